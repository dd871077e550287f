"""Scene files: the example parses as written, and every kind of mistake is reported with the file,
table and field named, all problems at once, without tracebacks."""
import json
import math
import shutil
import warnings
from pathlib import Path

import meshio
import numpy as np
import pytest

from hybrid import Simulation
from hybrid.app import geometry
from hybrid.app.scene import (SceneError, load_scene, parse_scene, reference_markdown, validate_command)

HERE = Path(__file__).parent
ROOT = HERE.parent

BODY = '''
[[bodies]]
name = "box"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
'''


# ----------------------------------------------------------------------------- mesh fixtures

CUBE_POINTS = np.array([[x, y, z] for z in (0.0, 1.0) for y in (0.0, 1.0) for x in (0.0, 1.0)]) - 0.5
# six tets around the 0-7 diagonal (Kuhn subdivision); half of them are negatively oriented
CUBE_TETS = np.array([[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]])
# outward quads of the unit cube (vertex index = x + 2y + 4z)
CUBE_QUADS = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]])


def cube_triangles():
    return CUBE_QUADS[:, [0, 1, 2, 0, 2, 3]].reshape(-1, 3)


def write_tet_cube(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    meshio.write(path, meshio.Mesh(CUBE_POINTS, [("tetra", CUBE_TETS)]))
    return path


def write_scene(tmp_path, text, name="scene.toml"):
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def problems_of(path):
    with pytest.raises(SceneError) as info:
        load_scene(path)
    return info.value.problems


def only_problem(path):
    problems = problems_of(path)
    assert len(problems) == 1, problems
    assert problems[0].startswith(f"{path}: "), problems[0]
    return problems[0]


# ----------------------------------------------------------------------------- valid scenes

def test_example_scene_parses_with_the_values_written():
    scene = load_scene(HERE / "scenes" / "example.toml")
    sim = scene.simulation
    assert scene.name == sim.name == "example"
    assert (sim.duration, sim.dt, sim.gravity, sim.output_fps) == (2.0, 0.001, (0.0, 0.0, -9.81), 60.0)
    assert (sim.solver.iterations, sim.solver.contact_margin) == (20, 0.005)
    [plane] = scene.planes
    assert plane.point == (0, 0, 0) and plane.normal == (0, 0, 1)
    assert (plane.friction, plane.restitution) == (0.5, 0.0)
    [body] = scene.bodies
    assert (body.name, body.model, body.mesh) == ("box", "rigid", None)
    assert body.shape.type == "box" and body.shape.size == (0.1, 0.1, 0.1)
    assert body.shape.radius is None and body.shape.resolution is None
    assert body.density == 1000.0 and body.position == (0.0, 0.0, 1.0)
    assert body.orientation == (1.0, 0.0, 0.0, 0.0)
    assert body.velocity == body.angular_velocity == (0.0, 0.0, 0.0)
    assert (body.friction, body.restitution, body.fixed) == (0.5, 0.0, False)
    assert body.young is None and body.anchors == () and body.loads == ()
    assert scene.raw["bodies"][0]["name"] == "box"
    assert scene.source_path == HERE / "scenes" / "example.toml"


def test_missing_fields_take_their_defaults(tmp_path):
    path = write_scene(tmp_path, '[[bodies]]\nname = "ball"\nshape = { type = "sphere", radius = 0.2 }\n',
                       name="drop.toml")
    scene = load_scene(path)
    assert scene.name == "drop"
    assert scene.simulation.duration == 2.0 and scene.simulation.dt == 0.001
    assert scene.simulation.gravity == (0.0, 0.0, -9.81) and scene.planes == ()
    body = scene.bodies[0]
    assert body.model == "rigid" and body.density == 1000.0 and body.orientation == (1, 0, 0, 0)
    assert body.shape.radius == 0.2 and body.shape.size is None


def test_linear_and_corotated_solvers_default_to_cholmod_and_cg(tmp_path):
    solver = load_scene(write_scene(tmp_path, BODY)).simulation.solver
    assert (solver.linear_solver, solver.corotated_solver) == ("cholmod", "cg")
    path = write_scene(tmp_path, '[simulation.solver]\nlinear_solver = "superlu"\n'
                                 'corotated_solver = "lu"\n' + BODY)
    solver = load_scene(path).simulation.solver
    assert (solver.linear_solver, solver.corotated_solver) == ("superlu", "lu")


def test_solver_choices_reach_every_fem_body(tmp_path):
    from hybrid.app.build import build
    soft = ('[[bodies]]\nname = "{}"\nmodel = "fem"\nyoung = 1e5\nframe = "{}"\n'
            'shape = {{ type = "box", size = [0.1, 0.1, 0.1] }}\nposition = [{}, 0, 0]\n')
    bodies = soft.format("a", "floating", 0.0) + soft.format("b", "corotated", 0.5)
    for choices in ('', 'linear_solver = "superlu"\ncorotated_solver = "lu"\n'):
        model, _ = build(load_scene(write_scene(tmp_path, "[simulation.solver]\n" + choices + bodies)))
        expected = ("superlu", "lu") if choices else ("cholmod", "cg")
        assert [(m.linear_solver, m.corotated_solver) for m in model.fem] == [expected] * 2


@pytest.mark.parametrize("line, expected", [
    ('linear_solver = "umfpack"', 'field \'linear_solver\' must be one of "cholmod", "superlu", got "umfpack"'),
    ('corotated_solver = "gmres"', 'field \'corotated_solver\' must be one of "cg", "lu", got "gmres"'),
])
def test_unknown_solver_choice_is_named_with_the_allowed_ones(tmp_path, line, expected):
    path = write_scene(tmp_path, f"[simulation.solver]\n{line}\n" + BODY)
    assert only_problem(path) == f"{path}: [simulation.solver]: {expected}"


def test_fem_scene_reads_every_field_and_normalises_vectors(tmp_path):
    path = tmp_path / "fem_full.toml"
    shutil.copy(HERE / "scenes" / "fem_full.toml", path)
    write_tet_cube(tmp_path / "meshes" / "cube.vtu")
    scene = load_scene(path)
    assert scene.name == "beam"
    assert scene.simulation.solver.iterations == 40 and scene.simulation.solver.contact_margin == 0.0
    assert scene.planes[0].normal == (0.0, 0.0, 1.0)
    beam, ball = scene.bodies
    assert beam.mesh == (tmp_path / "meshes" / "cube.vtu").resolve()
    assert (beam.young, beam.poisson, beam.frame, beam.order) == (1e6, 0.45, "corotated", 2)
    assert (beam.mass_matrix, beam.integrator) == ("consistent", "newmark")
    assert beam.damping.mass == 0.1 and beam.damping.stiffness == 0.001
    assert beam.anchors[0].box == ((-1.0, -1.0, -1.0), (-0.4, 1.0, 1.0))
    assert beam.anchors[0].velocity == (0.0, 0.0, 0.0)
    assert beam.loads[0].force == (0.0, 0.0, -10.0)
    assert math.isclose(sum(c * c for c in beam.orientation), 1.0, abs_tol=1e-15)
    assert ball.shape == ball.shape.__class__("capsule", None, 0.1, 0.2, 0.02)


def test_relative_mesh_paths_resolve_against_the_scene_folder(tmp_path, monkeypatch):
    sub = tmp_path / "sub"
    sub.mkdir()
    meshio.write(sub / "box.obj", meshio.Mesh(CUBE_POINTS, [("triangle", cube_triangles())]))
    meshio.write(sub / "quads.vtu", meshio.Mesh(CUBE_POINTS, [("quad", CUBE_QUADS)]))
    write_scene(sub, '[[bodies]]\nname = "a"\nmesh = "box.obj"\n'
                            '[[bodies]]\nname = "b"\nmesh = "quads.vtu"\n')
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    scene = load_scene(Path("..") / "sub" / "scene.toml")
    assert [b.mesh for b in scene.bodies] == [(sub / "box.obj").resolve(), (sub / "quads.vtu").resolve()]


def test_orientation_within_tolerance_is_renormalised(tmp_path):
    path = write_scene(tmp_path, BODY + "orientation = [1.0000005, 0.0, 0.0, 0.0]\n")
    assert load_scene(path).bodies[0].orientation == (1.0, 0.0, 0.0, 0.0)


# ----------------------------------------------------------------------------- one kind of mistake each

@pytest.mark.parametrize("text, table, key", [
    ("bodys = []\n" + BODY, "top level", "bodys"),
    ("[simulation]\ndtt = 0.1\n" + BODY, "[simulation]", "dtt"),
    ("[simulation.solver]\niteration = 3\n" + BODY, "[simulation.solver]", "iteration"),
    ("[[planes]]\nnormals = [0, 0, 1]\n" + BODY, "[planes] (planes[0])", "normals"),
    (BODY + "mass = 3.0\n", '[bodies] "box" (bodies[0])', "mass"),
    ('[[bodies]]\nname = "box"\nshape = { type = "box", size = [1, 1, 1], sise = 2 }\n',
     '[bodies] "box" (bodies[0])', "shape.sise"),
    ('[[bodies]]\nname = "b"\nmodel = "fem"\nyoung = 1e5\nshape = { type = "sphere", radius = 1 }\n'
     'damping = { mas = 1.0 }\n', '[bodies] "b" (bodies[0])', "damping.mas"),
    ('[[bodies]]\nname = "b"\nmodel = "fem"\nyoung = 1e5\nshape = { type = "sphere", radius = 1 }\n'
     '[[bodies.anchors]]\nbox = [[0, 0, 0], [1, 1, 1]]\nvelocty = [0, 0, 0]\n',
     '[bodies.anchors] "b" (bodies[0].anchors[0])', "velocty"),
    ('[[bodies]]\nname = "b"\nmodel = "fem"\nyoung = 1e5\nshape = { type = "sphere", radius = 1 }\n'
     '[[bodies.loads]]\nbox = [[0, 0, 0], [1, 1, 1]]\nforce = [0, 0, 1]\nforces = 1\n',
     '[bodies.loads] "b" (bodies[0].loads[0])', "forces"),
])
def test_unknown_key_is_named_with_its_table_and_the_allowed_keys(tmp_path, text, table, key):
    path = write_scene(tmp_path, text)
    message = only_problem(path)
    assert f"{path}: {table}: unknown key '{key}'" in message
    assert "allowed:" in message


def test_unknown_key_suggests_the_closest_field(tmp_path):
    message = only_problem(write_scene(tmp_path, BODY + "densty = 3.0\n"))
    assert "did you mean 'density'?" in message


@pytest.mark.parametrize("line, field, expected", [
    ('density = "heavy"', "density", 'must be a number > 0, got "heavy"'),
    ("density = true", "density", "must be a number > 0, got true"),
    ("fixed = 1", "fixed", "must be true or false, got 1"),
    ("position = [0.0, 1.0]", "position", "must be a list of 3 numbers, got [0.0, 1.0]"),
    ('velocity = [0.0, "a", 0.0]', "velocity", "must be a list of 3 numbers"),
    ("angular_velocity = [true, 0, 0]", "angular_velocity", "must be a list of 3 numbers"),
    ("friction = nan", "friction", "must be a number >= 0, got nan"),
    ('model = "soft"', "model", 'must be one of "rigid", "fem", "auto", got "soft"'),
])
def test_wrong_type_names_file_table_field_and_what_is_allowed(tmp_path, line, field, expected):
    path = write_scene(tmp_path, BODY + line + "\n")
    message = only_problem(path)
    assert message.startswith(f"{path}: [bodies] \"box\" (bodies[0]): field '{field}' {expected}")


def test_integer_fields_reject_floats_and_number_fields_accept_ints(tmp_path):
    path = write_scene(tmp_path, "[simulation]\nduration = 3\n[simulation.solver]\niterations = 2.5\n" + BODY)
    message = only_problem(path)
    assert message == f"{path}: [simulation.solver]: field 'iterations' must be an integer >= 1, got 2.5"


def test_negative_density_message_is_exact(tmp_path):
    path = write_scene(tmp_path, BODY + "density = -5.0\n")
    assert only_problem(path) == (f"{path}: [bodies] \"box\" (bodies[0]): field 'density' must be a "
                                  "number > 0, got -5.0")


def test_zero_quaternion_is_rejected(tmp_path):
    message = only_problem(write_scene(tmp_path, BODY + "orientation = [0, 0, 0, 0]\n"))
    assert "[bodies] \"box\" (bodies[0]): field 'orientation' must be a unit quaternion" in message
    assert message.endswith("got [0, 0, 0, 0] with norm 0 (allowed: within 0.001 of 1)")


def test_non_unit_quaternion_is_rejected_with_its_norm(tmp_path):
    message = only_problem(write_scene(tmp_path, BODY + "orientation = [1.0, 1.0, 0.0, 0.0]\n"))
    assert "field 'orientation' must be a unit quaternion" in message
    assert "got [1.0, 1.0, 0.0, 0.0] with norm 1.41421356" in message


def test_a_hand_written_quaternion_is_renormalised(tmp_path):
    """Four digits of a quarter turn about x (norm 0.99999) are a unit quaternion to the scene;
    the body is turned by exactly a quarter turn."""
    scene = load_scene(write_scene(tmp_path, BODY + "orientation = [0.7071, 0.7071, 0.0, 0.0]\n"))
    q = np.asarray(scene.bodies[0].orientation)
    np.testing.assert_allclose(q, [np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0], rtol=0, atol=1e-15)


def test_missing_mesh_file_reports_written_and_resolved_paths(tmp_path):
    path = write_scene(tmp_path, '[[bodies]]\nname = "m"\nmesh = "meshes/nope.vtu"\n')
    message = only_problem(path)
    assert "[bodies] \"m\" (bodies[0]): field 'mesh' = \"meshes/nope.vtu\"" in message
    assert str((tmp_path / "meshes" / "nope.vtu").resolve()) in message
    assert "file not found" in message


def test_unreadable_mesh_file_is_a_problem_not_a_traceback(tmp_path):
    (tmp_path / "junk.vtu").write_bytes(bytes(range(256)) * 4)
    message = only_problem(write_scene(tmp_path, '[[bodies]]\nname = "m"\nmesh = "junk.vtu"\n'))
    assert "field 'mesh' = \"junk.vtu\"" in message and "cannot read mesh" in message


def test_an_empty_mesh_file_is_said_to_be_empty(tmp_path):
    """An empty file read as "cannot read mesh (need at least one array to concatenate)"."""
    (tmp_path / "empty.stl").write_bytes(b"")
    message = only_problem(write_scene(tmp_path, '[[bodies]]\nname = "m"\nmesh = "empty.stl"\n'))
    assert "field 'mesh' = \"empty.stl\"" in message and message.endswith("the file is empty")
    (tmp_path / "comments.obj").write_text("# nothing but a comment\n")
    message = only_problem(write_scene(tmp_path, '[[bodies]]\nname = "m"\nmesh = "comments.obj"\n'))
    assert message.endswith("the file holds no points"), message
    meshio.write(tmp_path / "none.vtu", meshio.Mesh(np.zeros((0, 3)), [("tetra", np.zeros((0, 4), int))]))
    message = only_problem(write_scene(tmp_path, '[[bodies]]\nname = "m"\nmesh = "none.vtu"\n'))
    assert message.endswith("the file holds no points or cells"), message


def test_open_mesh_reports_its_boundary_edges(tmp_path):
    meshio.write(tmp_path / "open.obj", meshio.Mesh(CUBE_POINTS, [("triangle", cube_triangles()[:-1])]))
    message = only_problem(write_scene(tmp_path, '[[bodies]]\nname = "m"\nmesh = "open.obj"\n'))
    assert "field 'mesh' = \"open.obj\"" in message
    assert "not closed: 3 boundary edges, 0 non-manifold edges" in message


def test_fem_mesh_needs_tetrahedra(tmp_path):
    meshio.write(tmp_path / "surface.obj", meshio.Mesh(CUBE_POINTS, [("triangle", cube_triangles())]))
    text = '[[bodies]]\nname = "m"\nmodel = "fem"\nyoung = 1e6\nmesh = "surface.obj"\n'
    message = only_problem(write_scene(tmp_path, text))
    assert "field 'mesh'" in message and "no tetra or tetra10 cells (found: triangle)" in message


@pytest.mark.parametrize("dt", ["0.0", "-0.001"])
def test_non_positive_dt_is_rejected(tmp_path, dt):
    path = write_scene(tmp_path, f"[simulation]\ndt = {dt}\n" + BODY)
    assert only_problem(path) == f"{path}: [simulation]: field 'dt' must be a number > 0, got {dt}"


def test_dt_longer_than_duration_is_rejected(tmp_path):
    path = write_scene(tmp_path, "[simulation]\nduration = 0.01\ndt = 0.1\n" + BODY)
    assert only_problem(path) == f"{path}: [simulation]: field 'dt' must be <= duration (0.01 s), got 0.1"


def test_a_number_of_steps_beyond_reach_is_rejected(tmp_path):
    path = write_scene(tmp_path, "[simulation]\nduration = 1e300\ndt = 1e-300\n" + BODY)
    message = only_problem(path)      # was an OverflowError traceback when the run began
    assert "field 'dt' gives inf steps" in message
    assert "at most 1e+09 steps are allowed" in message


@pytest.mark.parametrize("shape, field, expected", [
    ('{ type = "box", size = [0.1, -0.1, 0.1] }', "shape.size", "must be a list of 3 numbers > 0"),
    ('{ type = "box", size = [0.1, 0.1] }', "shape.size", "must be a list of 3 numbers > 0"),
    ('{ type = "box" }', "shape.size", "is required"),
    ('{ type = "sphere", radius = 0 }', "shape.radius", "must be a number > 0, got 0"),
    ('{ type = "sphere", radius = 1, size = [1, 1, 1] }', "shape.size", 'is not used by shape type "sphere"'),
    ('{ type = "cylinder", radius = 1 }', "shape.height", "is required"),
    ('{ type = "capsule", radius = 0.1, height = 0.1 }', "shape.height", "must be >= 2 radius (0.2 m)"),
    ('{ type = "sphere", radius = 1, resolution = -1 }', "shape.resolution", "must be a number > 0"),
    ('{ type = "cone", radius = 1 }', "shape.type", 'must be one of "box", "sphere"'),
    ('{ radius = 1 }', "shape.type", "is required"),
    ('"sphere"', "shape", 'must be a table, got "sphere"'),
])
def test_bad_shape_values_name_the_shape_field(tmp_path, shape, field, expected):
    path = write_scene(tmp_path, f'[[bodies]]\nname = "s"\nshape = {shape}\n')
    message = only_problem(path)
    assert message.startswith(f"{path}: [bodies] \"s\" (bodies[0]): field '{field}' {expected}"), message


@pytest.mark.parametrize("line, field", [
    ("young = 1e6", "young"),
    ("poisson = 0.3", "poisson"),
    ('frame = "corotated"', "frame"),
    ("damping = { mass = 1.0 }", "damping"),
    ("[[bodies.anchors]]\nbox = [[0, 0, 0], [1, 1, 1]]", "anchors"),
])
def test_fem_field_on_a_rigid_body_says_it_needs_model_fem(tmp_path, line, field):
    path = write_scene(tmp_path, BODY + line + "\n")
    message = only_problem(path)
    assert message.startswith(f"{path}: [bodies] \"box\" (bodies[0]): field '{field}' needs model = \"fem\"")


def test_fem_body_requires_young(tmp_path):
    text = '[[bodies]]\nname = "f"\nmodel = "fem"\nshape = { type = "sphere", radius = 1 }\n'
    path = write_scene(tmp_path, text)
    assert "field 'young' is required for model = \"fem\"" in only_problem(path)


def test_poisson_ratio_of_one_half_is_rejected(tmp_path):
    text = ('[[bodies]]\nname = "f"\nmodel = "fem"\nyoung = 1e6\npoisson = 0.5\n'
            'shape = { type = "sphere", radius = 1 }\n')
    path = write_scene(tmp_path, text)
    assert only_problem(path) == (f"{path}: [bodies] \"f\" (bodies[0]): field 'poisson' must be a number "
                                  "in (-1, 0.5), got 0.5")


def test_anchor_box_with_min_above_max_is_rejected(tmp_path):
    text = ('[[bodies]]\nname = "f"\nmodel = "fem"\nyoung = 1e6\nshape = { type = "sphere", radius = 1 }\n'
            '[[bodies.anchors]]\nbox = [[0, 2, 0], [1, 1, 1]]\n')
    message = only_problem(write_scene(tmp_path, text))
    assert "[bodies.anchors] \"f\" (bodies[0].anchors[0]): field 'box' must be a box" in message
    assert "min <= max" in message


def test_duplicate_body_names_are_rejected(tmp_path):
    path = write_scene(tmp_path, BODY + BODY)
    message = only_problem(path)
    assert message.startswith(f"{path}: [bodies] \"box\" (bodies[1]): field 'name' must be unique")
    assert "bodies[0]" in message


@pytest.mark.parametrize("extra, word", [('mesh = "box.obj"', "both"), ("", "neither")])
def test_body_needs_exactly_one_of_shape_or_mesh(tmp_path, extra, word):
    meshio.write(tmp_path / "box.obj", meshio.Mesh(CUBE_POINTS, [("triangle", cube_triangles())]))
    shape = 'shape = { type = "sphere", radius = 1 }\n' if word == "both" else ""
    path = write_scene(tmp_path, f'[[bodies]]\nname = "b"\n{shape}{extra}\n')
    message = only_problem(path)
    assert message == (f"{path}: [bodies] \"b\" (bodies[0]): needs exactly one of field 'shape' or "
                       f"field 'mesh', got {word}")


def test_bodies_written_as_a_single_table_is_explained(tmp_path):
    path = write_scene(tmp_path, '[bodies]\nname = "b"\n')
    assert "field 'bodies' must be an array of tables ([[bodies]])" in only_problem(path)


def test_all_problems_are_reported_together(tmp_path):
    text = ("[simulation]\ndt = -1.0\nspeed = 2\n"
            "[[planes]]\nnormal = [0, 0, 0]\n"
            '[[bodies]]\nname = "a"\ndensity = -5.0\nyoung = 1e6\nshape = { type = "sphere", radius = 1 }\n'
            '[[bodies]]\nname = "b"\norientation = [0, 0, 0, 0]\nmesh = "missing.vtu"\n')
    path = write_scene(tmp_path, text)
    problems = problems_of(path)
    expected = ["[simulation]: unknown key 'speed'", "[simulation]: field 'dt'",
                "[planes] (planes[0]): field 'normal' must be a non-zero list",
                "[bodies] \"a\" (bodies[0]): field 'density'", "[bodies] \"a\" (bodies[0]): field 'young'",
                "[bodies] \"b\" (bodies[1]): field 'orientation'", "[bodies] \"b\" (bodies[1]): field 'mesh'"]
    assert len(problems) == len(expected), problems
    for fragment, problem in zip(expected, problems):
        assert problem.startswith(f"{path}: {fragment}"), (fragment, problem)


def test_parse_scene_accepts_a_dict(tmp_path):
    data = {"bodies": [{"name": "x", "shape": {"type": "sphere", "radius": 0.5}}]}
    scene = parse_scene(data, "inline.toml", tmp_path)
    assert scene.name == "inline" and scene.bodies[0].shape.radius == 0.5
    with pytest.raises(SceneError) as info:
        parse_scene({"bodies": [{"name": 1}]}, "inline.toml", tmp_path)
    assert any(p.startswith("inline.toml: [bodies] (bodies[0]): field 'name'") for p in info.value.problems)


# ----------------------------------------------------------------------------- command line

def test_validate_command_prints_every_problem_without_traceback(tmp_path, capsys):
    path = write_scene(tmp_path, BODY + "density = -5.0\nfriction = -1\n")
    assert validate_command(path) == 2
    out, err = capsys.readouterr()
    assert out == "" and "Traceback" not in err
    assert "field 'density'" in err and "field 'friction'" in err and "2 problems" in err


def test_validate_command_accepts_the_example(capsys):
    path = HERE / "scenes" / "example.toml"
    assert validate_command(path) == 0
    assert capsys.readouterr().out == f"OK: {path}: 1 bodies, 1 planes\n"


def test_validate_command_reports_toml_syntax_errors_with_line_and_column(tmp_path, capsys):
    path = write_scene(tmp_path, "[simulation]\ndt = = 0.1\n")
    assert validate_command(path) == 2
    err = capsys.readouterr().err
    assert f"{path}: invalid TOML" in err and "line 2, column" in err and "Traceback" not in err


@pytest.mark.parametrize("content", [None, b"\xff\xfe\x00 not text"])
def test_validate_command_reports_missing_or_binary_files(tmp_path, capsys, content):
    path = tmp_path / "scene.toml"
    if content is not None:
        path.write_bytes(content)
    assert validate_command(path) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{path}: ") and "Traceback" not in err


# ----------------------------------------------------------------------------- geometry and docs

def test_tet_mesh_surface_is_closed_outward_with_the_cube_volume(tmp_path):
    path = write_tet_cube(tmp_path / "cube.vtu")
    vertices, triangles = geometry.load_surface(path)
    assert vertices.shape == (8, 3) and triangles.shape == (12, 3)
    from rigid import trimesh
    assert trimesh.is_closed(triangles)
    assert math.isclose(trimesh.signed_volume(vertices, triangles), 1.0)


def test_tet_mesh_loader_flips_negative_tets_with_a_warning_naming_them(tmp_path):
    path = write_tet_cube(tmp_path / "cube.vtu")
    with pytest.warns(geometry.MeshWarning) as caught:
        points, tets, order = geometry.load_tet_mesh(path)
    # tets 1, 2 and 5 of CUBE_TETS have negative volume; the message names the file and them
    assert [str(w.message) for w in caught] == [
        f"{path}: 3 of 6 tets were inverted (negative volume) and have been reoriented: tets 1, 2, 5"]
    assert order == 1 and tets.shape == (6, 4)
    p = points[tets]
    volume = np.einsum("ij,ij->i", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0])) / 6
    assert np.allclose(volume, 1 / 6)


