"""The Simulation API: one step loop for the CLI, the tests and the benchmarks; a pure step."""
import json
import time
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest

from hybrid import Simulation
from hybrid.app.cli import main
from hybrid.app.scene import parse_scene
from hybrid.coupling.step import step

# a rigid box resting on a soft slab on the ground, a small soft block sliding on the ground
# beside it, and a ball falling freely: rigid-FEM and FEM-ground contact, held resting nodes
SCENE = """
[simulation]
name = "api_check"
duration = 0.06
dt = 0.002
output_fps = 100
[[planes]]
friction = 0.5
[[bodies]]
name = "slab"
model = "fem"
shape = { type = "box", size = [0.3, 0.3, 0.04], resolution = 0.05 }
young = 1.0e6
damping = { mass = 0.0, stiffness = 0.01 }
position = [0.0, 0.0, 0.02]
[[bodies]]
name = "box"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
density = 500.0
position = [0.0, 0.0, 0.0902]
[[bodies]]
name = "block"
model = "fem"
shape = { type = "box", size = [0.06, 0.06, 0.06], resolution = 0.03 }
young = 2.0e5
friction = 0.5
position = [0.5, 0.0, 0.0301]
velocity = [1.0, 0.0, 0.0]
[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.03 }
position = [-1.0, 0.0, 2.0]
"""


def scene_file(tmp_path):
    path = tmp_path / "api_check.toml"
    path.write_text(SCENE)
    return path


def state_arrays(state):
    out = [state.rigid.position, state.rigid.orientation, state.rigid.velocity]
    for s in state.fem:
        out += [s.x, s.v, s.node_reaction]
    return out


def test_step_twice_from_the_same_model_and_state_gives_the_same_state():
    """No hidden history: stepping one state, then another, then the first again gives the first
    answer bit for bit (caches on the model only memoise)."""
    sim = Simulation(parse_scene(tomllib.loads(SCENE), "<test>", Path(".")))
    for _ in range(15):                      # contacts established and warm-started
        sim.step()
    model, first = sim.model, sim.state
    sim.step()
    second = sim.state
    a = step(model, first)
    step(model, second)                      # something else in between
    b = step(model, first)
    assert all(np.array_equal(x, y) for x, y in zip(state_arrays(a), state_arrays(b)))
    assert all(np.array_equal(x, y) for x, y in zip(state_arrays(a), state_arrays(second)))


def test_running_a_scene_through_the_api_and_the_cli_writes_identical_files(tmp_path):
    path = scene_file(tmp_path)
    assert main(["run", str(path), "--out", str(tmp_path / "cli"), "--quiet"]) == 0
    summary = Simulation.from_toml(path).run(out=tmp_path / "api", progress=False, log=lambda m: None)
    assert summary["status"] == "ok"
    cli, api = tmp_path / "cli", tmp_path / "api"
    names = sorted(p.relative_to(cli) for p in cli.rglob("*") if p.is_file())
    assert names == sorted(p.relative_to(api) for p in api.rglob("*") if p.is_file())
    assert len([n for n in names if n.suffix == ".vtu"]) == 7          # t = 0, 0.01, ..., 0.06
    for name in names:
        if name.name != "summary.json":
            assert (cli / name).read_bytes() == (api / name).read_bytes(), name
    clock = ("wall_time", "steps_per_second")
    a, b = (json.loads((d / "summary.json").read_text()) for d in (cli, api))
    for d in (a, b):
        d["fracture"].pop("timings")
    assert {k: v for k, v in a.items() if k not in clock} == {k: v for k, v in b.items() if k not in clock}


