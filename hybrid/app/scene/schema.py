"""The scene schema as data: one :class:`Section` per TOML table, one :class:`Field` per key.

The loader, its error messages, the record docstrings and ``docs/scene_reference.md`` are all
derived from these tables, so they cannot drift apart.
"""
from dataclasses import dataclass

# Models whose bodies may carry FEM fields (young, anchors, ...). "auto" switches to FEM when
# stress demands it, so it needs the same material data.
FEM_MODELS = ("fem", "auto")
# A quaternion whose norm differs from 1 by more than this is a mistake, not rounding (the four
# digits of a hand-written 0.7071 give a norm 1e-5 short of 1; a typo gives far more).
QUATERNION_TOLERANCE = 1e-3
# a scene of more steps than this is a typo (1e9 steps take days at 1e4 steps/s)
MAX_STEPS = 1e9
# most elements a shape may be meshed into (a mistyped resolution would otherwise exhaust memory
# before any message: 1e-4 m on a 0.1 m box asked for 7.5 GiB in one array)
MAX_ELEMENTS = 2e6
# largest length (m) of a shape or extent of a mesh file: beyond it doubles resolve positions more
# coarsely than 0.1 mm (a contact margin is 5 mm), so it is a mistaken unit or a typo; and from
# about 1e60 m volumes and inertias (cubes and fifth powers of lengths) overflow
LARGEST_LENGTH = 1e12


class _Marker:
    def __init__(self, name):
        self.name = name

    def __repr__(self):
        return self.name


REQUIRED = _Marker("REQUIRED")   # schema default of a field that must be given
INVALID = _Marker("INVALID")     # value of a field that failed validation (a problem is recorded)


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
        """The :class:`Field` called ``name`` (StopIteration if the section has none)."""
        return next(f for f in self.fields if f.name == name)

    def names(self):
        """The section's field names, in schema order."""
        return [f.name for f in self.fields]


def _positive(name, default, unit, doc, **kw):
    return Field(name, "number", default, unit, doc, low=0.0, low_open=True, **kw)


def _non_negative(name, default, unit, doc, **kw):
    return Field(name, "number", default, unit, doc, low=0.0, **kw)


def _unit_interval(name, default, doc, **kw):
    return Field(name, "number", default, "", doc, low=0.0, high=1.0, **kw)


SOLVER = Section("simulation.solver", "[simulation.solver]", "Solver settings: the contact solver "
                 "and the linear systems of FEM bodies.", (
    Field("iterations", "integer", 20, "", "Contact solver iterations per step (at least: a "
          "pass with few contacts sweeps on until converged, up to 100 within 2,000 contact "
          "visits). The sweeps stop early once converged.", low=1),
    Field("deformable_iterations", "integer", 100, "", "Contact solver iterations per step when "
          "any contact is on a deformable body: those converge more slowly (a heavy box on a light "
          "slab sank into it after 20). The sweeps stop early once converged.", low=1),
    _non_negative("contact_margin", 0.005, "m", "Distance at which contacts are detected before touching."),
    Field("hold_resting", "boolean", True, "", "Step a deformable body lying still on static ground "
          "with its resting nodes held, checked every step (docs/coupling.md, held resting "
          "contact); `false` leaves every contact to the solver."),
    Field("linear_solver", "choice", "cholmod", "", "Sparse factorisation of the FEM bodies' system "
          "matrices: `cholmod` (supernodal Cholesky, SuiteSparse's CHOLMOD through cholespy; the "
          "fastest) or `superlu` (scipy's SuperLU, needs nothing beyond scipy).",
          choices=("cholmod", "superlu")),
    Field("corotated_solver", "choice", "cg", "", "How bodies with `frame = \"corotated\"` solve their "
          "system, which changes every step: `cg` (conjugate gradients, warm-started and "
          "preconditioned by the rest factorisation turned into the body's frame) or `lu` "
          "(factorise anew every step).", choices=("cg", "lu")),
))