def test_a_surface_written_as_separate_triangles_is_joined_where_its_corners_coincide(tmp_path):
    """An exporter that writes each triangle with its own three corners (a triangle soup) gave
    "surface is not closed: 72 boundary edges" for .obj and .vtu, while .stl (whose reader
    merges corners) was taken: the corners are now joined where they coincide, in every format,
    and the cube's volume and outward orientation come out as from a shared-vertex file."""
    from rigid import trimesh
    triangles = CUBE_QUADS[:, [0, 1, 2, 0, 2, 3]].reshape(-1, 3)
    soup = CUBE_POINTS[triangles].reshape(-1, 3) * 2.0            # 36 corners for 8 vertices
    rounded = soup + np.random.default_rng(5).uniform(-1e-7, 1e-7, soup.shape)     # single precision
    for name, corners in (("soup.obj", soup), ("soup.vtu", soup), ("rounded.vtu", rounded)):
        meshio.write(tmp_path / name, meshio.Mesh(corners, [("triangle", np.arange(36).reshape(-1, 3))]))
        vertices, faces = geometry.load_surface(tmp_path / name)
        assert vertices.shape == (8, 3) and faces.shape == (12, 3) and trimesh.is_closed(faces)
        assert math.isclose(trimesh.signed_volume(vertices, faces), 8.0, rel_tol=1e-6)


