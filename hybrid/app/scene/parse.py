"""Loading a scene file: read the TOML, check every table and field, return a Scene or raise
SceneError listing every problem."""
import math
import tomllib
import warnings
from pathlib import Path

from hybrid.app import deformable, geometry
from rigid.shapes import CIRCLE_DEFAULT_SEGMENTS

from .describe import describe, toml_text
from .records import (Anchor, Auto, Body, Damping, Load, Plane, Scene, Shape, Simulation, Solver,
                      Unbreakable)
from .schema import (ANCHOR, AUTO, BODY, DAMPING, FEM_MODELS, INVALID, LARGEST_LENGTH, LOAD, MAX_ELEMENTS,
                     MAX_STEPS, PLANE, SHAPE, SIMULATION, SOLVER, TOP, UNBREAKABLE)
from .tables import Where, read_table, table_entries, valid


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
        raw = path.read_bytes()
        # (a byte-order mark, as Notepad saves UTF-8, read as "Invalid statement" at line 1)
        data = tomllib.loads(raw.removeprefix(b"\xef\xbb\xbf").decode("utf-8"))
    except FileNotFoundError:
        raise SceneError([f"{path}: scene file not found"]) from None
    except IsADirectoryError:
        raise SceneError([f"{path}: is a folder, not a scene file"]) from None
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
    top = read_table(data, TOP, Where(source, "top level"), problems)
    simulation = _parse_simulation(top["simulation"], source, problems)
    planes = tuple(_parse_plane(entry, source, i, problems)
                   for i, entry in enumerate(table_entries(top["planes"], "planes", source, problems)))
    bodies = []
    first_index = {}
    for i, entry in enumerate(table_entries(top["bodies"], "bodies", source, problems)):
        body = _parse_body(entry, source, i, base_dir, problems)
        if isinstance(body.name, str):
            if body.name in first_index:
                problems.append(_body_where(source, i, body.name).problem(
                    "name", f"must be unique, got {toml_text(body.name)} again "
                            f"(first used by bodies[{first_index[body.name]}])"))
            if not body.name.isprintable():
                problems.append(_body_where(source, i, body.name).problem(
                    "name", "must have no control characters or line separators (a line break, a tab)"))
            first_index.setdefault(body.name, i)
        bodies.append(body)
    if not bodies and isinstance(top["bodies"], (list, tuple)):       # none given (a bad value is reported)
        problems.append(Where(source, "top level").problem("bodies", "needs at least one [[bodies]] table"))
    if problems:
        raise SceneError(problems)
    return Scene(simulation.name, Path(source), simulation, planes, tuple(bodies), data)


def _parse_simulation(table, source, problems):
    where = Where(source, "[simulation]")
    values = read_table(table if isinstance(table, dict) else {}, SIMULATION, where, problems)
    if values["name"] is None:
        values["name"] = Path(source).stem
        if len(values["name"].encode()) > NAME_BYTES:
            problems.append(where.problem("name", f"is the file's name, {len(values['name'].encode())} "
                                                  f"bytes, too long for the run's file names (at most "
                                                  f"{NAME_BYTES}): give a shorter name here"))
    elif valid(values["name"]) and not _plain_name(values["name"]):
        problems.append(where.problem("name", f"must be a plain name (output goes to outputs/<name>/ "
                                              f"and <name>.pvd: no '/' or '\\', no leading '.', "
                                              f"no control characters), got {toml_text(values['name'])}"))
    elif valid(values["name"]) and len(values["name"].encode()) > NAME_BYTES:
        problems.append(where.problem("name", f"must be at most {NAME_BYTES} bytes long (it names the "
                                              f"run's files, <name>.pvd and their temporary copies), "
                                              f"got {len(values['name'].encode())}"))
    solver_table = values.pop("solver")
    solver_where = Where(source, "[simulation.solver]")
    solver_table = solver_table if isinstance(solver_table, dict) else {}
    solver = Solver(**read_table(solver_table, SOLVER, solver_where, problems))
    if valid(values["dt"], values["duration"]) and values["dt"] > values["duration"]:
        problems.append(where.problem("dt", f"must be <= duration ({toml_text(values['duration'])} s), "
                                            f"got {toml_text(values['dt'])}"))
    elif valid(values["dt"], values["duration"]) and values["duration"] / values["dt"] > MAX_STEPS:
        problems.append(where.problem("dt", f"gives {values['duration'] / values['dt']:.3g} steps over "
                                            f"duration {toml_text(values['duration'])} s; at most "
                                            f"{MAX_STEPS:.0e} steps are allowed"))
    return Simulation(solver=solver, **values)


def _parse_plane(table, source, index, problems):
    values = read_table(table, PLANE, Where(source, f"[planes] (planes[{index}])"), problems)
    if valid(values["normal"]):
        length = math.hypot(*values["normal"])      # no squares: they underflow (1e-300) or overflow
        values["normal"] = tuple(c / length for c in values["normal"])
    return Plane(**values)


# the longest scene name (bytes, UTF-8): it names the run's files, whose temporary copies add about
# 40 bytes to it (hybrid.app.text_files.temporary_path), within a file system's 255
NAME_BYTES = 200


