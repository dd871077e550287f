"""Scene files: a declarative schema, a loader that reports every problem, and the reference docs.

A scene is a TOML file (SI units throughout) with a ``[simulation]`` table, ``[[planes]]`` and
``[[bodies]]``. The schema below is data: one :class:`Section` per table, one :class:`Field` per key
(type, default, allowed values, unit, doc). The loader, the error messages, the dataclass docstrings
and ``docs/scene_reference.md`` (``python -m hybrid.app.scene > docs/scene_reference.md``) are all
derived from it, so they cannot drift apart. Nothing from a scene file is ever evaluated.

    scene = load_scene("scenes/drop.toml")     # raises SceneError listing every problem
"""
import difflib
import math
import sys
import tomllib
from dataclasses import dataclass, field as dataclass_field
from pathlib import Path

from hybrid.app import geometry

# Models whose bodies may carry FEM fields (young, anchors, ...). "auto" switches to FEM when
# stress demands it, so it needs the same material data.
FEM_MODELS = ("fem", "auto")
# A quaternion whose norm differs from 1 by more than this is a mistake, not round-off.
QUATERNION_TOLERANCE = 1e-6
# a scene of more steps than this is a typo (1e9 steps take days at 1e4 steps/s)
MAX_STEPS = 1e9
# most elements a shape may be meshed into (a mistyped resolution would otherwise exhaust memory
# before any message: 1e-4 m on a 0.1 m box asked for 7.5 GiB in one array)
MAX_ELEMENTS = 2e6


class _Marker:
    def __init__(self, name):
        self.name = name

    def __repr__(self):
        return self.name


REQUIRED = _Marker("REQUIRED")   # schema default of a field that must be given
INVALID = _Marker("INVALID")     # value of a field that failed validation (a problem is recorded)


# ---------------------------------------------------------------------------------------------
# Schema
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Field:
    """One key of a scene table.

    kind: "number" (float; ints accepted), "integer", "string", "boolean", "vector" (3 numbers),
    "quaternion" (4 numbers w, x, y, z), "box" ([[min x, y, z], [max x, y, z]]), "choice" (one of
    ``choices``), "path" (file path relative to the scene file), "table" (nested table described by
    section ``table``), "tables" (array of such tables). Ranges (``low``/``high``, open or closed)
    apply to numbers, integers and each component of a vector.
    """
    name: str
    kind: str
    default: object = REQUIRED
    unit: str = ""
    doc: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple = ()
    nonzero: bool = False
    table: str | None = None
    fem: bool = False
    shapes: tuple = ()
    default_text: str | None = None


@dataclass(frozen=True)
class Section:
    """One table of the scene file: its key in the schema, how it is written, a doc and its fields."""
    key: str
    heading: str
    doc: str
    fields: tuple
    rules: tuple = ()

    def field(self, name):
        return next(f for f in self.fields if f.name == name)

    def names(self):
        return [f.name for f in self.fields]


def _positive(name, default, unit, doc, **kw):
    return Field(name, "number", default, unit, doc, low=0.0, low_open=True, **kw)


def _non_negative(name, default, unit, doc, **kw):
    return Field(name, "number", default, unit, doc, low=0.0, **kw)


def _unit_interval(name, default, doc, **kw):
    return Field(name, "number", default, "", doc, low=0.0, high=1.0, **kw)


SOLVER = Section("simulation.solver", "[simulation.solver]", "Contact solver settings.", (
    Field("iterations", "integer", 20, "", "Contact solver iterations per step.", low=1),
    Field("deformable_iterations", "integer", 100, "", "Contact solver iterations per step when "
          "any contact is on a deformable body: those converge more slowly (a heavy box on a light "
          "slab sank into it after 20). The sweeps stop early once converged.", low=1),
    _non_negative("contact_margin", 0.005, "m", "Distance at which contacts are detected before touching."),
    Field("hold_resting", "boolean", True, "", "Step a deformable body lying still on static ground "
          "with its resting nodes held, checked every step (see How it works: resting contact is "
          "held); `false` leaves every contact to the solver."),
))

SIMULATION = Section("simulation", "[simulation]",
                     "Time stepping and global settings. The table is optional.", (
    Field("name", "string", None, "", "Scene name; output goes to `outputs/<name>/`.",
          default_text="file name without extension"),
    _positive("duration", 2.0, "s", "Simulated time."),
    _positive("dt", 0.001, "s", "Time step."),
    Field("gravity", "vector", (0.0, 0.0, -9.81), "m/s^2", "Gravitational acceleration (world frame)."),
    _positive("output_fps", 60.0, "1/s", "Frames written per simulated second."),
    Field("solver", "table", None, "", "Contact solver settings.", table="simulation.solver",
          default_text="see `[simulation.solver]`"),
), rules=("`dt` must be <= `duration`.", "`duration / dt` (the number of steps) must be at most 1e9."))

PLANE = Section("planes", "[[planes]]", "Static half-spaces: the solid side is opposite the normal.", (
    Field("point", "vector", (0.0, 0.0, 0.0), "m", "A point on the plane."),
    Field("normal", "vector", (0.0, 0.0, 1.0), "", "Outward normal; normalised by the loader.", nonzero=True),
    _non_negative("friction", 0.5, "", "Coulomb friction coefficient."),
    _unit_interval("restitution", 0.0, "Coefficient of restitution."),
))