def test_bodies_read_through_the_api_follow_free_fall_and_rest():
    sim = Simulation(parse_scene(tomllib.loads(SCENE), "<test>", Path(".")))
    ball0 = sim.body("ball")
    sim.run(until=0.06, progress=False, log=lambda m: None)
    ball, g, t = sim.body("ball"), 9.81, sim.time
    assert sim.steps == 30 and t == pytest.approx(0.06)
    assert ball.kind == "rigid" and ball.points is None
    # free fall: z = z0 - g t^2 / 2, v = -g t (the leapfrog's error is O(dt), here 1e-3 of the drop)
    assert ball.position[2] == pytest.approx(ball0.position[2] - 0.5 * g * t * t, abs=2 * g * t * sim.dt)
    assert ball.velocity[2] == pytest.approx(-g * t, rel=1e-9)
    slab = sim.body("slab")
    assert slab.kind == "fem" and slab.points.shape[1] == 3 and len(slab.von_mises) == len(slab.tets)
    # the slab carries the box: its stress is of the order of the box's weight over its footprint
    pressure = 500.0 * 0.1 ** 3 * g / 0.1 ** 2
    assert 0.1 * pressure < slab.von_mises.max() < 100 * pressure
    assert np.all(slab.plastic_strain == 0.0)
    with pytest.raises(KeyError, match="bodies: slab, box, block, ball"):
        sim.body("nothing")


def test_built_in_scene_runs_by_name():
    sim = Simulation.from_toml("default")
    assert sim.scene.name == "default" and "ball" in sim.body_names
    assert Simulation("default").body_names == sim.body_names      # a name or path works as well


def test_run_refuses_times_and_folders_it_cannot_honour(tmp_path):
    """run(until=...) must be a time at or after the simulation's (nan, inf, a string or an
    earlier time raised deep errors or did nothing and reported ok); out must be a folder, and
    not the one this simulation's last run wrote (its frames were silently replaced)."""
    sim = Simulation(parse_scene(tomllib.loads(SCENE), "<test>", Path(".")))
    # (1e307 overflowed counting its steps; 1e30, 1e33 steps, ran for ever)
    for until in (float("nan"), float("inf"), "0.3", -1.0, True, 1e307, 1e30):
        with pytest.raises(ValueError, match="until must be a time"):
            sim.run(until=until, progress=False, log=lambda m: None)
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is a file"):
        sim.run(until=0.004, out=tmp_path / "file" / "run", progress=False, log=lambda m: None)
    sim.run(until=0.004, out=tmp_path / "run", progress=False, log=lambda m: None)
    with pytest.raises(ValueError, match="last run wrote there"):
        sim.run(until=0.008, out=tmp_path / "run", progress=False, log=lambda m: None)
    with pytest.raises(ValueError, match="until must be a time"):
        sim.run(until=0.0, progress=False, log=lambda m: None)
    # a run refused for its time writes nothing, and the folder of the last run stays guarded
    with pytest.raises(ValueError, match="until must be a time"):
        sim.run(until=0.001, out=tmp_path / "never", progress=False, log=lambda m: None)
    assert not (tmp_path / "never").exists()
    with pytest.raises(ValueError, match="last run wrote there"):
        sim.run(until=0.008, out=tmp_path / "run", progress=False, log=lambda m: None)
    summary = sim.run(until=0.008, out=tmp_path / "later", progress=False, log=lambda m: None)
    assert summary["status"] == "ok" and sim.time == pytest.approx(0.008)
    # an empty out wrote into the current folder; checkpoint_every as --checkpoint-every takes it
    with pytest.raises(ValueError, match="give a folder"):
        sim.run(until=0.012, out="", progress=False, log=lambda m: None)
    for every in (-1.0, float("nan"), "0.1", True):
        with pytest.raises(ValueError, match="checkpoint_every must be"):
            sim.run(until=0.012, out=tmp_path / "every", checkpoint_every=every, progress=False,
                    log=lambda m: None)
    assert not (tmp_path / "every").exists()


def test_run_refuses_an_until_that_rounds_to_no_step_and_a_time_past_the_duration():
    """A run takes whole steps (the nearest number): an until less than half a step from the
    simulation's time took none and said ok, so a loop asking 0.4 steps at a time never ended; a
    run() with the simulation past its scene's duration took none either (run(until=duration) is
    refused)."""
    sim = Simulation(parse_scene(tomllib.loads(SCENE), "<test>", Path(".")))
    dt = sim.dt
    for ahead in (0.4, -0.4, 1e-3):
        with pytest.raises(ValueError, match="a run takes whole steps"):
            sim.run(until=sim.time + ahead * dt, progress=False, log=lambda m: None)
    assert sim.steps == 0
    sim.run(until=sim.time + 0.6 * dt, progress=False, log=lambda m: None)
    assert sim.steps == 1
    sim.run(until=sim.scene.simulation.duration + 2 * dt, progress=False, log=lambda m: None)
    with pytest.raises(ValueError, match="past the scene's duration"):
        sim.run(progress=False, log=lambda m: None)
    summary = sim.run(until=sim.time, progress=False, log=lambda m: None)     # now: a frame, no step
    assert summary["status"] == "ok"
    before = sim.steps
    sim.run(until=np.array(sim.time + dt), progress=False, log=lambda m: None)
    assert sim.steps == before + 1      # (a 0-d array is a time like np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (an np.float16 was checked in float16: an overflow warning)
        sim.run(until=np.float16(sim.time + 2 * dt), progress=False, log=lambda m: None)