def test_a_tet_mesh_in_pieces_that_share_no_node_is_warned_of(tmp_path):
    """A body meshed as two halves whose interface nodes are doubled (a common export slip) was
    taken silently, and its free half fell away from the anchored one: the loader names the
    pieces and the doubled nodes."""
    right = CUBE_POINTS + [1.0, 0.0, 0.0]                 # shares the face x = 0.5, nodes doubled
    meshio.write(tmp_path / "halves.vtu", meshio.Mesh(np.vstack([CUBE_POINTS, right]),
                                                       [("tetra", np.vstack([CUBE_TETS, CUBE_TETS + 8]))]))
    with pytest.warns(geometry.MeshWarning) as caught:
        geometry.load_tet_mesh(tmp_path / "halves.vtu")
    said = [str(w.message) for w in caught if "share no node" in str(w.message)]
    assert len(said) == 1 and "form 2 pieces that share no node (the largest has 6 of 12 tets)" in said[0]
    assert "4 nodes lie on others" in said[0]
    with pytest.warns(geometry.MeshWarning) as caught:                 # one piece: no such warning
        geometry.load_tet_mesh(write_tet_cube(tmp_path / "cube.vtu"))
    assert not [w for w in caught if "share no node" in str(w.message) or "lie on" in str(w.message)]
    # one piece, but one tet takes a copy of a corner node: its faces there join nothing
    tets = CUBE_TETS.copy()
    tets[0][tets[0] == 0] = 8
    meshio.write(tmp_path / "slit.vtu", meshio.Mesh(np.vstack([CUBE_POINTS, CUBE_POINTS[:1]]),
                                                    [("tetra", tets)]))
    with pytest.warns(geometry.MeshWarning, match="1 of its nodes lie on others, so the tets on either "
                                                  "side of them are not joined there"):
        geometry.load_tet_mesh(tmp_path / "slit.vtu")