SIMULATION = Section("simulation", "[simulation]",
                     "Time stepping and global settings. The table is optional.", (
    Field("name", "string", None, "", "Scene name; output goes to `outputs/<name>/`: a plain "
          "name (no `/` or `\\`, no leading `.`, no control characters), at most 200 bytes long.",
          default_text="file name without extension"),
    _positive("duration", 2.0, "s", "Simulated time; a run takes the nearest whole number of "
              "steps of `dt` (the run log warns when that is not `duration` itself)."),
    _positive("dt", 0.001, "s", "Time step."),
    Field("gravity", "vector", (0.0, 0.0, -9.81), "m/s^2", "Gravitational acceleration (world frame).",
          low=-1e8, high=1e8),
    _positive("output_fps", 60.0, "1/s", "Frames written per simulated second, each at the first "
              "step at or after its time; the first at the start and one at the end."),
    Field("resolve_impacts", "boolean", False, "", "Take a step in which an impact on a "
          "deformable body begins, and which is longer than the impact, in sub-steps (up to 64) "
          "short enough that the impact spans four of them (47 on a backward Euler body, whose damping "
          "would otherwise take its rebound), each followed by its events; then "
          "the scene's `dt` again (docs/scenes.md, what a run says about it). The summary's "
          "`substeps` counts them."),
    Field("solver", "table", None, "", "Contact and linear solver settings.", table="simulation.solver",
          default_text="see `[simulation.solver]`"),
), rules=("`dt` must be <= `duration`.", "`duration / dt` (the number of steps) must be at most 1e9."))

PLANE = Section("planes", "[[planes]]", "Static half-spaces: the solid side is opposite the normal.", (
    Field("point", "vector", (0.0, 0.0, 0.0), "m", "A point on the plane."),
    Field("normal", "vector", (0.0, 0.0, 1.0), "", "Outward normal; normalised by the loader.", nonzero=True),
    _non_negative("friction", 0.5, "", "Coulomb friction coefficient."),
    _unit_interval("restitution", 0.0, "Coefficient of restitution of rigid bodies striking the "
                   "plane (deformable bodies bounce through their own elasticity)."),
))

SHAPE = Section("bodies.shape", "shape = { ... }", "Analytic shape of a body, centred on its position. "
                "An inline table, e.g. `shape = { type = \"sphere\", radius = 0.1 }`.", (
    Field("type", "choice", REQUIRED, "", "Kind of shape.", choices=("box", "sphere", "cylinder", "capsule")),
    Field("size", "vector", REQUIRED, "m", "Edge lengths along the body's x, y, z axes.",
          low=0.0, low_open=True, shapes=("box",)),
    _positive("radius", REQUIRED, "m", "Radius.", shapes=("sphere", "cylinder", "capsule")),
    _positive("height", REQUIRED, "m", "Length along the body's z axis (capsule: total, caps included).",
              shapes=("cylinder", "capsule")),
    _positive("resolution", None, "m", "Target edge length when meshing the shape; optional. "
              "Without it a deformable box is meshed in cells a third of its shortest side (an even "
              "count along each side, so the mesh keeps the box's mirror symmetries) while that "
              "makes at most 4,000 nodes; a larger (thin) box in two layers through its thin side "
              "(and across a bar's other small side), cells along its long sides up to 4 times "
              "longer than the layers' thickness to stay within 4,000 nodes (no longer: a plate more "
              "than about 20 times wider than thick goes over it, a 1 x 1 x 0.01 m plate to 51,000 "
              "nodes, which take a minute to factorise; give a `resolution` for fewer), and quadratic tets unless `order = 1` is given "
              "(docs/scenes.md, default meshes); a sphere or cylinder at half its radius. The run log "
              "states each body's mesh and why. A rigid box's surface vertices are its contact "
              "points: without it, its corners, edge midpoints and face centres, or, for a box 10 "
              "times heavier than a deformable body it meets nearly without friction, no further "
              "apart than 0.4 of the deformable surfaces' edges (docs/coupling.md).",
              shapes=("box", "sphere", "cylinder", "capsule"), default_text="chosen by the builder"),
    Field("refine", "integer", 1, "", "A deformable box's mesh (its default mesh, or the one "
          "`resolution` gives) with each cell split this many times along each side, the element "
          "order kept: how `hybrid converge --refine` refines a box (a default mesh's cells may be "
          "longer along its long sides, which halving `resolution` would not keep).", low=1,
          shapes=("box",)),
), rules=("`size` is required for and only allowed with `box`; `radius` with `sphere`, `cylinder`, "
          "`capsule`; `height` with `cylinder`, `capsule`.",
          "A capsule's `height` must be >= 2 `radius`.",
          "A deformable body (`model = \"fem\"` or `\"auto\"`) is a `box`, `sphere` or "
          "`cylinder`, or a tet mesh file (`mesh`); a `capsule` is for rigid bodies.",
          "`size`, `radius` and `height` must be at most 1e12 m.",
          "A shape that would be meshed into more than 2e6 elements (tetrahedra for a deformable "
          "body, surface triangles for a rigid one) is rejected: at its `resolution` or, when none "
          "is given, at the builder's default (for a deformable box see `resolution`, for a "
          "deformable sphere or cylinder half its radius, for a rigid cylinder or capsule 1/32 of "
          "its circumference)."))