def test_run_names_an_out_or_progress_of_the_wrong_type():
    """out=123 raised Path's own TypeError, not naming out; progress="no" showed the bar."""
    sim = Simulation(parse_scene(tomllib.loads(SCENE), "<test>", Path(".")))
    with pytest.raises(TypeError, match="out must be a folder's path"):
        sim.run(until=0.002, out=123, progress=False, log=lambda m: None)
    with pytest.raises(TypeError, match="progress must be True or False"):
        sim.run(until=0.002, progress="no", log=lambda m: None)
    assert sim.steps == 0


def test_a_second_run_reports_its_own_steps_per_second(tmp_path):
    """Steps count from the simulation's start; steps per second are the run's own steps over its
    wall time (a run after 50 steps taken one by one and a run of none reported 50 over its few
    milliseconds)."""
    sim = Simulation(parse_scene(tomllib.loads(SCENE), "<test>", Path(".")))
    for _ in range(5):
        sim.step()
    summary = sim.run(until=sim.time + 3 * sim.dt, out=tmp_path / "run", progress=False,
                      log=lambda m: None)
    assert summary["steps"] == 8
    assert summary["steps_per_second"] * summary["wall_time"] == pytest.approx(3)


def test_cli_lists_built_in_scenes_and_refuses_an_unknown_name(capsys):
    from hybrid.scenes import builtin_names
    assert main(["scenes"]) == 0
    listed = capsys.readouterr().out
    assert all(f"  {name} " in listed for name in builtin_names())
    assert {"dent", "pull", "shatter", "tear", "fragments", "pile"} <= set(builtin_names())
    # a copy of the cantilever reads its mesh relative to its own folder: the listing says where it is
    meshes = listed.split("meshes the scenes read")[1].split(": ", 1)[1].strip().split(", ")
    assert meshes and all(Path(m).is_absolute() and Path(m).is_file() for m in meshes)
    assert main(["run", "no_such_scene", "--quiet"]) == 2
    assert "built-in scenes: " in capsys.readouterr().err


@pytest.mark.parametrize("duration, dt, end", [(0.1, 0.003, 0.099), (0.1, 0.06, 0.12), (0.1, 0.001, None),
                                            (0.105, 0.01, 0.11), (0.125, 0.05, 0.15), (0.35, 0.1, 0.4)])
def test_a_duration_that_is_no_whole_number_of_steps_is_warned_of_with_where_the_run_ends(
        duration, dt, end):
    text = (f"[simulation]\nduration = {duration}\ndt = {dt}\n[[bodies]]\nname = \"b\"\n"
            "shape = { type = \"sphere\", radius = 0.1 }\n")
    sim = Simulation(parse_scene(tomllib.loads(text), "<scene>", Path(".")))
    said = [w for w in sim.warnings if w.startswith(f"duration {duration:g} s")]
    sim.run(progress=False, log=lambda message: None)
    if end is None:
        assert not said and sim.time == pytest.approx(duration)
    else:
        assert len(said) == 1 and f"ends at {end:g} s" in said[0]
        assert sim.time == pytest.approx(end)