def _plain_name(name):
    """Whether ``name`` names a file in a folder: no separators, no leading dot, no control
    characters (a scene named "../x" or an absolute path wrote, and cleared, a folder outside outputs/)."""
    return not (set(name) & {"/", "\\"} or name.startswith(".") or not name.isprintable())


def _body_where(source, index, name):
    label = f"[bodies] {toml_text(name)} (bodies[{index}])" if isinstance(name, str) else f"[bodies] (bodies[{index}])"
    return Where(source, label)


def _parse_body(table, source, index, base_dir, problems):
    name = table.get("name") if isinstance(table, dict) else None
    where = _body_where(source, index, name)
    values = read_table(table, BODY, where, problems, base_dir)
    given = set(table) if isinstance(table, dict) else set()
    model = values["model"]

    # FEM fields: only for FEM models, and young is then required
    fem_model = model in FEM_MODELS
    if valid(model) and not fem_model:
        for f in BODY.fields:
            if f.fem and f.name in given:
                needs = "model = \"auto\"" if f.name == "auto" else "model = \"fem\" or \"auto\""
                problems.append(where.problem(f.name, f"needs {needs} (this body has model = \"{model}\")"))
    if fem_model and values["fixed"] is True:
        problems.append(where.problem("fixed", f"needs model = \"rigid\" (this body has model = "
                                               f"\"{model}\"; a deformable body is held by "
                                               f"[[bodies.anchors]])"))
    if fem_model and values["young"] is None:
        problems.append(where.problem("young", f"is required for model = \"{model}\": "
                                               f"{describe(BODY.field('young'))} (Pa)"))
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
        if valid(model) and not fem_model and isinstance(table.get("shape"), dict) and "refine" in table["shape"]:
            problems.append(where.nested("shape").problem(
                "refine", f"needs model = \"fem\" or \"auto\" (it refines a deformable box's tet "
                          f"mesh; this body has model = \"{model}\")"))
        if valid(model) and fem_model and isinstance(values["shape"], Shape) \
                and values["shape"].type not in deformable.FEM_SHAPES:
            problems.append(where.problem(
                "shape", f"cannot be meshed: {deformable.fem_shape_message(values['shape'].type)}"))
        elif valid(model) and isinstance(values["shape"], Shape):
            _check_element_count(values["shape"], fem_model, where, problems,
                                 values["order"] if valid(values["order"]) else None)
    if has_mesh and valid(values["mesh"]) and valid(model):
        _check_mesh(table["mesh"], values["mesh"], model, where, problems)

    _check_start_speed(values, where, problems)
    damping = values.pop("damping")
    values["damping"] = Damping()
    if fem_model and isinstance(damping, dict):
        values["damping"] = Damping(**read_table(damping, DAMPING, where.nested("damping"), problems))
    values["auto"] = _parse_auto(values.pop("auto"), values, given, where, problems)
    for key, section, kind in (("anchors", ANCHOR, Anchor), ("loads", LOAD, Load),
                               ("unbreakable", UNBREAKABLE, Unbreakable)):
        entries = values[key]
        values[key] = ()
        if fem_model and entries:
            entries = table_entries(entries, key, source, problems, where=where)
            named = f" {toml_text(name)}" if isinstance(name, str) else ""
            values[key] = tuple(
                kind(**read_table(entry, section, Where(
                    source, f"[bodies.{key}]{named} (bodies[{index}].{key}[{i}])"), problems))
                for i, entry in enumerate(entries))
    return Body(**values)


def _check_start_speed(values, where, problems):
    """A body whose ``velocity`` starts it faster than the check after every step allows
    (hybrid.coupling.stability.MAX_SPEED), told from the scene alone, so that a study refuses
    the variant before anything runs (the build checks the rest: rim and node speeds from the
    body's mesh, hybrid.app.deformable.beyond)."""
    from hybrid.coupling.stability import MAX_SPEED
    v = values["velocity"]
    speed = math.hypot(*v) if valid(v) else 0.0
    if speed > MAX_SPEED:
        problems.append(where.problem("velocity", f"starts it at a speed of {speed:.3g} m/s: a run "
                                                  f"stops as unstable beyond {MAX_SPEED:.0e} m/s "
                                                  f"(allowed: up to {MAX_SPEED:.0e} m/s)"))


def _parse_auto(table, values, given, where, problems):
    """The body's switching thresholds (``auto = { ... }``), defaults when absent."""
    if "auto" in given and values["model"] != "auto" and values["fragment_model"] != "auto" \
            and valid(values["model"], values["fragment_model"]) and values["model"] in FEM_MODELS:
        problems.append(where.problem("auto", "needs model = \"auto\" or fragment_model = \"auto\""))
    if not isinstance(table, dict):
        return Auto()
    out = read_table(table, AUTO, where.nested("auto"), problems)
    low, high = out["rigidify_strain"], out["elastify_strain"]
    if valid(low, high) and high <= low:
        default = "" if "elastify_strain" in table else " (the default)"
        low_default = "" if "rigidify_strain" in table else ", the default"
        problems.append(where.nested("auto").problem(
            "elastify_strain", f"must exceed rigidify_strain ({toml_text(low)}{low_default}), got "
                               f"{toml_text(high)}{default}"))
        return Auto()
    return Auto(**out) if all(valid(v) for v in out.values()) else Auto()