def test_a_mesh_hundreds_of_metres_across_is_said_to_be_perhaps_in_millimetres(tmp_path):
    """A 0.4 m box written in millimetres read as a 400 m box of 1.6e10 kg with no word."""
    meshio.write(tmp_path / "mm.vtu", meshio.Mesh(CUBE_POINTS * 400.0, [("tetra", CUBE_TETS)]))
    for load in (geometry.load_tet_mesh, geometry.load_surface):
        with pytest.warns(geometry.MeshWarning, match="spans 400 m .*check the file's units"):
            load(tmp_path / "mm.vtu")
    with pytest.warns(geometry.MeshWarning) as caught:                      # 1 m: no such word
        geometry.load_tet_mesh(write_tet_cube(tmp_path / "cube.vtu"))
    assert not [w for w in caught if "units" in str(w.message)]


def test_a_stray_node_does_not_make_a_mesh_large_and_a_mesh_body_started_deep_is_told_its_units(tmp_path):
    """A 1 m cube with one node no cell uses at (100, 100, 100) was said to span 100 m; a 50 mm
    part written in millimetres (50 m, not over 100) placed at 3 cm height was told only that it
    starts 25 m inside the ground."""
    far = np.vstack([CUBE_POINTS, [[150.0, 150.0, 150.0]]])
    meshio.write(tmp_path / "stray.vtu", meshio.Mesh(far, [("tetra", CUBE_TETS)]))
    for load in (geometry.load_tet_mesh, geometry.load_surface):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            load(tmp_path / "stray.vtu")
        assert not [w for w in caught if "units" in str(w.message)]
    meshio.write(tmp_path / "part.vtu", meshio.Mesh(CUBE_POINTS * 50.0, [("tetra", CUBE_TETS)]))
    for model in ("fem", "rigid"):
        young = "young = 1e9\n" if model == "fem" else ""
        text = (f'[[planes]]\n[[bodies]]\nname = "part"\nmodel = "{model}"\n{young}'
                f'mesh = "part.vtu"\nposition = [0.0, 0.0, 0.03]\n')
        (tmp_path / "part.toml").write_text(text)
        try:
            said = Simulation.from_toml(tmp_path / "part.toml").warnings
        except SceneError as error:
            said = error.problems
        told = [m for m in said if "inside a plane" in m]
        assert len(told) == 1 and "millimetres reads 1000 times too large" in told[0], said