SHAPE = Section("bodies.shape", "shape = { ... }", "Analytic shape of a body, centred on its position. "
                "An inline table, e.g. `shape = { type = \"sphere\", radius = 0.1 }`.", (
    Field("type", "choice", REQUIRED, "", "Kind of shape.", choices=("box", "sphere", "cylinder", "capsule")),
    Field("size", "vector", REQUIRED, "m", "Edge lengths along the body's x, y, z axes.",
          low=0.0, low_open=True, shapes=("box",)),
    _positive("radius", REQUIRED, "m", "Radius.", shapes=("sphere", "cylinder", "capsule")),
    _positive("height", REQUIRED, "m", "Length along the body's z axis (capsule: total, caps included).",
              shapes=("cylinder", "capsule")),
    _positive("resolution", None, "m", "Target edge length when meshing the shape; optional.",
              shapes=("box", "sphere", "cylinder", "capsule"), default_text="chosen by the builder"),
), rules=("`size` is required for and only allowed with `box`; `radius` with `sphere`, `cylinder`, "
          "`capsule`; `height` with `cylinder`, `capsule`.",
          "A capsule's `height` must be >= 2 `radius`.",
          "A `resolution` that would mesh the shape into more than 2e6 elements (tetrahedra for a "
          "deformable body, surface triangles for a rigid one) is rejected."))

DAMPING = Section("bodies.damping", "damping = { ... }", "Rayleigh damping `C = mass M + stiffness K` "
                  "(FEM only).", (
    _non_negative("mass", 0.0, "1/s", "Mass-proportional coefficient."),
    _non_negative("stiffness", 0.0, "s", "Stiffness-proportional coefficient."),
))

REGION_DOC = "Region `[[xmin, ymin, zmin], [xmax, ymax, zmax]]` in body coordinates (rest shape)."

ANCHOR = Section("bodies.anchors", "[[bodies.anchors]]", "Nodes of an FEM body held at a prescribed "
                 "velocity: those inside `box` (body coordinates, rest shape).", (
    Field("box", "box", REQUIRED, "m", REGION_DOC),
    Field("velocity", "vector", (0.0, 0.0, 0.0), "m/s", "Prescribed velocity (world frame)."),
))

LOAD = Section("bodies.loads", "[[bodies.loads]]", "Constant force on the nodes of an FEM body inside "
               "`box` (body coordinates, rest shape).", (
    Field("box", "box", REQUIRED, "m", REGION_DOC),
    Field("force", "vector", REQUIRED, "N",
          "Total force over the region, shared among its nodes (world frame)."),
))

UNBREAKABLE = Section("bodies.unbreakable", "[[bodies.unbreakable]]", "Region of an FEM body that never "
                      "cracks: the elements whose centroid is inside `box` (body coordinates, rest shape).", (
    Field("box", "box", REQUIRED, "m", REGION_DOC),
))

