"""The ``hybrid`` command line end to end: run a small scene, read every output back, render it,
reject bad scenes cleanly, and run the built-in default scene."""
import csv
import json
import os
import subprocess
import sys
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest

from rigid import quaternion as quat
from rigid.mass import mass_properties
from rigid.shapes import make_shape

SMALL_SCENE = """\
[simulation]
name = "small"
duration = 0.3
dt = 0.004166666666666667
output_fps = 30

[[planes]]
friction = 0.5

[[bodies]]
name = "box"
shape = { type = "box", size = [0.2, 0.1, 0.1] }
position = [0.0, 0.0, 0.3]
angular_velocity = [1.0, 2.0, 0.5]

[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.08 }
density = 800.0
position = [0.3, 0.0, 0.2]
velocity = [0.5, 0.2, 1.0]
angular_velocity = [3.0, -1.0, 2.0]
"""
BODY_NAMES = ["box", "ball"]
FRAME_COUNT = 10            # t = 0, 1/30, ..., 0.3 s
COLUMNS = ["time", "body", "x", "y", "z", "qw", "qx", "qy", "qz", "vx", "vy", "vz",
           "wx", "wy", "wz", "kinetic_energy", "model"]


def hybrid(*args, cwd):
    """Run the console entry point as a user would; returns the CompletedProcess."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "hybrid", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """``hybrid run small.toml --out DIR`` once for the whole module: (scene folder, run folder, result)."""
    root = tmp_path_factory.mktemp("cli")
    (root / "small.toml").write_text(SMALL_SCENE)
    result = hybrid("run", "small.toml", "--out", "run", "--quiet", cwd=root)
    return root, root / "run", result


def test_run_writes_pvd_frames_csv_and_summary(small_run):
    _, out, result = small_run
    assert result.returncode == 0, result.stderr
    assert "done:" in result.stdout and "Traceback" not in result.stderr
    for name in ("small.pvd", "bodies.csv", "summary.json", "frames/frame_00000.vtu"):
        assert (out / name).is_file(), name


def test_pvd_lists_every_frame_in_increasing_time_and_meshio_reads_them(small_run):
    _, out, _ = small_run
    datasets = ET.parse(out / "small.pvd").getroot().findall("./Collection/DataSet")
    times = [float(d.get("timestep")) for d in datasets]
    files = [d.get("file") for d in datasets]
    assert len(datasets) == FRAME_COUNT
    assert np.all(np.diff(times) > 0)
    np.testing.assert_allclose(times, np.arange(FRAME_COUNT) / 30.0, atol=1e-9)
    assert sorted(p.name for p in (out / "frames").glob("*.vtu")) == [f.split("/")[-1] for f in files]
    for f in files:
        mesh = meshio.read(out / f)
        body_id = np.concatenate(mesh.cell_data["body_id"])
        assert len(body_id) == sum(len(block.data) for block in mesh.cells)
        assert sorted(np.unique(body_id)) == list(range(len(BODY_NAMES)))
        assert np.isfinite(mesh.points).all()


def test_bodies_csv_has_one_row_per_body_and_frame_with_consistent_kinetic_energy(small_run):
    _, out, _ = small_run
    with open(out / "bodies.csv", newline="") as f:
        reader = csv.DictReader(f)
        assert reader.fieldnames == COLUMNS
        rows = list(reader)
    assert len(rows) == len(BODY_NAMES) * FRAME_COUNT
    assert [r["body"] for r in rows] == BODY_NAMES * FRAME_COUNT
    assert {r["model"] for r in rows if r["body"] == "ball"} == {"rigid"}
    q = np.array([[float(r[k]) for k in ("qw", "qx", "qy", "qz")] for r in rows])
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)

    # the ball's mass and inertia from its mesh (the same mesh the simulator integrates)
    vertices, triangles = make_shape({"type": "sphere", "radius": 0.08})
    props = mass_properties(vertices, triangles, 800.0)
    ball = [r for r in rows if r["body"] == "ball"]
    for r in ball:
        v = np.array([float(r[k]) for k in ("vx", "vy", "vz")])
        w = np.array([float(r[k]) for k in ("wx", "wy", "wz")])
        R = quat.to_matrix(np.array([[float(r[k]) for k in ("qw", "qx", "qy", "qz")]]))[0]
        inertia_world = R @ props.inertia @ R.T
        expected = 0.5 * props.mass * v @ v + 0.5 * w @ inertia_world @ w
        assert float(r["kinetic_energy"]) == pytest.approx(expected, rel=1e-9)
    # the first row is the initial condition
    assert [float(ball[0][k]) for k in ("vx", "vy", "vz")] == pytest.approx([0.5, 0.2, 1.0])


def test_summary_reports_steps_timing_and_conservation(small_run):
    _, out, _ = small_run
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == 72
    assert summary["wall_time"] > 0
    assert summary["steps_per_second"] == pytest.approx(summary["steps"] / summary["wall_time"], rel=1e-6)
    assert "energy_relative_drift" in summary["conservation"]
    # gravity and a plane act: momentum is not expected to be conserved
    assert summary["conservation"]["momentum_conserved_expected"] is False
    # friction on the plane (and the default restitution of 0.5): energy is not conserved
    assert summary["conservation"]["energy_conserved_expected"] is False
    assert summary["conservation"]["energy_changed_by"] == ["friction", "restitution below 1"]


def test_render_writes_non_blank_pngs_and_a_movie(small_run):
    import imageio.v3 as iio
    _, out, _ = small_run
    result = hybrid("render", out, "--size", 320, 240, cwd=out.parent)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    pngs = sorted((out / "render").glob("frame_*.png"))
    assert len(pngs) == FRAME_COUNT
    for png in pngs[:: FRAME_COUNT - 1]:
        image = iio.imread(png)
        colours = np.unique(image.reshape(-1, image.shape[-1]), axis=0)
        assert image.std() > 5 and len(colours) > 2, f"{png.name} looks blank"
    movies = [p for p in (out / "render").iterdir() if p.suffix in (".mp4", ".gif")]
    assert len(movies) == 1 and movies[0].stat().st_size > 0


BAD_SCENES = {
    "negative_density": (SMALL_SCENE.replace("density = 800.0", "density = -800.0"), "density"),
    "unknown_key": (SMALL_SCENE.replace("output_fps = 30", "output_fps = 30\nbogus_key = 1"), "bogus_key"),
    # what `run` met only once it started (tracebacks, or `validate` saying OK to a scene `run` rejected)
    "no_bodies": (SMALL_SCENE[:SMALL_SCENE.index("[[bodies]]")], "[[bodies]]"),
    "auto_thresholds": (SMALL_SCENE.replace('name = "box"', 'name = "box"\nmodel = "auto"\nyoung = 1e6\n'
                                            'auto = { rigidify_strain = 1e-3, elastify_strain = 1e-4 }'),
                        "auto.elastify_strain"),
    "auto_threshold_above_the_default": (
        SMALL_SCENE.replace('name = "box"', 'name = "box"\nmodel = "auto"\nyoung = 1e6\n'
                            'auto = { rigidify_strain = 1e-2 }'), "got 0.001 (the default)"),
    "auto_window_beyond_reach": (SMALL_SCENE.replace('name = "box"', 'name = "box"\nmodel = "auto"\nyoung = 1e6\n'
                                                     'auto = { window = 100000000000000000000 }'),
                                 "auto.window' must be an integer in [1, 1e+06]"),
    "auto_table_on_a_rigid_body": (SMALL_SCENE.replace('name = "box"', 'name = "box"\nauto = { window = 5 }'),
                                   "'auto' needs model = \"auto\" (this body has model = \"rigid\")"),
    "anchor_holds_nothing": (SMALL_SCENE + 'model = "fem"\nyoung = 1e6\n'
                             '[[bodies.anchors]]\nbox = [[5.0, 5.0, 5.0], [6.0, 6.0, 6.0]]\n', "[[bodies.anchors]] 0 box"),
    "mesh_too_fine": (SMALL_SCENE.replace("size = [0.2, 0.1, 0.1] }", "size = [0.2, 0.1, 0.1], resolution = 1e-4 }"),
                      "shape.resolution"),
    "steps_beyond_reach": (SMALL_SCENE.replace("duration = 0.3\ndt = 0.004166666666666667",
                                               "duration = 1e300\ndt = 1e-300"), "dt"),
}


@pytest.mark.parametrize("command", ["validate", "run"])
@pytest.mark.parametrize("case", sorted(BAD_SCENES))
def test_bad_scene_exits_with_code_2_naming_file_and_field_without_traceback(tmp_path, command, case):
    text, field = BAD_SCENES[case]
    (tmp_path / f"{case}.toml").write_text(text)
    extra = ("--out", "out") if command == "run" else ()
    result = hybrid(command, f"{case}.toml", *extra, cwd=tmp_path)
    assert result.returncode == 2
    assert f"{case}.toml" in result.stderr and field in result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "outputs").exists()
    # every rejection ends with the same count line, whether parsing or building found it
    assert result.stderr.strip().splitlines()[-1].startswith(f"{case}.toml: 1 problem")


def test_out_naming_an_existing_file_exits_with_code_2_and_leaves_it(tmp_path):
    (tmp_path / "scene.toml").write_text(SMALL_SCENE)
    (tmp_path / "taken").write_text("mine")
    result = hybrid("run", "scene.toml", "--out", "taken", cwd=tmp_path)
    assert result.returncode == 2
    assert "--out" in result.stderr and "taken" in result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    assert (tmp_path / "taken").read_text() == "mine"


def test_run_without_a_scene_runs_the_built_in_default_scene(tmp_path):
    result = hybrid("run", "--out", "default_run", "--quiet", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "'default'" in result.stdout and "done:" in result.stdout
    summary = json.loads((tmp_path / "default_run" / "summary.json").read_text())
    assert summary["status"] == "ok"
    assert summary["simulated_time"] == pytest.approx(3.0)
    assert (tmp_path / "default_run" / "default.pvd").is_file()



PULLED_BAR = """\
[simulation]
duration = 0.02
dt = 0.001
gravity = [0.0, 0.0, 0.0]