@pytest.mark.parametrize("model", ["rigid", "fem"])
def test_energy_drift_of_a_free_fall_from_rest_at_the_origin_is_round_off(model):
    """A body falling from rest at z = 0 has a total energy of zero throughout: its drift is
    measured against the energy it converts (the summary read 1, as if all were lost). A rigid
    body follows the parabola exactly; a deformable one's step (v += h g, x += h v) loses
    m g^2 h^2 n / 2 in n steps of the m g^2 h^2 n (n + 1) / 2 of potential energy it converts."""
    sim = Simulation(parse_scene(tomllib.loads(f"""
[simulation]
duration = 0.5
dt = 0.005
[[bodies]]
name = "ball"
model = "{model}"
shape = {{ type = "sphere", radius = 0.1, resolution = 0.1 }}
{'young = 1e9' if model == 'fem' else ''}
"""), "<test>", Path(".")))
    summary = sim.run(progress=False, log=lambda m: None)
    ball = sim.body("ball")
    assert ball.velocity[2] == pytest.approx(-9.81 * 0.5, rel=1e-9)
    drift = summary["conservation"]["energy_relative_drift"]
    if model == "rigid":
        assert drift < 1e-9
    else:
        assert drift == pytest.approx(1 / (sim.steps + 1), rel=1e-6)


def test_energy_drift_of_millimetre_bodies_at_rest_in_zero_gravity_is_round_off():
    """Bodies at rest without gravity have energies of round-off, 1e-36 J: their changes read as
    an energy drift of 0.8-0.99. A drift is measured against at least 1e-12 of the bodies'
    kinetic energy moving their own size over the run: it reads round-off."""
    sim = Simulation(parse_scene(tomllib.loads("""
[simulation]
duration = 0.05
dt = 0.001
gravity = [0, 0, 0]
[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.0005 }
[[bodies]]
name = "cube"
model = "fem"
young = 1e6
shape = { type = "box", size = [0.001, 0.001, 0.001] }
position = [0.004, 0, 0]
"""), "<test>", Path(".")))
    summary = sim.run(progress=False, log=lambda m: None)
    assert summary["conservation"]["energy_relative_drift"] < 1e-6


def test_a_run_ending_between_frame_times_writes_its_end(tmp_path):
    """Frames come at the first step at or after each frame time, and the run's last state is
    written even when its end falls between them (a 0.03 s run at 60 frames/s kept t = 0.018)."""
    sim = Simulation(parse_scene(tomllib.loads("""
[simulation]
duration = 0.03
dt = 0.002
output_fps = 60
[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.1 }
"""), "<test>", Path(".")))
    summary = sim.run(out=tmp_path / "run", progress=False, log=lambda m: None)
    times = np.loadtxt(tmp_path / "run" / "bodies.csv", delimiter=",", skiprows=1, usecols=0, ndmin=1)
    assert times == pytest.approx([0.0, 0.018, 0.03])
    assert summary["frames"] == 3 and len(list((tmp_path / "run" / "frames").glob("*.vtu"))) == 3
    vz = np.loadtxt(tmp_path / "run" / "bodies.csv", delimiter=",", skiprows=1, usecols=11)[-1]
    assert vz == pytest.approx(-9.81 * 0.03)


def test_a_scene_changed_in_python_is_checked_as_its_file_would_be():
    """dataclasses.replace skips the scene file's checks: a negative young stepped with a
    negative von Mises stress, a negative dt ran backwards. Simulation(scene) checks it again,
    naming the field, and the summary shows the values it ran with."""
    from dataclasses import replace
    from hybrid.app.scene import SceneError, load_scene
    from hybrid.scenes import builtin_path
    scene = load_scene(builtin_path("dent"))
    plate = next(b for b in scene.bodies if b.name == "plate")

    def changed(**fields):
        return replace(scene, bodies=tuple(replace(b, **fields) if b is plate else b for b in scene.bodies))

    for fields, message in (({"young": -70e9}, r"field 'young' must be a number in \(0, 1e\+15\]"),
                            ({"poisson": 0.7}, "field 'poisson' must be"),
                            ({"yield_stress": "abc"}, "field 'yield_stress' must be")):
        with pytest.raises(SceneError, match=message):
            Simulation(changed(**fields))
    with pytest.raises(SceneError, match="field 'dt' must be"):
        Simulation(replace(scene, simulation=replace(scene.simulation, dt=-1e-3)))
    sim = Simulation(changed(yield_stress=100e6))
    summary = sim.run(until=2e-4, progress=False, log=lambda m: None)
    assert summary["scene"]["bodies"][2]["yield_stress"] == 100e6
    assert sim.model.fem[0].yield_stress == 100e6
    assert Simulation(scene).scene is scene         # an unchanged scene is used as it is