def test_quadratic_tets_give_order_two_and_keep_edge_nodes_consistent(tmp_path):
    # one negatively oriented tetra10: corners swapped, edge nodes at the true midpoints
    corners = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1]], float)
    edges = [(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)]
    points = np.vstack([corners, [(corners[a] + corners[b]) / 2 for a, b in edges]])
    meshio.write(tmp_path / "t10.vtu", meshio.Mesh(points, [("tetra10", np.arange(10)[None])]))
    with pytest.warns(geometry.MeshWarning, match="1 of 1 tets were inverted .*: tets 0$"):
        points, tets, order = geometry.load_tet_mesh(tmp_path / "t10.vtu")
    assert order == 2
    tet = tets[0]
    for k, (a, b) in enumerate(edges):
        assert np.allclose(points[tet[4 + k]], (points[tet[a]] + points[tet[b]]) / 2)
    p = points[tet[:4]]
    assert np.dot(p[1] - p[0], np.cross(p[2] - p[0], p[3] - p[0])) > 0


def test_degenerate_tets_are_named_by_index(tmp_path):
    # tet 2 repeats a corner, tet 4 has its four corners on one face of the cube
    tets = np.vstack([CUBE_TETS[:2], [[0, 1, 1, 7]], CUBE_TETS[2:3], [[0, 1, 2, 3]]])
    meshio.write(tmp_path / "flat.vtu", meshio.Mesh(CUBE_POINTS, [("tetra", tets)]))
    with pytest.raises(geometry.MeshError, match=r"flat.vtu: 2 of 5 tets are degenerate .*: tets 2, 4$"):
        geometry.load_tet_mesh(tmp_path / "flat.vtu")
    text = '[[bodies]]\nname = "m"\nmodel = "fem"\nyoung = 1e6\nmesh = "flat.vtu"\n'
    assert only_problem(write_scene(tmp_path, text)).endswith("2 of 5 tets are degenerate (near-zero "
                                                              "volume): tets 2, 4")