[[bodies]]
name = "bar"
model = "fem"
shape = { type = "box", size = [0.1, 0.02, 0.02], resolution = 0.01 }
young = 1e7

[[bodies.anchors]]
box = [[-0.06, -0.02, -0.02], [-0.049, 0.02, 0.02]]

[[bodies.anchors]]
box = [[0.049, -0.02, -0.02], [0.06, 0.02, 0.02]]
velocity = [0.01, 0.0, 0.0]
"""


def test_a_moving_anchor_run_does_not_quote_an_energy_drift(tmp_path):
    """A bar pulled by a moving anchor gains the anchor's work: its energy 'drift' reads 1 and
    said nothing, so the log says the drift is not measured and the summary that energy is not
    expected to be conserved."""
    (tmp_path / "bar.toml").write_text(PULLED_BAR)
    result = hybrid("run", "bar.toml", "--out", "run", "--quiet", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "energy drift not measured: moving anchors do work" in result.stdout
    conservation = json.loads((tmp_path / "run" / "summary.json").read_text())["conservation"]
    assert conservation["energy_conserved_expected"] is False
    assert "moving anchors" in conservation["energy_changed_by"]
    assert conservation["energy_relative_drift"] > 0.5          # the anchor's work, not an error


@pytest.mark.parametrize("writer", ["inline", "thread"])
def test_an_output_that_cannot_be_written_mid_run_is_said_so_not_unstable(tmp_path, monkeypatch, capsys,
                                                                          writer):
    """A full disk (or a folder made unwritable) during a run ended it as 'unstable: a step
    failed ... in hybrid.app.vtu.write_vtu', exit 3, as if the physics had diverged: it is the
    output, exit 2, status failed, and the frames written before stay, counted as the summary's
    frames (written off the stepping thread, the summary counted the frame that failed)."""
    from hybrid.app import output
    from hybrid.app.cli import main
    write = output.write_vtu
    written = []

    def filling(path, *args, **kwargs):
        if len(written) == 3:
            raise OSError(28, "No space left on device")
        written.append(path)
        return write(path, *args, **kwargs)

    monkeypatch.setattr(output, "write_vtu", filling)
    monkeypatch.setenv("HYBRID_WRITER", writer)
    (tmp_path / "small.toml").write_text(SMALL_SCENE)
    code = main(["run", str(tmp_path / "small.toml"), "--out", str(tmp_path / "run"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "could not write the run's output" in err and "No space left on device" in err
    assert "unstable" not in err
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["frames"] == 3
    assert len(list((tmp_path / "run" / "frames").glob("frame_*.vtu"))) == 3


def test_a_write_that_fails_as_the_files_close_is_an_output_failure_with_its_summary(tmp_path, monkeypatch,
                                                                                      capsys):
    """Written off the stepping thread, the last frames' failed write can be found only as the
    files close, after the steps: it escaped as an OSError traceback (exit 1) with no summary."""
    from hybrid.app import output
    from hybrid.app.cli import main
    close = output.RunWriter.close

    def full(self, summary=None):
        close(self, None)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(output.RunWriter, "close", full)
    (tmp_path / "small.toml").write_text(SMALL_SCENE)
    code = main(["run", str(tmp_path / "small.toml"), "--out", str(tmp_path / "run"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "could not write the run's output" in err and "Traceback" not in err, err
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["status"] == "failed" and "No space left" in summary["error"]
    assert summary["frames"] == len(list((tmp_path / "run" / "frames").glob("frame_*.vtu")))