def test_a_body_reports_its_mass_and_the_progress_of_a_log_ends_once():
    """Body.mass lets a user check momentum from the API: a box's is density times volume, rigid
    or deformable. A run logged to a file ends its progress with one 100% line (it was twice)."""
    import io
    from hybrid.app.progress import Progress
    sim = Simulation(parse_scene(tomllib.loads(SCENE), "<test>", Path(".")))
    assert sim.body("box").mass == pytest.approx(500.0 * 0.1 ** 3, rel=1e-12)
    assert sim.body("slab").mass == pytest.approx(1000.0 * 0.3 * 0.3 * 0.04, rel=1e-12)
    stream = io.StringIO()
    bar = Progress(0.01, stream=stream)
    for k in range(1, 11):
        bar.update(0.001 * k, k)
    bar.update(0.01, 10, force=True)
    lines = stream.getvalue().splitlines()
    assert sum(line.startswith("100.0%") for line in lines) == 1


def test_the_progress_rate_and_time_left_follow_the_recent_steps(monkeypatch):
    """A rigid pile that slows as it lands showed its fast start's rate to the end (57.9 steps/s
    at 10%, 18.1 at the end), and no time left: both come from the last 5-10 s of wall time."""
    import io
    from hybrid.app import progress as run
    now = [0.0]
    monkeypatch.setattr(run.clock, "perf_counter", lambda: now[0])
    stream = io.StringIO()
    bar = run.Progress(100.0, stream=stream)
    steps = 0
    for second in range(1, 61):          # 100 steps (1 simulated s) per wall s, then 10 (0.1 s)
        now[0] = float(second)
        steps += 100 if second <= 30 else 10
        t = second if second <= 30 else 30 + 0.1 * (second - 30)
        bar.update(t, steps, force=True)
    last = stream.getvalue().splitlines()[-1]
    rate, left = last.split("steps/s")[0].split()[-1], last.split("steps/s")[1].split()[0]
    assert float(rate) == pytest.approx(10.0)
    minutes, seconds = (int(v) for v in left.split(":"))
    assert 60 * minutes + seconds == pytest.approx((100.0 - 33.0) / 0.1, abs=1)