BODY = Section("bodies", "[[bodies]]", "Rigid or deformable bodies.", (
    Field("name", "string", REQUIRED, "", "Unique name."),
    Field("model", "choice", "rigid", "", "`rigid`, `fem` (deformable) or `auto` (switches when stress "
          "demands it).", choices=("rigid", "fem", "auto")),
    Field("shape", "table", None, "", "Analytic shape, see `shape = { ... }`.", table="bodies.shape",
          default_text="none"),
    Field("mesh", "path", None, "", "Mesh file (any format meshio reads), relative to the scene file's folder.",
          default_text="none"),
    _positive("density", 1000.0, "kg/m^3", "Mass density."),
    Field("position", "vector", (0.0, 0.0, 0.0), "m", "Position of the body origin (world frame)."),
    Field("orientation", "quaternion", (1.0, 0.0, 0.0, 0.0), "", "Unit quaternion `[w, x, y, z]`; "
          "renormalised if its norm is within 1e-6 of 1."),
    Field("velocity", "vector", (0.0, 0.0, 0.0), "m/s", "Initial velocity (world frame)."),
    Field("angular_velocity", "vector", (0.0, 0.0, 0.0), "rad/s", "Initial angular velocity (world frame)."),
    _non_negative("friction", 0.5, "", "Coulomb friction coefficient."),
    _unit_interval("restitution", 0.0, "Coefficient of restitution."),
    Field("fixed", "boolean", False, "", "Immovable (infinite mass)."),
    _positive("young", None, "Pa", "Young's modulus.", fem=True, default_text="required for FEM"),
    Field("poisson", "number", 0.3, "", "Poisson's ratio.", low=-1.0, high=0.5, low_open=True,
          high_open=True, fem=True),
    Field("damping", "table", None, "", "Rayleigh damping, see `damping = { ... }`.", table="bodies.damping",
          fem=True, default_text="no damping"),
    Field("frame", "choice", "floating", "", "`floating`: linear FEM in the shape-matched frame (fast); "
          "`corotated`: per-element rotations (large bending).", choices=("floating", "corotated"), fem=True),
    Field("order", "choice", 1, "", "Element order: 1 (linear tets) or 2 (quadratic tets).", choices=(1, 2),
          fem=True),
    Field("mass_matrix", "choice", "lumped", "", "Mass matrix.", choices=("lumped", "consistent"), fem=True),
    Field("integrator", "choice", "backward_euler", "", "`backward_euler` (stable, dissipative) or "
          "`newmark` (no numerical damping; a body's energy never exceeds its start energy plus the "
          "work done on it). A free body is stepped in the frame spinning with it.",
          choices=("backward_euler", "newmark"), fem=True),
    Field("anchors", "tables", (), "", "Held regions, see `[[bodies.anchors]]`.", table="bodies.anchors",
          fem=True, default_text="none"),
    Field("loads", "tables", (), "", "Applied forces, see `[[bodies.loads]]`.", table="bodies.loads",
          fem=True, default_text="none"),
    _positive("yield_stress", None, "Pa", "Von Mises yield stress: von Mises perfect plasticity "
              "(plastic strain per element, or per quadrature point for order 2). Absent: purely "
              "elastic, no plasticity pass runs.", fem=True, default_text="none (elastic)"),
    _positive("plastic_update_strain", 0.02, "", "Equivalent plastic strain, accumulated in some "
              "element since the last update, at which the plastic deformation is baked into the rest "
              "shape (one refactorisation of this body); needs `yield_stress`.", fem=True),
    _positive("max_plastic_strain", None, "", "Cap on the equivalent plastic strain of an element "
              "(further flow is elastic); needs `yield_stress`.", fem=True, default_text="none (no cap)"),
    _positive("fracture_stress", None, "Pa", "Tensile strength: an element whose smoothed largest "
              "principal stress exceeds it cracks. Absent: the body never breaks.", fem=True,
              default_text="none (unbreakable)"),
    _positive("tearing_strain", None, "", "Equivalent plastic strain at which an element tears "
              "(ductile fracture); needs `yield_stress`.", fem=True, default_text="none"),
    Field("fragment_model", "choice", "fem", "", "What fragments become: `fem`, `rigid`, or `auto` "
          "(fragments with fewer than `rigid_fragment_tets` elements become rigid).",
          choices=("fem", "rigid", "auto"), fem=True),
    Field("rigid_fragment_tets", "integer", 8, "", "Size (elements) below which an `auto` fragment "
          "becomes rigid.", low=1, fem=True),
    Field("max_cracks_per_step", "integer", 16, "", "Most elements that crack in one step (the most "
          "overstressed first).", low=1, fem=True),
    Field("unbreakable", "tables", (), "", "Regions that never crack, see `[[bodies.unbreakable]]`.",
          table="bodies.unbreakable", fem=True, default_text="none"),
), rules=("Exactly one of `shape` or `mesh` is required.",
          "Names must be unique.",
          "FEM fields (marked FEM) need `model = \"fem\"` or `\"auto\"`; `young` is then required.",
          "`tearing_strain` needs `yield_stress`.",
          "`plastic_update_strain` and `max_plastic_strain` need `yield_stress`.",
          "A mesh must be readable and closed; an FEM body's mesh must contain tetra or tetra10 "
          "cells: `order = 2` on a tetra mesh adds a node at the middle of every (straight) edge, "
          "`order = 1` on a tetra10 mesh keeps the corner nodes only. Tets with zero volume are "
          "rejected, listed by index; inverted tets (negative volume) are reoriented, with a warning "
          "listing them by index.",
          "`model = \"auto\"` is not implemented yet: a scene using it is rejected.",
          "Every anchor and load box must hold at least one node of the body's mesh (checked when "
          "the body is built, by `run` and `validate`).",
          "A scene needs at least one body."))

TOP = Section("", "top level", "The scene file.", (
    Field("simulation", "table", None, "", "Time stepping.", table="simulation"),
    Field("planes", "tables", (), "", "Static planes.", table="planes"),
    Field("bodies", "tables", (), "", "Bodies.", table="bodies"),
))

SCHEMA = {s.key: s for s in (TOP, SIMULATION, SOLVER, PLANE, BODY, SHAPE, DAMPING, ANCHOR, LOAD,
                                  UNBREAKABLE)}


def _default(section, name):
    return section.field(name).default


# ---------------------------------------------------------------------------------------------
# Describing fields: error messages and reference docs
# ---------------------------------------------------------------------------------------------