def test_validate_and_run_print_the_reoriented_tets_as_a_warning(tmp_path, capsys):
    from hybrid.app.cli import main
    write_tet_cube(tmp_path / "cube.vtu")
    path = write_scene(tmp_path, '[simulation]\nduration = 0.002\ndt = 0.001\n[[bodies]]\nname = "m"\n'
                                 'model = "fem"\nyoung = 1e6\nmesh = "cube.vtu"\n')
    warning = "tets were inverted (negative volume) and have been reoriented: tets 1, 2, 5"
    assert main(["validate", str(path)]) == 0
    out, err = capsys.readouterr()
    assert out.startswith("OK:") and err.count(warning) == 1
    first, second, third = err.splitlines()[:3]     # what it is doing (a large mesh takes a while),
    assert "checking the built bodies: meshing and factorising 1 deformable body" in first
    assert second.startswith("mesh: 'm': ") and third.startswith("warning: ")  # the mesh, warnings
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    assert capsys.readouterr().err.count(warning) == 1


def test_mesh_errors_name_the_file(tmp_path):
    with pytest.raises(geometry.MeshError, match="nope.obj: file not found"):
        geometry.load_surface(tmp_path / "nope.obj")
    meshio.write(tmp_path / "lines.vtu", meshio.Mesh(CUBE_POINTS[:2], [("line", np.array([[0, 1]]))]))
    with pytest.raises(geometry.MeshError, match="lines.vtu: no triangle, quad or tetra cells"):
        geometry.load_surface(tmp_path / "lines.vtu")
    # a closed tetrahedron surface whose fourth corner lies in the plane of the other three
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, 0.25, 0]], float)
    flat_tris = np.array([[1, 3, 2], [0, 2, 3], [0, 3, 1], [0, 1, 2]])
    meshio.write(tmp_path / "flat.obj", meshio.Mesh(flat, [("triangle", flat_tris)]))
    with pytest.raises(geometry.MeshError, match="flat.obj: surface encloses zero volume"):
        geometry.load_surface(tmp_path / "flat.obj")


def test_committed_scene_reference_matches_the_schema():
    committed = (ROOT / "docs" / "scene_reference.md").read_text()
    assert committed == reference_markdown(), "run: python -m hybrid.app.scene > docs/scene_reference.md"


@pytest.mark.parametrize("model", ["fem", "auto"])
def test_fixed_on_a_deformable_body_is_refused_and_the_anchors_named(tmp_path, model):
    """``fixed`` holds a rigid body only: on a deformable body it was ignored (the body fell)."""
    path = write_scene(tmp_path, BODY + f'model = "{model}"\nyoung = 1e6\nfixed = true\n')
    assert only_problem(path) == (f"{path}: [bodies] \"box\" (bodies[0]): field 'fixed' needs "
                                  f"model = \"rigid\" (this body has model = \"{model}\"; a "
                                  "deformable body is held by [[bodies.anchors]])")


def _box_quads(half, offset=0.0):
    """A box's 8 corners (centred at ``offset``) and its 6 faces as quads facing outward."""
    return CUBE_POINTS * 2 * half + offset, CUBE_QUADS


