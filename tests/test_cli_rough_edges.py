"""What a new user meets on the command line: clear messages and exit code 2, never a traceback."""
import pytest

from hybrid.app.cli import main


def test_out_below_a_file_is_refused_naming_the_file(tmp_path, capsys):
    blocker = tmp_path / "notes.txt"
    blocker.write_text("mine")
    assert main(["run", "default", "--out", str(blocker / "sub"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"{blocker} is a file" in err and "Traceback" not in err
    assert blocker.read_text() == "mine"


@pytest.mark.parametrize("scene", ["default", "jelly"])
def test_out_that_cannot_be_created_is_refused_before_the_run(scene, capsys):
    """A folder the system will not make (/proc takes no new entries) is bad input, said before
    anything runs or deformable bodies are built (a large mesh takes a minute)."""
    assert main(["run", scene, "--out", "/proc/hybrid-no-such-folder", "--quiet"]) == 2
    captured = capsys.readouterr()
    assert "--out /proc/hybrid-no-such-folder: cannot create the folder" in captured.err
    assert "Traceback" not in captured.err
    assert "running" not in captured.out and "building" not in captured.out


def test_a_scene_refused_when_its_bodies_are_built_leaves_no_folder_behind(tmp_path, capsys):
    """The run folder is made before the bodies are built; a problem found in building them
    removes the folders the command made, and only those."""
    scene = tmp_path / "anchor.toml"
    scene.write_text('[[bodies]]\nname = "b"\nmodel = "fem"\nyoung = 1e6\n'
                     'shape = { type = "box", size = [0.1, 0.1, 0.1] }\n'
                     'anchors = [ { box = [[5, 5, 5], [6, 6, 6]] } ]\n')
    (tmp_path / "kept").mkdir()
    assert main(["run", str(scene), "--out", str(tmp_path / "kept" / "a" / "b"), "--quiet"]) == 2
    assert "contains no mesh node" in capsys.readouterr().err
    assert (tmp_path / "kept").is_dir() and not any((tmp_path / "kept").iterdir())


def test_an_unknown_writer_in_the_environment_is_bad_input_naming_the_variable(tmp_path, capsys,
                                                                                monkeypatch):
    monkeypatch.setenv("HYBRID_WRITER", "bogus")
    assert main(["run", "default", "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "HYBRID_WRITER='bogus': must be one of auto, process, thread, inline" in err
    assert "Traceback" not in err and not (tmp_path / "out").exists()


def test_the_render_hint_is_quoted_for_the_shell(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scene = tmp_path / "short.toml"
    scene.write_text('[simulation]\nduration = 0.01\n[[bodies]]\nname = "b"\n'
                     'shape = { type = "sphere", radius = 0.1 }\n')
    assert main(["run", str(scene), "--out", "out dir", "--quiet"]) == 0
    assert "render it with: hybrid render 'out dir'" in capsys.readouterr().out


def test_render_size_must_be_drawable(tmp_path, capsys):
    assert main(["render", str(tmp_path), "--size", "0", "-5"]) == 2
    assert "16 to 8192 pixels" in capsys.readouterr().err


def test_help_lists_every_render_field_and_version_is_printed(capsys):
    with pytest.raises(SystemExit):
        main(["render", "--help"])
    text = capsys.readouterr().out
    assert all(f in text for f in ("von_mises", "principal_stress", "plastic_strain"))
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0 and capsys.readouterr().out.startswith("hybrid ")


def test_a_rigid_body_starting_inside_a_deformable_one_is_warned_about():
    import tomllib
    from pathlib import Path

    from hybrid import Simulation
    from hybrid.app.scene import parse_scene
    text = """
[simulation]
dt = 0.001
[[bodies]]
name = "block"
model = "fem"
shape = { type = "box", size = [0.2, 0.2, 0.2], resolution = 0.1 }
young = 1.0e6
position = [0.0, 0.0, 0.1]
[[bodies]]
name = "stone"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
position = [0.0, 0.0, %s]
"""
    sunk = Simulation(parse_scene(tomllib.loads(text % 0.22), "<test>", Path(".")))   # 3 cm into it
    assert sunk.warnings == ["bodies 'block' and 'stone' overlap at the start"]
    clear = Simulation(parse_scene(tomllib.loads(text % 0.2501), "<test>", Path(".")))
    assert clear.warnings == []


@pytest.mark.parametrize("shape, at, overlap", [
    ('{ type = "box", size = [0.2, 0.2, 0.2] }', "0.5", True),          # one pose: vertex on vertex
    ('{ type = "sphere", radius = 0.1 }', "0.5", True),
    ('{ type = "box", size = [0.2, 0.2, 0.2] }', "0.7001", False)])    # face to face, apart
def test_bodies_placed_at_one_pose_are_warned_of_as_overlapping(shape, at, overlap):
    """Two bodies at the same pose meet only vertex to vertex, at no depth: they were not warned
    of, and fell through each other; one whose centre lies inside itself and the other is."""
    import tomllib
    from pathlib import Path

    from hybrid import Simulation
    from hybrid.app.scene import parse_scene
    sim = Simulation(parse_scene(tomllib.loads(
        f'[[bodies]]\nname = "a"\nshape = {shape}\nposition = [0.0, 0.0, 0.5]\n'
        f'[[bodies]]\nname = "b"\nshape = {shape}\nposition = [0.0, 0.0, {at}]\n'), "<test>", Path(".")))
    assert sim.warnings == (["bodies 'a' and 'b' overlap at the start"] if overlap else [])


def test_an_unexpected_error_in_a_step_ends_the_run_with_its_frames_and_summary(tmp_path, capsys,
                                                                                 monkeypatch):
    import json

    from hybrid.coupling import step as coupled

    solve, calls = coupled.solve, []

    def failing(*args):
        calls.append(1)
        if len(calls) == 30:
            return 1.0 / 0.0
        return solve(*args)

    monkeypatch.setattr(coupled, "solve", failing)
    monkeypatch.setenv("HYBRID_NO_WARM_UP", "1")       # the build's warm-up steps would count too
    scene = tmp_path / "drop.toml"
    scene.write_text("""
[simulation]
duration = 0.1
dt = 0.001
output_fps = 100
[[planes]]
[[bodies]]
name = "block"
model = "fem"
young = 1.0e6
shape = { type = "box", size = [0.1, 0.1, 0.1], resolution = 0.05 }
position = [0.0, 0.0, 0.2]
""")
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out), "--quiet", "--checkpoint-every", "0.01"]) == 3
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert "a step failed at t = 0.029 s in hybrid.coupling.step.coupled_step" in err
    assert "ZeroDivisionError" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "unstable" and summary["steps"] == 29
    assert len(list((out / "frames").glob("*.vtu"))) == summary["frames"] == 3
    # its checkpoints (at 0.01 and 0.02 s) would only lead into the failure again: removed, so
    # the scene, once mended, runs again in the same folder (it was refused as a stopped run)
    assert not (out / "checkpoint.npz").exists()
    monkeypatch.setattr(coupled, "solve", solve)
    assert main(["run", str(scene), "--out", str(out), "--quiet"]) == 0


def test_validate_takes_a_built_in_scene_name_as_run_does(capsys):
    assert main(["validate", "dent"]) == 0
    assert "dent.toml: 4 bodies" in capsys.readouterr().out
    assert main(["validate", "no-such-scene"]) == 2
    assert "no such scene file or built-in scene" in capsys.readouterr().err


def test_validate_gives_the_warnings_a_run_would(tmp_path, capsys):
    """A scene whose run warns (two bodies overlapping, one 5 cm inside the ground, a fixed body
    given a velocity, which it ignores) validates with those warnings, still OK: they are not
    errors, but validate said "OK" alone while the run warned."""
    scene = tmp_path / "warned.toml"
    scene.write_text("""
[[planes]]
[[bodies]]
name = "a"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
position = [0.0, 0.0, 0.0]
[[bodies]]
name = "b"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
position = [0.05, 0.0, 0.0]
[[bodies]]
name = "post"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
position = [1.0, 0.0, 0.5]
fixed = true
velocity = [1.0, 0.0, 0.0]
""")
    assert main(["validate", str(scene)]) == 0
    out, err = capsys.readouterr()
    assert out.startswith("OK")
    assert "warning: bodies 'a' and 'b' overlap at the start" in err
    assert "warning: body 'a' starts 0.05 m inside a plane" in err
    assert "warning: body 'post' is fixed: its velocity has no effect" in err


def test_a_box_too_thin_for_its_length_in_double_precision_is_a_problem_of_its_shape(tmp_path, capsys):
    """A rigid box 1e8 m long and 1 m thick validated, and its first step failed with "cannot
    convert float NaN to integer": its moment of inertia about the long axis, a difference of
    terms 1e16 times larger, came out 0. Building the scene now names the body and its shape."""
    scene = tmp_path / "beam.toml"
    scene.write_text('[simulation]\ngravity = [0, 0, 0]\n[[bodies]]\nname = "beam"\n'
                     'shape = { type = "box", size = [1e8, 1, 1] }\nangular_velocity = [1, 0, 0]\n')
    for command in ("validate", "run"):
        assert main([command, str(scene), *(["--out", str(tmp_path / "out")] if command == "run" else [])]) == 2
        err = capsys.readouterr().err
        assert "\"beam\"" in err and "field 'shape' gives an unusable body" in err, err
        assert "principal moments of inertia" in err and "Warning" not in err, err
    assert not (tmp_path / "out").exists()


def test_a_folder_named_as_a_built_in_scene_does_not_hide_it(tmp_path, capsys, monkeypatch):
    """``hybrid run default --out default`` makes a folder 'default' in the current folder, and
    the next ``hybrid run default`` there read it as the scene file: "cannot read scene file (Is
    a directory)". A folder is no scene file: the name is the built-in scene's."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "dent").mkdir()
    assert main(["validate", "dent"]) == 0
    assert "dent.toml: 4 bodies" in capsys.readouterr().out
    (tmp_path / "other").mkdir()
    assert main(["validate", "other"]) == 2


def test_a_runaway_start_says_so_without_numpys_warnings(tmp_path, capsys):
    """A box started at 1e300 m/s stopped as unstable, naming it, after three numpy
    RuntimeWarnings with source lines (the first frame's totals and the summary's drifts
    overflowing): they are noise around the message. It is refused as a start beyond the
    run's limits, naming the field."""
    scene = tmp_path / "fast.toml"
    scene.write_text('[simulation]\nduration = 0.01\n[[bodies]]\nname = "box"\n'
                     'shape = { type = "box", size = [0.1, 0.1, 0.1] }\nvelocity = [1e300, 0, 0]\n')
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert main(["run", str(scene), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "field 'velocity' starts it at a speed of 1e+300 m/s" in err and "Warning" not in err, err


def test_an_unbreakable_box_holding_no_element_is_a_problem_as_an_empty_anchor_box_is(tmp_path, capsys):
    """An ``[[bodies.unbreakable]]`` box that holds no element (given in world coordinates, say)
    keeps nothing whole and was taken without a word, where an anchor or load box that holds no
    node is refused."""
    scene = tmp_path / "grip.toml"
    scene.write_text('[[bodies]]\nname = "bar"\nmodel = "fem"\nyoung = 1e7\nfracture_stress = 1e5\n'
                     'shape = { type = "box", size = [0.2, 0.02, 0.02], resolution = 0.01 }\n'
                     '[[bodies.unbreakable]]\nbox = [[0.09, -0.02, -0.02], [0.11, 0.02, 0.02]]\n'
                     '[[bodies.unbreakable]]\nbox = [[1.0, 1.0, 1.0], [2.0, 2.0, 2.0]]\n')
    assert main(["validate", str(scene)]) == 2
    err = capsys.readouterr().err
    assert "[[bodies.unbreakable]] 1 box" in err and "contains no element's centre" in err, err
    assert "unbreakable]] 0" not in err


def test_an_empty_out_is_refused_as_the_python_api_refuses_it(capsys):
    """``hybrid run X --out ""`` wrote to the default folder without a word, where
    ``sim.run(out="")`` raises ValueError."""
    assert main(["run", "dent", "--out", ""]) == 2
    assert "--out is empty" in capsys.readouterr().err


@pytest.mark.parametrize("z, refused", [(0.0, True), (0.0495, False)])
def test_a_deformable_body_started_deep_in_the_ground_is_refused(tmp_path, capsys, z, refused):
    """A soft cube 0.1 m across started half in the ground had its buried nodes pushed out in
    one step: strained by 0.6, it gained 33 J in 0.017 s and the run stopped as unstable, after
    a warning that it would be thrown. Deeper than 1% of its size, it is a problem of its
    position; half a millimetre in, it is warned of and pushed out."""
    scene = tmp_path / "buried.toml"
    scene.write_text(f'[simulation]\nduration = 0.01\n[[planes]]\n[[bodies]]\nname = "box"\nmodel = "fem"\n'
                     f'young = 1e6\nshape = {{ type = "box", size = [0.1, 0.1, 0.1] }}\nposition = [0, 0, {z}]\n')
    code = main(["run", str(scene), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    if refused:
        assert code == 2 and "field 'position' starts it 0.05 m inside a plane" in err, err
        assert not (tmp_path / "out").exists()
    else:
        assert code == 0 and "starts 0.0005 m inside a plane: it is pushed out in its first step" in err, err


def test_a_rigid_body_spinning_without_bound_stops_the_run_naming_its_rim_speed(tmp_path):
    """A rigid box started at 1e160 rad/s ran to the end with status ok, its kinetic energy inf
    and the energy drift nan: only its speed and position were checked. Its rim speed is (a
    scene starting so is refused; here the spin comes after the start)."""
    import warnings
    from dataclasses import replace
    from hybrid import Simulation
    from hybrid.coupling.stability import InstabilityError
    scene = tmp_path / "spin.toml"
    scene.write_text('[simulation]\nduration = 0.01\n[[bodies]]\nname = "b"\n'
                     'shape = { type = "box", size = [0.1, 0.1, 0.1] }\n')
    sim = Simulation(str(scene))
    rs = sim.state.rigid
    sim.state = replace(sim.state, rigid=replace(rs, angular_momentum=rs.angular_momentum + [1e157, 0, 0]))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(InstabilityError, match=r"unstable: body 'b' at t = 0.001 s: rim speed \(m/s\)"):
            sim.step()


@pytest.mark.parametrize("field, value, quantity", [
    ("velocity", "[12000.0, 0, 0]", "a speed of 1.2e+04 m/s"),
    ("angular_velocity", "[0, 0, 3e5]", "a rim speed of"),
    ("position", "[2e6, 0, 0]", "a distance from the origin of 2e+06 m"),
])
def test_a_scene_starting_beyond_the_runs_divergence_limits_is_refused(tmp_path, capsys, field, value,
                                                                       quantity):
    """A ball started at 12 km/s passed `validate` and its run stopped as unstable at the first
    step (the check after every step stops at 1e4 m/s and 1e6 m from the origin): such a start
    is a problem of the field that gives it, and a start just inside the limits runs."""
    for given, refused in ((value, True), ("[9000.0, 0, 0]" if field == "velocity" else "[0, 0, 0]", False)):
        scene = tmp_path / f"{refused}.toml"
        scene.write_text('[simulation]\nduration = 0.002\ngravity = [0, 0, 0]\n[[bodies]]\nname = "ball"\n'
                         f'shape = {{ type = "sphere", radius = 0.05 }}\n{field} = {given}\n')
        assert main(["validate", str(scene)]) == (2 if refused else 0)
        code = main(["run", str(scene), "--out", str(tmp_path / f"out{refused}"), "--quiet"])
        err = capsys.readouterr().err
        if refused:
            assert code == 2 and f"field '{field}' starts it at {quantity}" in err, err
            assert "a run stops as unstable beyond" in err and not (tmp_path / "outTrue").exists()
        else:
            assert code == 0, err


def test_a_command_whose_reader_has_left_ends_without_a_traceback(tmp_path):
    """``hybrid scenes | head -1`` printed a BrokenPipeError traceback and exited 1: the reader
    of the output leaving is no error of the command."""
    import os
    import subprocess
    import sys
    read, write = os.pipe()
    os.close(read)                       # the reader has left before the first line
    try:
        done = subprocess.run([sys.executable, "-m", "hybrid", "scenes"], stdout=write,
                              stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr


def test_a_run_of_a_vanishingly_small_step_ends_with_its_summary(tmp_path, capsys):
    """dt = duration = 1e-200 s: the summary's energy floor divided by the duration squared,
    which is 0.0, and the run ended in a ZeroDivisionError traceback without its summary."""
    scene = tmp_path / "tiny.toml"
    scene.write_text('[simulation]\nduration = 1e-200\ndt = 1e-200\n[[planes]]\n[[bodies]]\nname = "b"\n'
                     'shape = { type = "box", size = [0.1, 0.1, 0.1] }\nposition = [0, 0, 0.05]\n')
    assert main(["run", str(scene), "--out", str(tmp_path / "out"), "--quiet"]) == 0, capsys.readouterr().err
    assert (tmp_path / "out" / "summary.json").exists()


def test_a_deformable_body_spun_past_the_limits_is_refused_naming_its_angular_velocity(tmp_path, capsys):
    """A deformable bar given only an angular velocity whose nodes start at 2e4 m/s was refused
    naming field 'velocity', which it does not have: the field is the one that gives the speed."""
    scene = tmp_path / "spun.toml"
    scene.write_text('[simulation]\nduration = 0.002\ngravity = [0, 0, 0]\n[[bodies]]\nname = "bar"\n'
                     'model = "fem"\nyoung = 7e10\nshape = { type = "box", size = [0.2, 0.02, 0.02], '
                     'resolution = 0.02 }\nangular_velocity = [0, 0, 2e5]\n')
    assert main(["validate", str(scene)]) == 2
    assert "field 'angular_velocity' starts it at a node speed of 2" in capsys.readouterr().err
    scene.write_text(scene.read_text().replace("angular_velocity = [0, 0, 2e5]",
                                               "velocity = [2e4, 0, 0]"))
    assert main(["validate", str(scene)]) == 2
    assert "field 'velocity' starts it at a speed of 2e+04 m/s" in capsys.readouterr().err


def test_a_mesh_whose_own_coordinates_lie_beyond_the_limit_is_named_not_its_position(tmp_path, capsys):
    """A rigid body made from a mesh file whose vertices lie 5e6 m out was refused naming its
    'position', which the scene never set: the mesh puts it there."""
    (tmp_path / "far.obj").write_text("v 5e6 0 0\nv 5000000.1 0 0\nv 5e6 0.1 0\nv 5e6 0 0.1\n"
                                      "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    scene = tmp_path / "far.toml"
    scene.write_text('[simulation]\nduration = 0.002\ngravity = [0, 0, 0]\n[[bodies]]\nname = "m"\n'
                     'mesh = "far.obj"\n')
    assert main(["validate", str(scene)]) == 2
    err = capsys.readouterr().err
    assert "field 'mesh' starts it at a distance from the origin of 5e+06 m" in err, err