def _fmt(value):
    """A value as it would be written in TOML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_fmt(v)}" for k, v in value.items()) + " }"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _range_text(f):
    low = None if f.low is None else f"{f.low:g}"
    high = None if f.high is None else f"{f.high:g}"
    if low is not None and high is not None:
        return f"in {'(' if f.low_open else '['}{low}, {high}{')' if f.high_open else ']'}"
    if low is not None:
        return f"{'>' if f.low_open else '>='} {low}"
    if high is not None:
        return f"{'<' if f.high_open else '<='} {high}"
    return ""


def _allowed_text(f):
    """Allowed values in a few words: '> 0', 'in [0, 1]', '"rigid", "fem"', 'non-zero'."""
    if f.kind == "choice":
        return ", ".join(_fmt(c) for c in f.choices)
    parts = [_range_text(f)] if _range_text(f) else []
    if f.kind == "vector" and parts:
        parts = [f"each {parts[0]}"]
    if f.nonzero:
        parts.append("non-zero")
    if f.kind == "quaternion":
        parts.append("unit norm")
    if f.kind == "box":
        parts.append("min <= max on each axis")
    return ", ".join(parts)


def _describe(f):
    """What a field must be, for error messages: 'a number > 0', 'one of "rigid", "fem"'."""
    span = _range_text(f)
    span = f" {span}" if span else ""
    if f.kind == "number":
        return f"a number{span}"
    if f.kind == "integer":
        return f"an integer{span}"
    if f.kind == "string":
        return "a non-empty string"
    if f.kind == "boolean":
        return "true or false"
    if f.kind == "vector":
        return f"a {'non-zero ' if f.nonzero else ''}list of 3 numbers{span}"
    if f.kind == "quaternion":
        return "a unit quaternion [w, x, y, z]"
    if f.kind == "box":
        return "a box [[xmin, ymin, zmin], [xmax, ymax, zmax]] with min <= max on each axis"
    if f.kind == "choice":
        return "one of " + ", ".join(_fmt(c) for c in f.choices)
    if f.kind == "path":
        return "a file path string"
    return "a table" if f.kind == "table" else "an array of tables"


_TYPE_NAMES = {"number": "number", "integer": "integer", "string": "string", "boolean": "boolean",
               "vector": "3 numbers", "quaternion": "4 numbers", "box": "2 x 3 numbers",
               "choice": "choice", "path": "path", "table": "table", "tables": "array of tables"}


def _default_text(f):
    if f.default_text is not None:
        return f.default_text
    if f.default is REQUIRED:
        return "required"
    if f.kind == "tables" and f.default == ():
        return "none"
    if isinstance(f.default, float):
        return f"{f.default:g}"
    if isinstance(f.default, tuple):
        return "[" + ", ".join(f"{c:g}" for c in f.default) + "]"
    return _fmt(f.default)


# ---------------------------------------------------------------------------------------------
# Scene dataclasses (docstrings list every field, generated from the schema)
# ---------------------------------------------------------------------------------------------

Vec3 = tuple[float, float, float]
Box = tuple[Vec3, Vec3]


@dataclass(frozen=True)
class Solver:
    iterations: int = _default(SOLVER, "iterations")
    deformable_iterations: int = _default(SOLVER, "deformable_iterations")
    contact_margin: float = _default(SOLVER, "contact_margin")
    hold_resting: bool = _default(SOLVER, "hold_resting")


@dataclass(frozen=True)
class Simulation:
    name: str
    duration: float = _default(SIMULATION, "duration")
    dt: float = _default(SIMULATION, "dt")
    gravity: Vec3 = _default(SIMULATION, "gravity")
    output_fps: float = _default(SIMULATION, "output_fps")
    solver: Solver = Solver()


@dataclass(frozen=True)
class Plane:
    point: Vec3 = _default(PLANE, "point")
    normal: Vec3 = _default(PLANE, "normal")
    friction: float = _default(PLANE, "friction")
    restitution: float = _default(PLANE, "restitution")


@dataclass(frozen=True)
class Shape:
    type: str
    size: Vec3 | None = None
    radius: float | None = None
    height: float | None = None
    resolution: float | None = None


@dataclass(frozen=True)
class Damping:
    mass: float = _default(DAMPING, "mass")
    stiffness: float = _default(DAMPING, "stiffness")


@dataclass(frozen=True)
class Anchor:
    box: Box
    velocity: Vec3 = _default(ANCHOR, "velocity")


@dataclass(frozen=True)
class Load:
    box: Box
    force: Vec3


@dataclass(frozen=True)
class Unbreakable:
    box: Box


@dataclass(frozen=True)
class Body:
    name: str
    model: str = _default(BODY, "model")
    shape: Shape | None = None
    mesh: Path | None = None
    density: float = _default(BODY, "density")
    position: Vec3 = _default(BODY, "position")
    orientation: tuple[float, float, float, float] = _default(BODY, "orientation")
    velocity: Vec3 = _default(BODY, "velocity")
    angular_velocity: Vec3 = _default(BODY, "angular_velocity")
    friction: float = _default(BODY, "friction")
    restitution: float = _default(BODY, "restitution")
    fixed: bool = _default(BODY, "fixed")
    young: float | None = None
    poisson: float = _default(BODY, "poisson")
    damping: Damping = Damping()
    frame: str = _default(BODY, "frame")
    order: int = _default(BODY, "order")
    mass_matrix: str = _default(BODY, "mass_matrix")
    integrator: str = _default(BODY, "integrator")
    anchors: tuple[Anchor, ...] = ()
    loads: tuple[Load, ...] = ()
    yield_stress: float | None = None
    plastic_update_strain: float = _default(BODY, "plastic_update_strain")
    max_plastic_strain: float | None = None
    fracture_stress: float | None = None
    tearing_strain: float | None = None
    fragment_model: str = _default(BODY, "fragment_model")
    rigid_fragment_tets: int = _default(BODY, "rigid_fragment_tets")
    max_cracks_per_step: int = _default(BODY, "max_cracks_per_step")
    unbreakable: tuple[Unbreakable, ...] = ()


@dataclass(frozen=True)
class Scene:
    """A validated scene.

    Attributes:
        name: scene name (``simulation.name``), used for the output folder.
        source_path: the scene file as given to :func:`load_scene`.
        simulation: time stepping settings.
        planes: static half-spaces.
        bodies: bodies in file order.
        raw: the parsed TOML as a dict, for writing into ``summary.json``.
    """
    name: str
    source_path: Path
    simulation: Simulation
    planes: tuple[Plane, ...]
    bodies: tuple[Body, ...]
    raw: dict = dataclass_field(default_factory=dict, repr=False)


def _attribute_doc(section, summary, extra=""):
    lines = [summary, "", "Attributes (SI units; defaults as in the scene file):"]
    for f in section.fields:
        unit = f" [{f.unit}]" if f.unit else ""
        allowed = _allowed_text(f)
        allowed = f"; allowed: {allowed}" if allowed else ""
        fem = " (FEM only)" if f.fem else ""
        lines.append(f"    {f.name}{unit}: {f.doc}{fem} Default: {_default_text(f)}{allowed}.")
    return "\n".join(lines) + extra


Solver.__doc__ = _attribute_doc(SOLVER, "Contact solver settings (``[simulation.solver]``).")
Simulation.__doc__ = _attribute_doc(SIMULATION, "Time stepping settings (``[simulation]``).")
Plane.__doc__ = _attribute_doc(PLANE, "A static half-space (``[[planes]]``); ``normal`` is a unit vector.")
Shape.__doc__ = _attribute_doc(SHAPE, "An analytic body shape; fields a type does not use are None.")
Damping.__doc__ = _attribute_doc(DAMPING, "Rayleigh damping of an FEM body.")
Anchor.__doc__ = _attribute_doc(ANCHOR, "A held region of an FEM body; ``box`` is ``(min, max)``.")
Load.__doc__ = _attribute_doc(LOAD, "A loaded region of an FEM body; ``box`` is ``(min, max)``.")
Unbreakable.__doc__ = _attribute_doc(UNBREAKABLE, "A region of an FEM body that never cracks.")
Body.__doc__ = _attribute_doc(BODY, "A body (``[[bodies]]``).", "\n    ``mesh`` is the resolved absolute "
                              "path; ``orientation`` is a unit quaternion (w, x, y, z).")


# ---------------------------------------------------------------------------------------------
# Loading
# ---------------------------------------------------------------------------------------------

class SceneError(Exception):
    """A scene file with problems; ``problems`` lists every one, each naming file, table and field."""

    def __init__(self, problems):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


def load_scene(path):
    """Read, validate and return the scene in TOML file ``path``.

    Raises SceneError listing every problem found (missing or unparsable file, unknown keys, wrong
    types, values out of range, missing or unusable meshes), each naming the file, table and field.
    """
    path = Path(path)
    try:
        with open(path, "rb") as stream:
            data = tomllib.load(stream)
    except FileNotFoundError:
        raise SceneError([f"{path}: scene file not found"]) from None
    except tomllib.TOMLDecodeError as error:
        raise SceneError([f"{path}: invalid TOML: {error}"]) from None
    except UnicodeDecodeError as error:
        raise SceneError([f"{path}: not UTF-8 text ({error.reason} at byte {error.start})"]) from None
    except OSError as error:
        raise SceneError([f"{path}: cannot read scene file ({error.strerror or error})"]) from None
    return parse_scene(data, str(path), path.parent)


def parse_scene(data, source, base_dir):
    """Validate the parsed TOML ``data`` of scene file ``source`` (a name used in messages);
    mesh paths resolve against ``base_dir``. Returns a Scene or raises SceneError."""
    problems = []
    base_dir = Path(base_dir)
    top = _read_table(data, TOP, _Where(source, "top level"), problems)
    simulation = _parse_simulation(top["simulation"], source, problems)
    planes = tuple(_parse_plane(entry, source, i, problems)
                   for i, entry in enumerate(_entries(top["planes"], "planes", source, problems)))
    bodies = []
    first_index = {}
    for i, entry in enumerate(_entries(top["bodies"], "bodies", source, problems)):
        body = _parse_body(entry, source, i, base_dir, problems)
        if isinstance(body.name, str):
            if body.name in first_index:
                problems.append(_body_where(source, i, body.name).problem(
                    "name", f"must be unique, got \"{body.name}\" again "
                            f"(first used by bodies[{first_index[body.name]}])"))
            first_index.setdefault(body.name, i)
        bodies.append(body)
    if not bodies and isinstance(top["bodies"], (list, tuple)):       # none given (a bad value is reported)
        problems.append(_Where(source, "top level").general("needs at least one [[bodies]] table"))
    if problems:
        raise SceneError(problems)
    return Scene(simulation.name, Path(source), simulation, planes, tuple(bodies), data)


def _parse_simulation(table, source, problems):
    where = _Where(source, "[simulation]")
    values = _read_table(table if isinstance(table, dict) else {}, SIMULATION, where, problems)
    if values["name"] is None:
        values["name"] = Path(source).stem
    solver_table = values.pop("solver")
    solver_where = _Where(source, "[simulation.solver]")
    solver_table = solver_table if isinstance(solver_table, dict) else {}
    solver = Solver(**_read_table(solver_table, SOLVER, solver_where, problems))
    if _valid(values["dt"], values["duration"]) and values["dt"] > values["duration"]:
        problems.append(where.problem("dt", f"must be <= duration ({_fmt(values['duration'])} s), "
                                            f"got {_fmt(values['dt'])}"))
    elif _valid(values["dt"], values["duration"]) and values["duration"] / values["dt"] > MAX_STEPS:
        problems.append(where.problem("dt", f"gives {values['duration'] / values['dt']:.3g} steps over "
                                            f"duration {_fmt(values['duration'])} s; at most "
                                            f"{MAX_STEPS:.0e} steps are allowed"))
    return Simulation(solver=solver, **values)


def _parse_plane(table, source, index, problems):
    values = _read_table(table, PLANE, _Where(source, f"[planes] (planes[{index}])"), problems)
    if _valid(values["normal"]):
        length = math.sqrt(sum(c * c for c in values["normal"]))
        values["normal"] = tuple(c / length for c in values["normal"])
    return Plane(**values)


def _body_where(source, index, name):
    label = f"[bodies] \"{name}\" (bodies[{index}])" if isinstance(name, str) else f"[bodies] (bodies[{index}])"
    return _Where(source, label)


def _parse_body(table, source, index, base_dir, problems):
    name = table.get("name") if isinstance(table, dict) else None
    where = _body_where(source, index, name)
    values = _read_table(table, BODY, where, problems, base_dir)
    given = set(table) if isinstance(table, dict) else set()
    model = values["model"]

    # FEM fields: only for FEM models, and young is then required
    fem_model = model in FEM_MODELS
    if _valid(model) and not fem_model:
        for f in BODY.fields:
            if f.fem and f.name in given:
                problems.append(where.problem(f.name, f"needs model = \"fem\" or \"auto\" "
                                                      f"(this body has model = \"{model}\")"))
    if fem_model and values["young"] is None:
        problems.append(where.problem("young", f"is required for model = \"{model}\": "
                                               f"{_describe(BODY.field('young'))} (Pa)"))
    for key in ("plastic_update_strain", "max_plastic_strain"):
        if fem_model and key in given and values["yield_stress"] is None:
            problems.append(where.problem(key, "needs field 'yield_stress' (the body is elastic without it)"))
    if fem_model and values["tearing_strain"] is not None and values.get("yield_stress") is None:
        problems.append(where.problem("tearing_strain", "needs field 'yield_stress' (tearing is "
                                                        "measured in plastic strain)"))

    # exactly one of shape or mesh
    has_shape, has_mesh = "shape" in given, "mesh" in given
    if has_shape == has_mesh:
        problems.append(where.general("needs exactly one of field 'shape' or field 'mesh', got "
                                      + ("both" if has_shape else "neither")))
    if has_shape and values["shape"] is not None:
        values["shape"] = _parse_shape(values["shape"], where, problems)
        if _valid(model) and isinstance(values["shape"], Shape):
            _check_element_count(values["shape"], fem_model, where, problems)
    if model == "auto":
        problems.append(where.problem("model", "= \"auto\" (switching between rigid and FEM) is not "
                                               "implemented yet; use \"rigid\" or \"fem\""))
    if has_mesh and _valid(values["mesh"]) and _valid(model):
        _check_mesh(table["mesh"], values["mesh"], model, where, problems)

    damping = values.pop("damping")
    values["damping"] = Damping()
    if fem_model and isinstance(damping, dict):
        values["damping"] = Damping(**_read_table(damping, DAMPING, where.nested("damping"), problems))
    for key, section, kind in (("anchors", ANCHOR, Anchor), ("loads", LOAD, Load),
                               ("unbreakable", UNBREAKABLE, Unbreakable)):
        entries = values[key]
        values[key] = ()
        if fem_model and entries:
            entries = _entries(entries, key, source, problems, where=where)
            named = f" \"{name}\"" if isinstance(name, str) else ""
            values[key] = tuple(
                kind(**_read_table(entry, section, _Where(
                    source, f"[bodies.{key}]{named} (bodies[{index}].{key}[{i}])"), problems))
                for i, entry in enumerate(entries))
    return Body(**values)


def _parse_shape(table, where, problems):
    """Validate the shape table; fields a shape type does not use are errors."""
    shape_where = where.nested("shape")
    if not isinstance(table, dict):
        return INVALID
    kind = table.get("type")
    if kind not in SHAPE.field("type").choices:
        # without a valid type we cannot tell which other fields belong; report the type only
        _read_table(table, SHAPE, shape_where, problems, only=(SHAPE.field("type"),))
        return INVALID
    used = [f for f in SHAPE.fields if f.name == "type" or kind in f.shapes]
    takes = ", ".join(f.name for f in used if f.name != "type")
    for key in table:
        if key in SHAPE.names() and key not in [f.name for f in used]:
            problems.append(shape_where.problem(key, f"is not used by shape type \"{kind}\" "
                                                     f"(it takes: {takes})"))
    values = _read_table(table, SHAPE, shape_where, problems, only=used)
    height, radius = values.get("height"), values.get("radius")
    if kind == "capsule" and _valid(height, radius) and height < 2 * radius:
        problems.append(shape_where.problem("height", f"must be >= 2 radius ({_fmt(2 * radius)} m) "
                                                      f"for a capsule, got {_fmt(height)}"))
    return Shape(**values)


def _check_element_count(shape, fem_model, where, problems):
    """Record a problem if meshing the shape at its ``resolution`` would make more elements than
    MAX_ELEMENTS (tetrahedra for a deformable body, surface triangles for a rigid one)."""
    h = shape.resolution
    if not _valid(h) or h is None:
        return
    r = shape.radius
    if shape.type == "box":
        cells = [math.ceil(a / h - 1e-9) for a in shape.size]
        count = 6 * cells[0] * cells[1] * cells[2] if fem_model else \
            4 * (cells[0] * cells[1] + cells[1] * cells[2] + cells[2] * cells[0])
    else:
        length = 2 * r if shape.type == "sphere" else shape.height
        count = 6 * (2 * r / h) ** 2 * (length / h) if fem_model else \
            2 * (2 * math.pi * r * length + 4 * math.pi * r * r) / h ** 2
    if count > MAX_ELEMENTS:
        kind = "tetrahedra" if fem_model else "surface triangles"
        problems.append(where.nested("shape").problem(
            "resolution", f"= {_fmt(h)} m would mesh the shape into about {count:.2g} {kind}; at "
                          f"most {MAX_ELEMENTS:.0e} are allowed (use a coarser resolution)"))


def _check_mesh(written, resolved, model, where, problems):
    """Record a problem if the mesh file is missing, unreadable or unusable for ``model``."""
    try:
        mesh = geometry.read_mesh(resolved)
        if model == "fem":
            geometry.tets_from_mesh(mesh, resolved)
        geometry.surface_from_mesh(mesh, resolved)
    except geometry.MeshError as error:
        problems.append(where.problem("mesh", f"= \"{written}\" (resolved to {resolved}): {error.reason}"))


# ---------------------------------------------------------------------------------------------
# Generic table reading
# ---------------------------------------------------------------------------------------------

class _Where:
    """Where a problem is: the file, a table label such as ``[bodies] "box" (bodies[2])`` and a
    prefix for fields of inline tables (``shape.``)."""

    def __init__(self, source, label, prefix=""):
        self.source, self.label, self.prefix = source, label, prefix

    def nested(self, name):
        return _Where(self.source, self.label, f"{self.prefix}{name}.")

    def general(self, text):
        return f"{self.source}: {self.label}: {text}"

    def problem(self, name, text):
        return self.general(f"field '{self.prefix}{name}' {text}")


def _entries(value, name, source, problems, where=None):
    """The tables of an array of tables; non-tables are reported and skipped."""
    if value is None or value is INVALID:
        return []
    where = where or _Where(source, "top level")
    if isinstance(value, dict):
        problems.append(where.problem(name, f"must be an array of tables ([[{name}]]), got a single table"))
        return []
    if not isinstance(value, (list, tuple)):
        problems.append(where.problem(name, f"must be an array of tables ([[{name}]]), got {_fmt(value)}"))
        return []
    good = []
    for i, entry in enumerate(value):
        if isinstance(entry, dict):
            good.append(entry)
        else:
            problems.append(where.problem(f"{name}[{i}]", f"must be a table, got {_fmt(entry)}"))
    return good


def _read_table(table, section, where, problems, base_dir=None, only=None):
    """Check ``table`` against ``section``: unknown keys, required keys, types and ranges.

    Returns {field name: value} with defaults filled in and INVALID for fields that failed.
    Nested tables are returned unchecked (or None when absent) for the caller to read.
    ``only`` restricts the fields read (unknown keys are still judged against all of the section).
    """
    fields = section.fields if only is None else only
    allowed = section.names()
    if not isinstance(table, dict):
        problems.append(where.general(f"must be a table, got {_fmt(table)}"))
        table = {}
    for key in table:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), allowed, n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            problems.append(where.general(f"unknown key '{where.prefix}{key}'{hint}; allowed: "
                                          + ", ".join(allowed)))
    values = {}
    for f in fields:
        if f.name not in table:
            if f.default is REQUIRED:
                problems.append(where.problem(f.name, f"is required: {_describe(f)}"))
                values[f.name] = INVALID
            else:
                values[f.name] = f.default
        elif f.kind == "table":
            value = table[f.name]
            if not isinstance(value, dict):
                problems.append(where.problem(f.name, f"must be a table, got {_fmt(value)}"))
                value = INVALID
            values[f.name] = value
        elif f.kind == "tables":
            values[f.name] = table[f.name]
        else:
            values[f.name] = _convert(f, table[f.name], where, problems, base_dir)
    return values


def _convert(f, value, where, problems, base_dir):
    """The checked Python value of one scalar/vector field, or INVALID after recording a problem."""
    try:
        return _CONVERTERS[f.kind](f, value, base_dir)
    except _Bad as bad:
        problems.append(where.problem(f.name, f"must be {_describe(f)}, got {_fmt(value)}{bad.note}"))
        return INVALID


class _Bad(Exception):
    """A value that does not fit its field; ``note`` is appended to the message."""

    def __init__(self, note=""):
        self.note = note


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _in_range(f, x):
    if f.low is not None and (x < f.low or (f.low_open and x == f.low)):
        return False
    if f.high is not None and (x > f.high or (f.high_open and x == f.high)):
        return False
    return True


def _number(f, value, _):
    if not _is_number(value) or not _in_range(f, value):
        raise _Bad()
    return float(value)


def _integer(f, value, _):
    if not isinstance(value, int) or isinstance(value, bool) or not _in_range(f, value):
        raise _Bad()
    return value


def _string(f, value, _):
    if not isinstance(value, str) or not value.strip():
        raise _Bad()
    return value


def _boolean(f, value, _):
    if not isinstance(value, bool):
        raise _Bad()
    return value


def _numbers(value, count):
    if not isinstance(value, list) or len(value) != count or not all(_is_number(c) for c in value):
        raise _Bad()
    return tuple(float(c) for c in value)


def _vector(f, value, _):
    vector = _numbers(value, 3)
    if not all(_in_range(f, c) for c in vector) or (f.nonzero and not any(vector)):
        raise _Bad()
    return vector


def _quaternion(f, value, _):
    q = _numbers(value, 4)
    norm = math.sqrt(sum(c * c for c in q))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise _Bad(f" with norm {norm:.9g} (allowed: within {QUATERNION_TOLERANCE:g} of 1)")
    return tuple(c / norm for c in q)


def _box(f, value, _):
    if not isinstance(value, list) or len(value) != 2:
        raise _Bad()
    low, high = _numbers(value[0], 3), _numbers(value[1], 3)
    if any(a > b for a, b in zip(low, high)):
        raise _Bad()
    return low, high


def _choice(f, value, _):
    if not any(value == c and type(value) is type(c) for c in f.choices):
        raise _Bad()
    return value


def _path(f, value, base_dir):
    if not isinstance(value, str) or not value.strip():
        raise _Bad()
    path = Path(value).expanduser()
    return path if path.is_absolute() else (Path(base_dir or ".") / path).resolve()


_CONVERTERS = {"number": _number, "integer": _integer, "string": _string, "boolean": _boolean,
               "vector": _vector, "quaternion": _quaternion, "box": _box, "choice": _choice, "path": _path}


def _valid(*values):
    return all(v is not INVALID and v is not None for v in values)


def reference_markdown():
    """The scene file reference (every table and field, unit, default, allowed values) as Markdown."""
    out = ["# Scene file reference", "",
           "Generated from the schema in `hybrid/app/scene.py` by `python -m hybrid.app.scene > "
           "docs/scene_reference.md`; do not edit by hand.", "",
           "Scene files are TOML, in SI units. Unknown keys are errors. Integers are accepted where "
           "numbers are expected; booleans are not numbers. Vectors are lists of 3 numbers. Mesh paths "
           "are relative to the scene file's folder. Check a file with `hybrid validate <file>`.", ""]
    for section in SCHEMA.values():
        if section is TOP:
            continue
        out += [f"## `{section.heading}`", "", section.doc, ""]
        if section.rules:
            out += [f"- {rule}" for rule in section.rules] + [""]
        out += ["| Field | Type | Unit | Default | Allowed | Description |",
                "|---|---|---|---|---|---|"]
        for f in section.fields:
            doc = f.doc + (" FEM only." if f.fem else "")
            if f.shapes and len(f.shapes) < len(SHAPE.field("type").choices):
                doc += " For " + ", ".join(f"`{s}`" for s in f.shapes) + "."
            cells = [f"`{f.name}`", _TYPE_NAMES[f.kind], f.unit or "-", _default_text(f),
                     _allowed_text(f) or "-", doc]
            out.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
        out.append("")
    return "\n".join(out)


def validate_command(path, check=None):
    """``hybrid validate <path>``: print "OK: ..." (stdout) or every problem (stderr); return 0 or 2.

    ``check(scene)``, when given, runs on a scene that parsed and raises ValueError for problems
    only the built bodies show (an anchor box holding no node, say): what ``hybrid run`` would
    reject, ``validate`` rejects too."""
    try:
        scene = load_scene(path)
        if check is not None:
            try:
                with geometry.caught_mesh_warnings() as repaired:
                    check(scene)
            except (ValueError, geometry.MeshError) as error:
                raise SceneError([f"{path}: {error}"]) from None
            for message in repaired:
                print(f"warning: {message}", file=sys.stderr)
    except SceneError as error:
        for problem in error.problems:
            print(problem, file=sys.stderr)
        print(f"{path}: {len(error.problems)} problem{'s' if len(error.problems) != 1 else ''}",
              file=sys.stderr)
        return 2
    print(f"OK: {path}: {len(scene.bodies)} bodies, {len(scene.planes)} planes")
    return 0


if __name__ == "__main__":
    sys.stdout.write(reference_markdown())