def _parse_shape(table, where, problems):
    """Validate the shape table; fields a shape type does not use are errors."""
    shape_where = where.nested("shape")
    if not isinstance(table, dict):
        return INVALID
    kind = table.get("type")
    if kind not in SHAPE.field("type").choices:
        # without a valid type we cannot tell which other fields belong; report the type only
        read_table(table, SHAPE, shape_where, problems, only=(SHAPE.field("type"),))
        return INVALID
    used = [f for f in SHAPE.fields if f.name == "type" or kind in f.shapes]
    takes = ", ".join(f.name for f in used if f.name != "type")
    for key in table:
        if key in SHAPE.names() and key not in [f.name for f in used]:
            problems.append(shape_where.problem(key, f"is not used by shape type \"{kind}\" "
                                                     f"(it takes: {takes})"))
    values = read_table(table, SHAPE, shape_where, problems, only=used)
    for key in ("size", "radius", "height"):
        value = values.get(key)
        if valid(value) and max(value if isinstance(value, tuple) else (value,)) > LARGEST_LENGTH:
            problems.append(shape_where.problem(key, f"must be at most {LARGEST_LENGTH:g} m (a larger "
                                                     f"length is a unit mistake), got {toml_text(value)}"))
            values[key] = INVALID
    height, radius = values.get("height"), values.get("radius")
    if kind == "capsule" and valid(height, radius) and height < 2 * radius:
        problems.append(shape_where.problem("height", f"must be >= 2 radius ({toml_text(2 * radius)} m) "
                                                      f"for a capsule, got {toml_text(height)}"))
    return Shape(**values)


def _check_element_count(shape, fem_model, where, problems, order=None):
    """Record a problem if meshing the shape at its ``resolution`` (or the builder's default, for
    the body's ``order``, None when not given) would make more elements than MAX_ELEMENTS
    (tetrahedra for a deformable body, surface triangles for a rigid one)."""
    r = shape.radius
    sizes = {"box": (shape.size,), "sphere": (r,)}.get(shape.type, (r, shape.height))
    if not valid(*sizes) or shape.resolution is INVALID:     # reported already
        return
    h = _mesh_resolution(shape, fem_model)
    if h is None:
        return
    # in floats, capped, so no size or resolution overflows an integer (inf counts are rejected)
    refine = shape.refine if shape.type == "box" and valid(shape.refine) else 1
    if shape.type == "box" and fem_model and shape.resolution is None:
        default = deformable.default_box_mesh(shape.size, order)
        h, count = default.resolution / refine, float(default.tet_count) * refine ** 3
    elif shape.type == "box":
        cells = [max(1.0, math.ceil(min(a / h, 1e18) - 1e-9)) * (refine if fem_model else 1)
                 for a in shape.size]
        count = 6 * cells[0] * cells[1] * cells[2] if fem_model else \
            4 * (cells[0] * cells[1] + cells[1] * cells[2] + cells[2] * cells[0])
    else:
        length = 2 * r if shape.type == "sphere" else shape.height
        across = 2 * r / h
        count = 6 * across * across * (length / h) if fem_model else \
            2 * (2 * math.pi * r * length + 4 * math.pi * r * r) / h / h
    if count > MAX_ELEMENTS:
        kind = "tetrahedra" if fem_model else "surface triangles"
        given = f"= {toml_text(h)} m" if shape.resolution is not None else \
            f"is not given, and its default ({h:.3g} m for this shape)"
        problems.append(where.nested("shape").problem(
            "resolution", f"{given} would mesh the shape into about {count:.2g} {kind}; at "
                          f"most {MAX_ELEMENTS:.0e} are allowed (use a coarser resolution)"))


def _mesh_resolution(shape, fem_model):
    """The edge length (m) a shape is meshed at: its ``resolution``, else the builder's default;
    None for rigid boxes and spheres, whose default meshes are small whatever their size."""
    if shape.resolution is not None:
        return shape.resolution
    if fem_model:
        return deformable.default_resolution(shape)
    if shape.type in ("cylinder", "capsule"):        # rigid.shapes: segments of the default circle
        return 2 * math.pi * shape.radius / CIRCLE_DEFAULT_SEGMENTS
    return None


def _check_mesh(written, resolved, model, where, problems):
    """Record a problem if the mesh file is missing, unreadable or unusable for ``model`` (what
    it warns of is told as the body is built)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", geometry.MeshWarning)
            if model in FEM_MODELS:
                mesh = geometry.read_mesh(resolved)
                geometry.tets_from_mesh(mesh, resolved)
                geometry.surface_from_mesh(mesh, resolved)
            else:                       # (read once for the bodies of one file)
                geometry.load_surface(resolved)
    except geometry.MeshError as error:
        problems.append(where.problem("mesh", f"= \"{written}\" (resolved to {resolved}): {error.reason}"))