@pytest.mark.parametrize("inner_written", ["inward", "outward"])
def test_a_surface_with_a_cavity_has_the_mass_of_its_shell_however_the_cavity_faces(tmp_path, inner_written):
    """A hollow box (outer side 0.4 m, cavity 0.2 m) whose cavity's wall is written facing out
    of the cavity added the cavity's volume (18 kg instead of 14 at 250 kg/m^3): each piece of
    a surface now faces away from the solid by how deep it lies among the others, so both ways
    of writing it weigh 250 * (0.064 - 0.008) = 14 kg, with the inertia of the shell; an island
    inside the cavity adds its own volume."""
    from rigid import trimesh
    from rigid.mass import mass_properties
    outer, quads = _box_quads(0.2)
    inner, _ = _box_quads(0.1)
    island, _ = _box_quads(0.025)
    inner_quads = quads if inner_written == "outward" else quads[:, ::-1]
    points = np.concatenate([outer, inner, island])
    faces = np.concatenate([quads, inner_quads + 8, quads[:, ::-1] + 16])   # the island written inward
    for name, count in (("hollow.obj", 2), ("island.obj", 3)):
        pieces = faces[: 6 * count]
        meshio.write(tmp_path / name, meshio.Mesh(points[: 8 * count], [("quad", pieces)]))
        vertices, triangles = geometry.load_surface(tmp_path / name)
        volume = 0.064 - 0.008 + (0.05 ** 3 if count == 3 else 0.0)
        assert math.isclose(trimesh.signed_volume(vertices, triangles), volume, rel_tol=1e-12)
        props = mass_properties(vertices, triangles, 250.0)
        mass, com, inertia = props.mass, props.com, props.inertia
        assert math.isclose(mass, 250.0 * volume, rel_tol=1e-12)
        # a centred box's moment about an axis through its centre: m a^2 / 6 (a its side)
        moment = 250.0 * (0.4 ** 5 - 0.2 ** 5 + (0.05 ** 5 if count == 3 else 0.0)) / 6
        assert np.allclose(np.diag(inertia), moment, rtol=1e-10) and np.allclose(com, 0.0, atol=1e-14)


def test_two_boxes_touching_at_a_corner_weigh_both_however_each_faces(tmp_path):
    """Two 0.2 m boxes meeting at one corner, written with the corner as one vertex and the
    second box facing inward, were one piece of surface to the orientation (pieces were joined
    through shared vertices), whose two signed volumes summed to zero: the file was refused as
    enclosing no volume. Pieces are joined through shared edges, so each box is oriented
    by itself: 2 * 250 * 0.008 = 4 kg, centred on the shared corner."""
    from rigid.mass import mass_properties
    first, quads = _box_quads(0.1)
    second = first + 0.2          # its corner (-0.1, -0.1, -0.1) + 0.2 is the first's (0.1, 0.1, 0.1)
    shared = np.argmin(second.sum(axis=1))
    corner = np.argmax(first.sum(axis=1))
    index = np.arange(8) + 8 - (np.arange(8) > shared)
    index[shared] = corner
    points = np.concatenate([first, np.delete(second, shared, axis=0)])
    faces = np.concatenate([quads, index[quads][:, ::-1]])
    meshio.write(tmp_path / "pair.obj", meshio.Mesh(points, [("quad", faces)]))
    vertices, triangles = geometry.load_surface(tmp_path / "pair.obj")
    assert len(vertices) == 15
    props = mass_properties(vertices, triangles, 250.0)
    assert math.isclose(props.mass, 4.0, rel_tol=1e-12)
    assert np.allclose(props.com, 0.1, atol=1e-14)


def test_a_strength_the_model_cannot_reach_or_its_weight_exceeds_is_warned_of(tmp_path, capsys):
    from hybrid import Simulation
    """``yield_stress = 1e12`` with ``young = 1e9`` (a yield strain of 1,000) and a 0.5 m column
    of 2,000 kg/m^3 with ``fracture_stress = 1 kPa`` (its weight makes 9.8 kPa at its base) were
    taken without a word; ordinary strengths are not warned of."""
    path = write_scene(tmp_path, """
[simulation]
duration = 0.01
[[planes]]
[[bodies]]
name = "block"
model = "fem"
young = 1e9
yield_stress = 1e12
shape = { type = "box", size = [0.1, 0.1, 0.5] }
position = [0.0, 0.0, 0.25]
[[bodies]]
name = "chalk"
model = "fem"
young = 1e9
density = 2000
fracture_stress = 1e3
shape = { type = "box", size = [0.1, 0.1, 0.5] }
position = [1.0, 0.0, 0.25]
[[bodies]]
name = "steel"
model = "fem"
young = 2e11
density = 7800
yield_stress = 2.5e8
fracture_stress = 5e8
shape = { type = "box", size = [0.1, 0.1, 0.5] }
position = [2.0, 0.0, 0.25]
""")
    assert validate_command(path, check=lambda scene: Simulation(scene).warnings) == 0
    err = capsys.readouterr().err
    assert "body 'block': yield_stress 1e+12 Pa over young 1e+09 Pa is a yield strain of 1e+03" in err
    weight = 2000 * 9.81 * 0.5
    assert f"body 'chalk': fracture_stress 1e+03 Pa is below the stress its own weight makes across " \
           f"its height (density g h = {weight:.3g} Pa)" in err
    assert "steel" not in err and err.count("warning:") == 2


def test_a_deformable_capsule_is_listed_among_the_files_other_problems(tmp_path):
    """A deformable body shaped as a capsule (no tet mesher for it) was told only once the file
    had no other problem (the shape is meshed as the scene is built): ``validate`` said the
    file's other problems and not it. It is now a problem of the file itself, told with them."""
    path = write_scene(tmp_path, """
[[bodies]]
name = "pill"
model = "auto"
young = 1e6
shape = { type = "capsule", radius = 0.05, height = 0.2 }
[[bodies]]
name = "box"
shape = { type = "box", size = [0.1, 0.1, -0.1] }
""")
    found = problems_of(path)
    assert any("\"pill\"" in p and "'shape' cannot be meshed" in p and "not 'capsule'" in p for p in found), found
    assert any("\"box\"" in p and "shape.size" in p for p in found), found


@pytest.mark.parametrize("name", ["/elsewhere", "../../escaped", "a/b", "a\\b", ".hidden", "two\nlines",
                                  "next\u0085line", "line\u2028separator"])