DAMPING = Section("bodies.damping", "damping = { ... }", "Rayleigh damping `C = mass M + stiffness K` "
                  "(FEM only).", (
    _non_negative("mass", 0.0, "1/s", "Mass-proportional coefficient."),
    _non_negative("stiffness", 0.0, "s", "Stiffness-proportional coefficient."),
))

AUTO = Section("bodies.auto", "auto = { ... }", "When a `model = \"auto\"` body (or an `auto` "
               "fragment) switches between rigid and FEM (docs/auto.md). Strains are measured as an "
               "element's strain rate times a time: for rigidifying, the body's response time (the "
               "longer of its elastic wave transit time, largest extent over sqrt(young / density), "
               "and the step); for elastifying, the longer of the step and the wave's transit "
               "across one element. Dimensionless, so the defaults hold from rubber to steel and "
               "centimetres to metres.", (
    _positive("rigidify_strain", 1e-4, "", "An FEM auto body becomes rigid once its measured strain "
              "(root mean square over its volume) stays below this for `window` steps (and "
              "nothing yields, its largest principal stress is below `fracture_margin` of "
              "`fracture_stress`, its anchors are still and, unless anchored, it has no load and "
              "no mass damping). At most a tenth of the elastify threshold in use."),
    _positive("elastify_strain", 1e-3, "", "A rigid auto body becomes FEM again, before the step is "
              "taken, when the change of its contact load in that step (each partner's total) would "
              "strain it by more than this (predicted through its kept FEM factorisation); raise it "
              "for soft bodies that carry strains of a percent or more under their own weight. A plastic or breakable "
              "body uses at most half its yield strain `yield_stress / young` (and half "
              "`fracture_stress / young`), so it is deformable before anything yields or cracks. "
              "Must exceed `rigidify_strain`."),
    Field("window", "integer", 10, "", "Steps the strain rate must stay low before rigidifying, "
          "so also the fewest steps a body turned deformable stays so (but a fragment under "
          "`rigid_fragment_tets`); a body turned rigid turns deformable at the first step that "
          "would strain it.", low=1, high=1_000_000),
    Field("fracture_margin", "number", 0.5, "", "A breakable body rigidifies only while its largest "
          "principal stress is below this fraction of `fracture_stress`.", low=0.0, high=1.0,
          low_open=True),
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
                      "cracks: the elements whose centroid is inside `box` (body coordinates, rest shape; "
                      "a box holding none is an error, as an anchor or load box holding no node is).", (
    Field("box", "box", REQUIRED, "m", REGION_DOC),
))

BODY = Section("bodies", "[[bodies]]", "Rigid or deformable bodies.", (
    Field("name", "string", REQUIRED, "", "Unique name, without control characters (a study's "
          "`--set bodies.<name>.<field>` takes names with dots)."),
    Field("model", "choice", "rigid", "", "`rigid`, `fem` (deformable) or `auto` (stepped as rigid "
          "while its deformation does not change, as FEM while a load would deform it; "
          "docs/auto.md).", choices=("rigid", "fem", "auto")),
    Field("shape", "table", None, "", "Analytic shape, see `shape = { ... }`.", table="bodies.shape",
          default_text="none"),
    Field("mesh", "path", None, "", "Mesh file (any format meshio reads), relative to the scene file's folder.",
          default_text="none"),
    _positive("density", 1000.0, "kg/m^3", "Mass density."),
    Field("position", "vector", (0.0, 0.0, 0.0), "m", "Position of the body origin (world frame). "
          "A body starting inside a plane is warned of and pushed out; a deformable one may start "
          "at most 1% of its size inside (its nodes are pushed out in one step), a rigid one at "
          "most its size (its bounding sphere's diameter). At most 1e6 m "
          "from the origin (docs/limits.md)."),
    Field("orientation", "quaternion", (1.0, 0.0, 0.0, 0.0), "", "Unit quaternion `[w, x, y, z]`; "
          "renormalised if its norm is within 1e-3 of 1 (`[0.7071, 0.7071, 0, 0]` is a quarter "
          "turn about x)."),
    Field("velocity", "vector", (0.0, 0.0, 0.0), "m/s", "Initial velocity (world frame); at most "
          "1e4 m/s, beyond which a run stops as unstable (docs/limits.md)."),
    Field("angular_velocity", "vector", (0.0, 0.0, 0.0), "rad/s", "Initial angular velocity (world "
          "frame); its rim speed (times the body's radius) at most 1e4 m/s."),
    _non_negative("friction", 0.5, "", "Coulomb friction coefficient."),
    _unit_interval("restitution", 0.0, "Coefficient of restitution of the body's collisions "
                   "while it is rigid (the larger of the two bodies' counts). A deformable body (`fem`, "
                   "or `auto` while deformable) bounces through its own elasticity and its contacts "
                   "take none: a rigid ball on a stiff, coarsely meshed one rebounds far less than "
                   "this ([limits.md](limits.md))."),
    Field("fixed", "boolean", False, "", "Immovable (infinite mass). Rigid bodies only: a deformable body is held by `[[bodies.anchors]]`."),
    Field("young", "number", None, "Pa", "Young's modulus (at most 1e15 Pa, a thousand times "
          "diamond's).", low=0.0, low_open=True, high=1e15, fem=True, default_text="required for FEM"),
    Field("poisson", "number", 0.3, "", "Poisson's ratio.", low=-1.0, high=0.5, low_open=True,
          high_open=True, fem=True),
    Field("damping", "table", None, "", "Rayleigh damping, see `damping = { ... }`.", table="bodies.damping",
          fem=True, default_text="no damping"),
    Field("frame", "choice", "floating", "", "`floating`: linear FEM in the shape-matched frame (fast); "
          "`corotated`: per-element rotations (large bending).", choices=("floating", "corotated"), fem=True),
    Field("order", "choice", None, "", "Element order: 1 (linear tets) or 2 (quadratic tets).",
          choices=(1, 2), fem=True, default_text="the mesh file's (2 for tetra10 cells); 2 for "
          "a thin box meshed by default (no `resolution`) that the former cubic cells would mesh "
          "into more than 4,000 nodes (docs/scenes.md, default meshes); else 1"),
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
              "elastic, no plasticity pass runs. Warned of when over a tenth of `young` (a yield strain "
              "linear elasticity does not reach) or below `density` g h, the stress the body's weight "
              "makes across its height h.", fem=True, default_text="none (elastic)"),
    _positive("plastic_update_strain", 0.02, "", "Equivalent plastic strain, accumulated in some "
              "element since the last update, at which the plastic deformation is baked into the rest "
              "shape (one refactorisation of this body); needs `yield_stress`.", fem=True),
    _positive("max_plastic_strain", None, "", "Cap on the accumulated equivalent plastic strain of an element "
              "(the frames' `plastic_strain`; further flow is elastic); needs `yield_stress`.", fem=True, default_text="none (no cap)"),
    _positive("fracture_stress", None, "Pa", "Tensile strength: an element whose smoothed largest "
              "principal stress exceeds it cracks. Absent: the body never breaks. Warned of as "
              "`yield_stress` is.", fem=True,
              default_text="none (unbreakable)"),
    _positive("tearing_strain", None, "", "Equivalent plastic strain at which an element tears "
              "(ductile fracture); needs `yield_stress`.", fem=True, default_text="none"),
    Field("fragment_model", "choice", "fem", "", "What fragments become: `fem`, `rigid` (for good; "
          "not the largest, nor pieces holding anchor or load nodes), "
          "or `auto` (auto bodies, rigid while calm and FEM while struck; those with fewer than "
          "`rigid_fragment_tets` elements rigid at once). An auto body's fragments that are not "
          "rigid for good are auto.",
          choices=("fem", "rigid", "auto"), fem=True),
    Field("rigid_fragment_tets", "integer", 8, "", "Size (elements) below which an `auto` fragment "
          "turns rigid as it breaks off (not after a `window`); once a blow has made it deformable it "
          "waits for its window like any auto body.", low=1, fem=True),
    Field("max_cracks_per_step", "integer", 16, "", "Most elements that crack in one step (the most "
          "overstressed first).", low=1, fem=True),
    Field("unbreakable", "tables", (), "", "Regions that never crack, see `[[bodies.unbreakable]]`.",
          table="bodies.unbreakable", fem=True, default_text="none"),
    Field("auto", "table", None, "", "Thresholds of `model = \"auto\"` switching, see "
          "`auto = { ... }`.", table="bodies.auto", fem=True, default_text="see `auto = { ... }`"),
), rules=("Exactly one of `shape` or `mesh` is required.",
          "Names must be unique.",
          "FEM fields (marked FEM) need `model = \"fem\"` or `\"auto\"`; `young` is then required.",
          "`tearing_strain` needs `yield_stress`.",
          "`plastic_update_strain` and `max_plastic_strain` need `yield_stress`.",
          "Each anchor and load box must hold a mesh node; anchor boxes that share nodes must give "
          "them the same velocity (each shared node counts in the first anchor's reaction).",
          "A mesh must be readable and closed; an FEM body's mesh must contain tetra or tetra10 "
          "cells: `order = 2` on a tetra mesh adds a node at the middle of every (straight) edge, "
          "`order = 1` on a tetra10 mesh keeps the corner nodes only. Tets with zero volume are "
          "rejected, listed by index, and so are an FEM body's tets too badly shaped to solve (flat "
          "slivers and needles: volume below 1e-6 of the regular tet on their longest edge; they "
          "make its matrix singular in double precision); inverted tets (negative volume) are reoriented, with a warning "
          "listing them by index; tets in pieces that share no node are warned of (with the nodes "
          "that lie on others, doubled at an interface), and so are nodes that lie on others in one "
          "piece (a slit the tets do not join across). A surface's corners are joined where they "
          "coincide (triangles written each with its own corners), and each of its pieces (triangles "
          "joined through shared edges; pieces touching at a vertex are two) is turned to face away "
          "from the solid (a cavity's wall into the cavity), whichever way it was written as a whole "
          "(a piece whose triangles are wound both ways is refused, with the count of edges "
          "traversed twice in the same direction). "
          "Every cell must name nodes the "
          "file has, and the points may span at most 1e12 m (a mesh spanning over 100 m is warned "
          "of: meshes are read in metres).",
          "A body whose fields give no usable body is rejected naming the field: a shape so small "
          "that its volume underflows, or a deformable body placed so far from the origin that its "
          "elements lose their volume in double precision.",
          "`auto` needs `model = \"auto\"` or `fragment_model = \"auto\"`.",
          "Every anchor and load box must hold at least one node of the body's mesh (checked when "
          "the body is built, by `run` and `validate`).",
          "A scene needs at least one body."))

TOP = Section("", "top level", "The scene file.", (
    Field("simulation", "table", None, "", "Time stepping.", table="simulation"),
    Field("planes", "tables", (), "", "Static planes.", table="planes"),
    Field("bodies", "tables", (), "", "Bodies.", table="bodies"),
))

SCHEMA = {s.key: s for s in (TOP, SIMULATION, SOLVER, PLANE, BODY, SHAPE, DAMPING, ANCHOR, LOAD,
                                  UNBREAKABLE, AUTO)}


def field_default(section, name):
    """The schema default of field ``name`` of ``section``."""
    return section.field(name).default