@pytest.mark.parametrize("order", [1, 2])
def test_a_deformable_body_s_node_velocities_and_masses_sum_to_its_momentum_and_energy(order):
    """Body gives a deformable body's node velocities and lumped masses, so a user can check its
    momentum and energy by hand: a box spinning and flying in zero gravity keeps the momentum it
    was given, and the sums agree with Body's velocity and kinetic energy."""
    text = f"""[simulation]\nduration = 0.1\ndt = 0.002\ngravity = [0.0, 0.0, 0.0]\n[[bodies]]
name = "b"\nmodel = "fem"\norder = {order}\nyoung = 1e5\ndensity = 1000.0
shape = {{ type = "box", size = [0.2, 0.1, 0.05] }}\nvelocity = [1.0, 0.5, 0.0]\nangular_velocity = [0.0, 0.0, 8.0]\n"""
    sim = Simulation(parse_scene(tomllib.loads(text), "<test>", Path(".")))
    sim.run(until=0.05, progress=False, log=lambda m: None)
    b = sim.body("b")
    m, v = b.node_masses, b.node_velocities
    assert m.sum() == pytest.approx(1000.0 * 0.2 * 0.1 * 0.05, rel=1e-12) == pytest.approx(b.mass, rel=1e-12)
    momentum = (m[:, None] * v).sum(axis=0)
    np.testing.assert_allclose(momentum, [1.0, 0.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(momentum / b.mass, b.velocity, atol=1e-12)
    assert 0.5 * (m * (v * v).sum(axis=1)).sum() == pytest.approx(b.kinetic_energy, rel=1e-12)
    spin = (m[:, None] * np.cross(b.points - b.position, v - b.velocity)).sum(axis=0)
    assert spin[2] > 0 and np.abs(spin[:2]).max() < 1e-9 * spin[2]


def test_a_logged_progress_says_it_is_alive_each_minute_with_times_to_the_run_s_scale(monkeypatch):
    """Off a terminal the bar writes a line per tenth of the run: a 50k-tet impact's slow steps
    printed nothing for 86 s; a 20 ms run read t = 0.000 s and 0.0 steps/s at steps of 9 s."""
    import io
    from hybrid.app import progress
    now = [0.0]
    monkeypatch.setattr(progress.clock, "perf_counter", lambda: now[0])
    stream = io.StringIO()
    bar = progress.Progress(0.02, stream=stream)
    for k in range(1, 21):              # 20 steps of 1e-4 s, 9 s each: a tenth of the run in 3 minutes
        now[0] = 9.0 * k
        bar.update(1e-4 * k, k)
    lines = stream.getvalue().splitlines()
    # the first step, then a line each minute (steps 8 and 15, 72 s and 135 s), and the tenth
    assert [line.split("t = ")[1].split()[0] for line in lines] == ["0.00010", "0.00080", "0.00150", "0.00200"]
    assert all(float(line.split("steps/s")[0].split()[-1]) == pytest.approx(1 / 9.0, rel=0.01)
               for line in lines)


def test_what_is_no_scene_is_refused_saying_what_a_simulation_is_built_from():
    """None or a dict raised an AttributeError from deep inside; TOML text given as a path was
    echoed whole as an unknown built-in scene's name."""
    for wrong in (None, {"simulation": {"duration": 1.0}}, 3.0):
        with pytest.raises(TypeError, match="scene file's path, a built-in scene's name or a parsed Scene"):
            Simulation(wrong)
    with pytest.raises(KeyError, match="TOML text is not read as a scene") as refused:
        Simulation.from_toml(SCENE)
    assert len(str(refused.value)) < 300
    with pytest.raises(KeyError, match="no built-in scene"):            # too long for a file name
        Simulation.from_toml("x" * 5000)


def test_a_mesh_path_changed_in_python_is_read_where_it_was_checked(tmp_path, monkeypatch):
    """A relative mesh path set with dataclasses.replace was checked against the scene file's
    folder (as the file's own paths are) but read from the current folder: another file, another
    mass, no message; a path given as a string raised AttributeError. Both now read the file the
    check found, next to the scene file."""
    import dataclasses
    import meshio
    from hybrid.app.scene import load_scene
    (tmp_path / "sub" / "m").mkdir(parents=True)
    (tmp_path / "m").mkdir()
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    meshio.write(tmp_path / "sub" / "m" / "tet.vtu", meshio.Mesh(points * 0.2, [("tetra", [[0, 1, 2, 3]])]))
    meshio.write(tmp_path / "m" / "tet.vtu", meshio.Mesh(points * 0.1, [("tetra", [[0, 1, 2, 3]])]))
    (tmp_path / "sub" / "scene.toml").write_text(
        '[simulation]\nduration = 0.01\ndt = 0.001\n[[bodies]]\nname = "b"\nmodel = "fem"\n'
        'young = 1e6\ndensity = 1000\nshape = { type = "box", size = [0.1, 0.1, 0.1] }\n')
    monkeypatch.chdir(tmp_path)
    scene = load_scene(tmp_path / "sub" / "scene.toml")
    for mesh in (Path("m/tet.vtu"), "m/tet.vtu"):
        body = dataclasses.replace(scene.bodies[0], shape=None, mesh=mesh)
        sim = Simulation(dataclasses.replace(scene, bodies=(body,)))
        assert sim.body("b").mass == pytest.approx(1000 * 0.2 ** 3 / 6)     # sub/m/tet.vtu's


@pytest.mark.parametrize("changes, changed_by", [
    ("", []),
    ("planes = 1", ["friction"]),
    ('model = "fem"\nyoung = 1e6', ["deformable contact", "backward Euler"]),
    ('model = "fem"\nyoung = 1e6\nintegrator = "newmark"\nyield_stress = 1e5',
     ["deformable contact", "plastic flow"]),
])
def test_the_summary_says_what_may_change_a_scenes_energy(tmp_path, changes, changed_by):
    """energy_conserved_expected was true in a plastic, inelastic, frictional scene (it looked at
    moving anchors only); it now lists what in the scene may change the energy. Two frictionless
    perfectly elastic bodies in zero gravity change nothing; a plane with its default friction
    does."""
    plane = "[[planes]]\npoint = [0, 0, -1]\nrestitution = 1.0\n" if changes == "planes = 1" else ""
    changes = "" if plane else changes
    text = ("[simulation]\nduration = 0.004\ndt = 0.002\ngravity = [0, 0, 0]\n" + plane +
            "[[bodies]]\nname = \"a\"\nshape = { type = \"box\", size = [0.1, 0.1, 0.1] }\n"
            f"friction = 0.0\nrestitution = 1.0\n{changes}\n"
            "[[bodies]]\nname = \"b\"\nshape = { type = \"sphere\", radius = 0.05 }\n"
            "position = [1.0, 0.0, 0.0]\nfriction = 0.0\nrestitution = 1.0\n")
    sim = Simulation(parse_scene(tomllib.loads(text), "<test>", Path(".")))
    conservation = sim.run(progress=False, log=lambda m: None)["conservation"]
    assert conservation["energy_changed_by"] == changed_by
    assert conservation["energy_conserved_expected"] is (not changed_by)


def test_the_summarys_energy_counts_the_work_of_constant_loads():
    """A free Newmark box pushed by a constant 3 N load in zero gravity: its kinetic energy is the
    load's work, F times the distance its nodes moved, so the total with the loads' potential
    (-F . x) is conserved (the summary read a drift of 1.0 and said the energy was expected to
    be conserved)."""
    text = ("[simulation]\nduration = 0.2\ndt = 0.001\ngravity = [0, 0, 0]\n[[bodies]]\nname = \"box\"\n"
            "model = \"fem\"\nshape = { type = \"box\", size = [0.2, 0.1, 0.1] }\nyoung = 1e7\n"
            "integrator = \"newmark\"\n[[bodies.loads]]\nbox = [[0.099, -1, -1], [1, 1, 1]]\n"
            "force = [3.0, 0.0, 0.0]\n")
    sim = Simulation(parse_scene(tomllib.loads(text), "<test>", Path(".")))
    conservation = sim.run(progress=False, log=lambda m: None)["conservation"]
    assert conservation["energy_conserved_expected"] and conservation["energy_changed_by"] == []
    assert conservation["energy_relative_drift"] < 1e-9
    # the body's motion is F t / m: the work is real, and what the drift is measured against
    box = sim.body("box")
    assert abs(box.velocity[0] - 3.0 * 0.2 / (1000.0 * 0.002)) < 1e-9 * 0.3


def test_restitution_is_no_energy_changer_where_only_deformable_bodies_meet_planes():
    """A deformable body dropped on a frictionless plane: the summary listed 'restitution below 1'
    (the default restitution of both), which acts on rigid contacts only."""
    text = ("[simulation]\nduration = 0.002\n[[planes]]\nfriction = 0.0\n[[bodies]]\nname = \"box\"\n"
            "model = \"fem\"\nshape = { type = \"box\", size = [0.1, 0.1, 0.1] }\nyoung = 1e6\n"
            "position = [0, 0, 0.1]\nintegrator = \"newmark\"\nfriction = 0.0\n")
    sim = Simulation(parse_scene(tomllib.loads(text), "<test>", Path(".")))
    assert sim.run(progress=False, log=lambda m: None)["conservation"]["energy_changed_by"] == \
        ["deformable contact"]
    rigid = text.replace('model = "fem"\n', "").replace("young = 1e6\n", "").replace('integrator = "newmark"\n', "")
    sim = Simulation(parse_scene(tomllib.loads(rigid), "<test>", Path(".")))
    assert sim.run(progress=False, log=lambda m: None)["conservation"]["energy_changed_by"] == \
        ["restitution below 1"]


def test_a_second_run_calls_rate_counts_only_its_own_steps():
    """A script that runs in pieces (run(until=0.1), then run(until=0.2)) read hundreds of
    thousands of steps/s at the second piece's first line: all the run's steps over the piece's
    wall time. The rate is the piece's steps over its wall time."""
    import io
    from hybrid.app.progress import Progress
    stream = io.StringIO()
    bar = Progress(0.2, stream=stream, first_steps=1_000_000)
    time.sleep(0.01)
    bar.update(0.1001, 1_000_001, force=True)       # one step in at least 10 ms
    assert float(stream.getvalue().split()[-2]) <= 100.0


def test_numpy_vectors_in_a_scene_changed_in_python_place_the_body_as_tuples_do():
    """A body's position set to a numpy array failed deep inside the scene's check ("the truth
    value of an array with more than one element is ambiguous"): arrays are vectors as tuples
    are, and the body starts where they say (free fall from there: z = z0 - g t^2 / 2 exactly
    for a rigid body)."""
    from dataclasses import replace
    scene = parse_scene(tomllib.loads('[simulation]\ndt = 0.001\nduration = 0.01\n[[bodies]]\nname = "b"\n'
                                      'shape = { type = "sphere", radius = 0.1 }\n'), "drop.toml", Path("."))
    moved = replace(scene, bodies=(replace(scene.bodies[0], position=np.array([1.0, 2.0, 10.0]),
                                           velocity=np.array([0.5, 0.0, 0.0])),),
                    simulation=replace(scene.simulation, gravity=np.array([0.0, 0.0, -9.81])))
    sim = Simulation(moved)
    for _ in range(10):
        sim.step()
    t = sim.time
    np.testing.assert_allclose(sim.body("b").position, [1.0 + 0.5 * t, 2.0, 10.0 - 9.81 * t * t / 2],
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize("dt, steps, expected", [(5e-4, 135, 0.0675), (1e-4, 200, 0.02), (1 / 240, 480, 2.0)])
def test_simulated_time_stays_on_the_grid_of_steps(dt, steps, expected):
    """Adding the step each time left 0.06750000000000005 after 135 steps of 0.5 ms (in the
    events and frames' times) and 0.019999999999999934 after 200 of 0.1 ms; the time is the
    multiple of the step, as near the decimal time as one rounding leaves it."""
    sim = Simulation(parse_scene(tomllib.loads(
        f'[simulation]\nduration = 1.0\ndt = {dt!r}\ngravity = [0.0, 0.0, 0.0]\n'
        '[[bodies]]\nname = "ball"\nshape = { type = "sphere", radius = 0.1 }\n'), "<t>", Path(".")))
    for _ in range(steps):
        sim.step()
    assert sim.time == steps * dt
    assert abs(sim.time - expected) <= 2 * np.spacing(expected)
    added = 0.0
    for _ in range(steps):
        added += dt
    assert added != sim.time                      # (the sum drifts off it: the test can fail)


def test_one_bodys_row_is_its_row_of_the_whole_table():
    """Simulation.body makes the one row it reads (all 404 rows of a pile took 0.7 ms a call):
    each body's row, rigid or deformable, is the one the whole table gives, value for value."""
    from hybrid.app import observe
    sim = Simulation(parse_scene(tomllib.loads(SCENE), "api_check", Path(".")))
    for _ in range(5):
        sim.step()
    table = observe.body_rows(sim.model, sim.state)
    assert {row[-1] for row in table} == {"rigid", "fem"}
    for k, row in enumerate(table):
        assert observe.body_rows(sim.model, sim.state, only=k) == [row]
        assert list(sim.body(row[1]).position) == list(row[2:5])


def test_a_checkpoint_interval_below_the_times_round_off_checkpoints_every_step(tmp_path):
    """--checkpoint-every 1e-300 ran for ever after its first frame (adding the interval to the
    next checkpoint's time until it passed now never got there, and a first Ctrl-C was not seen):
    the run ends, checkpointing at every step. Run in a child process so that a hang fails."""
    import subprocess
    import sys
    scene = tmp_path / "tiny.toml"
    scene.write_text('[simulation]\nduration = 0.02\ndt = 0.002\n[[planes]]\n[[bodies]]\nname = "box"\n'
                     'shape = { type = "box", size = [0.1, 0.1, 0.1] }\nposition = [0.0, 0.0, 0.3]\n')
    done = subprocess.run([sys.executable, "-m", "hybrid", "run", str(scene), "--out", str(tmp_path / "out"),
                           "--checkpoint-every", "1e-300"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["steps"] == 10


@pytest.mark.parametrize("path", [None, 3, 2.5])
def test_from_toml_of_something_that_is_no_path_says_what_it_takes(path):
    """``Simulation.from_toml(None)`` raised a bare TypeError from inside the path code."""
    with pytest.raises(TypeError, match=f"a scene file's path .* not {type(path).__name__}"):
        Simulation.from_toml(path)