def test_a_scene_name_that_is_not_a_plain_name_is_refused(tmp_path, name):
    """A scene's output goes to outputs/<name>/: an absolute name or "../../x" wrote (and
    cleared the frames of) a folder outside outputs/. It must be a plain name."""
    text = "[simulation]\nname = " + json.dumps(name) + "\n" + BODY
    problem = only_problem(write_scene(tmp_path, text))
    assert "[simulation]: field 'name' must be a plain name" in problem


@pytest.mark.parametrize("name, size", [("x" * 201, 201), ("\u00e9" * 101, 202)])
def test_a_scene_name_too_long_for_a_file_name_is_refused_counting_its_bytes(tmp_path, name, size):
    """The name names <name>.pvd and its temporary copy: 300 letters passed validate and the run
    ended in a traceback (file name too long), leaving an empty frames/ folder."""
    text = "[simulation]\nname = " + json.dumps(name) + "\n" + BODY
    problem = only_problem(write_scene(tmp_path, text))
    assert "field 'name' must be at most 200 bytes long" in problem and f"got {size}" in problem
    assert load_scene(write_scene(tmp_path, "[simulation]\nname = " + json.dumps("x" * 200) + "\n"
                                  + BODY)).name == "x" * 200


@pytest.mark.parametrize("text, expected", [
    ('[simulation]\ngravity = [0, 0, -1e300]\n' + BODY, "field 'gravity' must be a list of 3 numbers in [-1e+08, 1e+08]"),
    (BODY + 'model = "fem"\nyoung = 1e300\n', "field 'young' must be a number in (0, 1e+15]")])
def test_gravity_and_stiffness_beyond_any_material_are_refused(tmp_path, text, expected):
    """Gravity of 1e300 passed validate with numpy's overflow warnings, and young = 1e300 with
    CHOLMOD's warning that the matrix was not positive definite (its entries overflowed)."""
    assert expected in only_problem(write_scene(tmp_path, text))


def test_a_body_name_with_a_line_break_is_refused(tmp_path):
    problem = only_problem(write_scene(tmp_path, '[[bodies]]\nname = "a\\nb"\nshape = { type = "sphere", radius = 0.1 }\n'))
    assert "field 'name' must have no control characters" in problem



def test_a_scene_file_saved_with_a_byte_order_mark_reads_as_without(tmp_path):
    """A UTF-8 file with a byte-order mark (as Notepad saves it) read as "invalid TOML: Invalid
    statement (at line 1, column 1)"."""
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + BODY.encode())
    assert load_scene(path).bodies[0].name == "box"
    (tmp_path / "folder").mkdir()
    assert only_problem(tmp_path / "folder").endswith("is a folder, not a scene file")


def test_refine_on_a_rigid_box_is_refused_not_ignored(tmp_path):
    """``shape.refine`` splits a deformable box's tet cells; on a rigid box it was taken and did
    nothing."""
    problem = only_problem(write_scene(tmp_path, '[[bodies]]\nname = "a"\n'
                                                 'shape = { type = "box", size = [0.1, 0.1, 0.1], refine = 2 }\n'))
    assert "field 'shape.refine' needs model = \"fem\" or \"auto\"" in problem


def test_surface_pieces_that_cross_each_other_are_warned_of_and_nested_ones_are_not(tmp_path):
    """Two closed boxes overlapping by half, written as one surface, weigh both whole (their
    overlap counted twice) without a word. Pieces with vertices both inside and outside another
    cross it: warned of. A cavity with an island (nested, not crossing) is not."""
    import warnings
    first, quads = _box_quads(0.1)
    second, _ = _box_quads(0.1, offset=0.1)
    meshio.write(tmp_path / "pair.obj", meshio.Mesh(np.concatenate([first, second]), [("quad", np.concatenate([quads, quads + 8]))]))
    with pytest.warns(geometry.MeshWarning, match="2 pieces of the surface cross each other"):
        geometry.load_surface(tmp_path / "pair.obj")
    outer, _ = _box_quads(0.2)
    inner, _ = _box_quads(0.1)
    island, _ = _box_quads(0.025)
    faces = np.concatenate([quads, quads[:, ::-1] + 8, quads + 16])
    meshio.write(tmp_path / "nested.obj", meshio.Mesh(np.concatenate([outer, inner, island]), [("quad", faces)]))
    with warnings.catch_warnings():
        warnings.simplefilter("error", geometry.MeshWarning)
        geometry.load_surface(tmp_path / "nested.obj")


def test_a_needle_tet_in_a_deformable_bodys_file_is_refused_naming_it(tmp_path):
    """A needle (a corner just above a triangle's long edge) beside a good mesh passed
    `validate`; its body's matrix was not positive definite to CHOLMOD and the body, falling
    freely, reached 2e8 m/s in two steps. Refused for a deformable body, naming the tet and its
    quality (volume over the regular tet's on its longest edge, which the cube's tets far exceed);
    a rigid body, which needs only the surface, takes the file."""
    from fem.mesh import tet_quality
    needle = np.array([[2.0, 0, 0], [3.0, 0, 0], [2.0, 1.0, 0], [2.5, 0.5, 1e-7]])
    points = np.vstack([CUBE_POINTS, needle])
    tets = np.vstack([CUBE_TETS, [[8, 9, 10, 11]]])
    quality = tet_quality(points, tets)
    regular = np.array([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    assert tet_quality(regular, np.array([[0, 1, 2, 3]]))[0] == pytest.approx(1.0, rel=1e-12)
    assert quality[:-1].min() > 0.1 and quality[-1] < 1e-6
    meshio.write(tmp_path / "needle.vtu", meshio.Mesh(points, [("tetra", tets)]))
    with pytest.raises(geometry.MeshError, match=r"1 of 7 tets are too badly shaped.*tets 6; remesh"):
        geometry.load_tet_mesh(tmp_path / "needle.vtu")
    scene = write_scene(tmp_path, '[[bodies]]\nname = "b"\nmodel = "fem"\nyoung = 1e8\nmesh = "needle.vtu"\n')
    assert any("field 'mesh'" in p and "too badly shaped" in p for p in problems_of(scene))
    rigid = write_scene(tmp_path, '[[bodies]]\nname = "b"\nmesh = "needle.vtu"\n', "rigid.toml")
    load_scene(rigid)
