"""Batch studies on Dask (``hybrid sweep``): variants run in parallel give the numbers they give
alone, a rerun keeps finished runs, bad settings are refused before anything runs, a failed run
does not stop the others, and the same command runs on a real scheduler and worker."""
import csv
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hybrid import sweep
from hybrid.app.cli import main
from hybrid.app.scene import SceneError
from hybrid.app.variants import SettingError, parse_value, toml_text

DROP = """[simulation]
duration = 0.25
dt = 0.004
output_fps = 40

[[planes]]
restitution = 0.3

[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.05 }
position = [0.0, 0.0, 0.3]
"""
BEAM = """[simulation]
duration = 0.02
dt = 0.01
gravity = [0.0, 0.0, -9.81]

[[bodies]]
name = "beam"
model = "fem"
shape = { type = "box", size = [0.2, 0.05, 0.05], resolution = 0.05 }
young = 1e7

[[bodies.anchors]]
box = [[-0.11, -1.0, -1.0], [-0.09, 1.0, 1.0]]
"""


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """A 2 x 2 sweep (time step x restitution) of a dropped ball on two local workers."""
    folder = tmp_path_factory.mktemp("study")
    scene = folder / "drop.toml"
    scene.write_text(DROP)
    rows = sweep(scene, ["simulation.dt=0.004,0.002", "bodies.ball.restitution=0.2,0.8"],
                 out=folder / "out", workers=2)
    return scene, folder / "out", rows


def test_two_by_two_sweep_on_two_workers_matches_each_variant_run_alone(study, tmp_path):
    scene, out, rows = study
    assert [r["status"] for r in rows] == ["ok"] * 4
    assert {(r["simulation.dt"], r["bodies.ball.restitution"]) for r in rows} == \
        {(0.004, 0.2), (0.004, 0.8), (0.002, 0.2), (0.002, 0.8)}
    table = list(csv.DictReader(open(out / "results.csv")))
    assert [t["id"] for t in table] == [r["id"] for r in rows]
    heights = {}
    for row in rows:
        folder = Path(row["folder"])
        alone = tmp_path / row["id"]
        assert main(["run", str(folder / "drop.toml"), "--out", str(alone), "--quiet"]) == 0
        assert (alone / "bodies.csv").read_bytes() == (folder / "bodies.csv").read_bytes()
        heights[row["bodies.ball.restitution"]] = float(row["ball.z"])
        # its cost is its stepping time, as for a run kept from before (not the worker's start)
        assert row["wall_s"] == json.loads((folder / "summary.json").read_text())["wall_time"]
    # the sweep changed what it says it changed: the livelier ball is higher when it ends
    assert heights[0.8] > heights[0.2] + 0.01


def test_a_rerun_keeps_finished_runs_and_reruns_the_interrupted_one(study):
    scene, out, rows = study
    summaries = {r["id"]: Path(r["folder"]) / "summary.json" for r in rows}
    stamps = {k: p.stat().st_mtime_ns for k, p in summaries.items()}
    interrupted = rows[1]["id"]
    summaries[interrupted].unlink()             # as a run stopped part way leaves it
    again = sweep(scene, ["simulation.dt=0.004,0.002", "bodies.ball.restitution=0.2,0.8"],
                  out=out, workers=1)
    assert [r["status"] for r in again] == ["ok"] * 4
    for key, path in summaries.items():
        if key == interrupted:
            assert path.exists()
        else:
            assert path.stat().st_mtime_ns == stamps[key], f"{key} was run again"
    assert [r["ball.z"] for r in again] == [r["ball.z"] for r in rows]


@pytest.mark.parametrize("setting, named", [
    ("bodies.nobody.restitution=0.1", "no body 'nobody'"),
    ("simulation.dtt=0.1,0.2", "dtt"),
    ("simulation.dt=0.01,-1", "dt"),
    ("planes.3.friction=0.1", "planes"),
    ("restitution=0.1", "restitution"),
    ("bodies.ball.velocity=0;0;-5,[0,0,-1e5]", "field 'velocity' starts it at a speed of 1e+05 m/s"),
])
def test_a_bad_set_is_an_exit_2_error_naming_the_key_and_nothing_runs(tmp_path, capsys, setting, named):
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    code = main(["sweep", str(scene), "--set", setting, "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert named in err and "nothing was run" in err and "Traceback" not in err
    assert not (tmp_path / "out" / "runs").exists()


def test_a_scheduler_that_cannot_be_reached_leaves_no_files_and_excludes_workers(tmp_path, capsys,
                                                                                monkeypatch):
    """Nothing is written before Dask is reached (the variant's scene file was, though the run
    said "nothing was run"); --workers and --scheduler are one or the other."""
    from hybrid.app import study

    def unreachable(workers, scheduler):
        raise OSError(f"Timed out trying to connect to {scheduler}")
    monkeypatch.setattr(study, "_client", unreachable)
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    out = tmp_path / "out"
    code = main(["sweep", str(scene), "--set", "simulation.dt=0.01", "--scheduler",
                 "tcp://127.0.0.1:1", "--out", str(out), "--quiet"])
    assert code == 2 and "nothing was run" in capsys.readouterr().err
    assert not out.exists()
    with pytest.raises(SystemExit) as exit_code:
        main(["sweep", str(scene), "--set", "simulation.dt=0.01", "--workers", "1", "--scheduler",
              "tcp://127.0.0.1:1", "--out", str(out)])
    assert exit_code.value.code == 2 and "not allowed with" in capsys.readouterr().err


def test_a_scheduler_address_that_is_no_address_is_an_exit_2_error(tmp_path, capsys):
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    out = tmp_path / "out"
    code = main(["sweep", str(scene), "--set", "simulation.dt=0.01", "--scheduler", "nonsense",
                 "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "--scheduler nonsense: not a scheduler address" in err
    assert "Traceback" not in err and not out.exists()


@pytest.mark.parametrize("address", ["http://127.0.0.1:8786", "tcp://127.0.0.1:99999"])
def test_a_scheduler_address_no_scheduler_has_is_refused_at_once_even_with_every_run_kept(
        tmp_path, capsys, monkeypatch, address):
    """A port out of range waited 20 s to time out; a wrong address with every run kept from an
    earlier study passed unnoticed (exit 0). Refused before Dask is tried."""
    from hybrid.app import study
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    out = tmp_path / "out"
    assert main(["sweep", str(scene), "--set", "simulation.dt=0.01", "--workers", "1", "--out",
                 str(out), "--quiet"]) == 0
    capsys.readouterr()

    def tried(workers, scheduler):
        raise AssertionError(f"Dask was tried at {scheduler}")
    monkeypatch.setattr(study, "_client", tried)
    code = main(["sweep", str(scene), "--set", "simulation.dt=0.01", "--scheduler", address,
                 "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and f"--scheduler {address}: not a scheduler address" in err, err


def test_a_key_set_twice_is_an_exit_2_error_and_nothing_runs(tmp_path, capsys):
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    code = main(["sweep", str(scene), "--set", "bodies.ball.restitution=0,0.5", "--set",
                 "bodies.ball.restitution=0.2", "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 2 and "bodies.ball.restitution: given more than once" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_set_values_and_variant_files_round_trip():
    assert parse_value("0;0;1.5") == [0, 0, 1.5]
    assert parse_value("[1, 2]") == [1, 2]
    assert parse_value("corotated") == "corotated"
    assert parse_value("true") is True
    data = {"simulation": {"dt": 0.1 / 3, "name": 'a "b"', "solver": {"iterations": 5}},
            "planes": [{"normal": [0.0, 0.0, 1.0]}],
            "bodies": [{"name": "x", "shape": {"type": "box", "size": [1.0, 2.0, 3.0]},
                        "anchors": [{"box": [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]}]}]}
    import tomllib
    assert tomllib.loads(toml_text(data)) == data
    # names past U+FFFF (an emoji: JSON's ASCII escapes made surrogate halves TOML refuses, and
    # every variant of such a scene failed), other scripts, control characters and DEL
    named = {"simulation": {"name": "Сцена_😀"},
             "bodies": [{"name": "кубик 😀", "material": {"k 😀": "a\x7f\x01\n\t\"\\"}}]}
    assert tomllib.loads(toml_text(named)) == named


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_port(port, process, seconds=30):
    end = time.time() + seconds
    while time.time() < end:
        assert process.poll() is None, "the Dask process ended"
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise AssertionError(f"nothing listens on port {port}")


def test_sweep_through_a_real_scheduler_and_worker_records_a_failed_run_and_runs_the_rest(
        tmp_path, capsys, monkeypatch):
    """Through a scheduler whose worker runs in another folder, with the study folder given
    relative to this one (as the default outputs/<scene>-sweep is): the worker is sent absolute
    paths (it failed every run, and the error it wrote over was lost)."""
    port = _free_port()
    dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    env = os.environ | {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    scheduler = subprocess.Popen(dask + ["--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    worker = None
    try:
        _wait_for_port(port, scheduler)
        address = f"tcp://127.0.0.1:{port}"
        worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address,
                                   "--nthreads", "1", "--no-dashboard", "--host", "127.0.0.1"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                                  cwd=Path(__file__).parent)
        scene = tmp_path / "beam.toml"
        scene.write_text(BEAM)
        monkeypatch.chdir(tmp_path)
        # the second anchor box holds no node: that variant fails when its bodies are built
        code = main(["sweep", "beam.toml", "--set",
                     "bodies.beam.anchors.0.box=[[-0.11,-1,-1],[-0.09,1,1]],[[5,5,5],[6,6,6]]",
                     "--scheduler", address, "--out", "out", "--quiet"])
        assert code == 3                    # a run failed: the exit code says so, the table is written
        rows = list(csv.DictReader(open(tmp_path / "out" / "results.csv")))
        assert [r["status"] for r in rows] == ["ok", "failed"]
        assert "anchor" in rows[1]["error"]
        summary = json.loads((tmp_path / rows[0]["folder"] / "summary.json").read_text())
        assert summary["status"] == "ok" and summary["steps"] == 2
        assert "1 of 2 runs ok" in capsys.readouterr().out
    finally:
        for process in (worker, scheduler):
            if process is not None:
                process.terminate()
                process.wait(timeout=30)


@pytest.mark.parametrize("tol", ["-1", "0", "1.5"])
def test_converge_refuses_a_tolerance_that_is_no_relative_error(tmp_path, capsys, tol):
    assert main(["converge", "default", "--tol", tol, "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert "give a relative error between 0 and 1" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_variant_whose_mesh_file_changed_is_not_taken_as_finished(tmp_path):
    """A study run again keeps a run only if its inputs are the same: the mesh a body reads as
    well as the scene text (it kept results made from an older mesh)."""
    import shutil
    from hybrid.app.study import finished
    from hybrid.app.variants import make_variants
    root = Path(__file__).resolve().parents[1]
    shutil.copy(root / "meshes" / "ball_r10cm.vtu", tmp_path / "m.vtu")
    scene = tmp_path / "m.toml"
    scene.write_text('[simulation]\nduration = 0.01\n[[bodies]]\nname = "thing"\nmesh = "m.vtu"\n')
    variant = make_variants(scene, [{"bodies.thing.restitution": 0.5}])[0]
    run = tmp_path / "run"
    run.mkdir()
    (run / variant.file_name).write_text(variant.text())
    (run / "summary.json").write_text(json.dumps({"status": "ok", "wall_time": 0.1}))
    assert finished(run, variant.text(), variant.file_name)
    (tmp_path / "m.vtu").write_bytes((tmp_path / "m.vtu").read_bytes() + b"\n")
    assert not finished(run, variant.text(), variant.file_name)


def test_a_plot_against_a_vector_key_is_refused_before_anything_runs(tmp_path, capsys):
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    code = main(["sweep", str(scene), "--set", "bodies.ball.position=0;0;0.55,0;0;0.85", "--out",
                 str(tmp_path / "out"), "--plot", "ball.z:bodies.ball.position", "--quiet"])
    assert code == 2 and "takes values that are not numbers" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_sweep_from_python_names_its_settings_keys_not_the_command_line(tmp_path):
    """sweep() given a dict words its errors in its own terms (they read "--set ..." and
    "--zip", the command line's flags, which a Python caller never gave); nothing runs."""
    from hybrid import SettingError, sweep        # (the public names api.md gives)
    with pytest.raises(SettingError) as error:
        sweep("dent", {"bodies.nope.young": [1e9]}, out=tmp_path / "a")
    assert str(error.value).startswith("settings key bodies.nope.young: no body 'nope'")
    with pytest.raises(SettingError) as error:
        sweep("dent", {"simulation.dt": [1e-3, 2e-3], "bodies.plate.young": [1e9]},
              out=tmp_path / "b", zipped=True)
    assert "--" not in str(error.value) and str(error.value).startswith("zipped=True needs")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


@pytest.mark.parametrize("key", ["simulation.dt=0.001,0.002", "simulation.output_fps=10,20"])
def test_converge_refuses_a_setting_its_ladder_sets(tmp_path, capsys, key):
    """A --set of the time step (or the frame rate the ladder aligns) was overwritten by the
    ladder in every run, and the table labelled the runs by the values never used."""
    code = main(["converge", "default", "--set", key, "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "ladder sets it in every run" in err and key.split("=")[0] in err
    assert not (tmp_path / "out").exists()


def test_a_study_run_again_with_a_value_added_keeps_every_run_it_had(tmp_path):
    """Run ids name the variant, not its place in the grid: a value added in the middle kept
    only the runs before it (numbered by position, the later ones ran again under new numbers
    and their old folders were left behind)."""
    from hybrid.app.study import sweep
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    out = tmp_path / "out"
    first = sweep(scene, {"simulation.dt": [0.01, 0.005]}, out, workers=1)
    again = sweep(scene, {"simulation.dt": [0.01, 0.0075, 0.005]}, out, workers=1)
    kept = {r["id"]: r for r in again}
    assert all(kept[r["id"]]["wall_s"] == r["wall_s"] for r in first)      # not run again
    assert len(list((out / "runs").iterdir())) == 3


def test_python_studies_take_numpy_values_and_refuse_bad_workers_and_tolerances(tmp_path):
    """From Python: numpy numbers and arrays are values like any (an np.int64 was refused as no
    integer, an array taken as one value); workers=-1 (which waited for ever) and tol=5 (taken
    silently) are errors in the API's words."""
    import numpy as np
    from hybrid.app.converge import converge
    from hybrid.app.study import sweep
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    rows = sweep(scene, {"simulation.solver.iterations": np.arange(5, 7),
                         "bodies.ball.restitution": np.float32(0.5)}, tmp_path / "out", workers=1)
    assert [r["status"] for r in rows] == ["ok", "ok"]
    with pytest.raises(SettingError, match="workers=-1"):
        sweep(scene, {"simulation.dt": [0.01]}, tmp_path / "w", workers=-1)
    with pytest.raises(SettingError, match="tol=5"):
        converge(scene, tmp_path / "c", tol=5)
    with pytest.raises(SceneError, match="settings key"):
        sweep(scene, {"simulation.dt": [-1.0]}, tmp_path / "neg", workers=1)
    # an empty list ran nothing and returned an empty table
    with pytest.raises(SettingError, match="simulation.dt: no values given"):
        sweep(scene, {"simulation.dt": []}, tmp_path / "none", workers=1)
    assert not (tmp_path / "w").exists() and not (tmp_path / "c").exists()
    assert not (tmp_path / "none").exists()


def test_the_convergence_report_says_why_it_has_no_extrapolation():
    """A two-level ladder, failed runs and an erratic order are told apart (all three read
    "erratic"), and a study whose every run failed says so instead of asking for more levels."""
    from hybrid.app.study_cli import report

    def row(dt, status="ok", method="finest-difference"):
        return {"id": f"dt={dt}", "dt": dt, "resolution": "", "status": status,
                "error:ball.z": 0.1, "estimate:ball.z": method, "recommended": False,
                "max_relative_error": 0.1, "wall_per_sim_s": 1.0}
    two = report([row(0.01), row(0.005)], 0.01)
    assert "a ladder of 2 levels gives no observed order" in two[0]
    failed = report([row(0.01), row(0.005, "unstable"), row(0.0025)], 0.01)
    assert "runs of the ladder did not finish ok" in failed[0]
    erratic = report([row(0.01), row(0.005), row(0.0025)], 0.01)
    assert "do not shrink steadily at one order" in erratic[0]
    none = report([row(0.01, "unstable"), row(0.005, "failed")], 0.01)
    assert "no run finished ok" in none[0] and "every run failed" in none[-1]
    assert not any("add --dt levels" in line for line in none)


def test_the_convergence_report_tells_each_group_of_a_set_apart():
    """``--set bodies.bar.integrator=backward_euler,newmark`` makes two ladders: one was
    extrapolated and the other not, and the report said both were differences from the finest
    run, and that the recommended run (from the extrapolated one) was measured against an
    unconverged run. Each group is now reported by itself."""
    from hybrid.app.study_cli import report

    def row(k, dt, integrator, method, recommended=False):
        return {"id": f"{k:03d}", "bodies.bar.integrator": integrator, "dt": dt, "resolution": "",
                "status": "ok", "error:bar.com": 0.01, "estimate:bar.com": method,
                "recommended": recommended, "max_relative_error": 0.01, "wall_per_sim_s": 1.0 + k}
    rows = [row(0, 0.01, "backward_euler", "richardson"),
            row(1, 0.005, "backward_euler", "richardson", recommended=True),
            row(2, 0.0025, "backward_euler", "richardson"),
            row(3, 0.01, "newmark", "finest-difference"), row(4, 0.005, "newmark", "finest-difference"),
            row(5, 0.0025, "newmark", "finest-difference")]
    lines = report(rows, 0.05)
    told = [line for line in lines if "differences from the finest run" in line]
    assert len(told) == 1 and told[0].startswith("bar.com (bodies.bar.integrator=newmark): "), lines
    assert lines[-1].startswith("recommended: dt = 0.005 s") and "not converged" not in lines[-1], lines
    assert "bodies.bar.integrator=backward_euler" in lines[-1]


@pytest.mark.parametrize("plot, ok", [("simulated_time", True), ("ball.z", True), ("nobody.z", False)])
def test_sweep_plots_every_documented_figure_and_refuses_a_body_the_scene_lacks(tmp_path, capsys,
                                                                               plot, ok):
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    out = tmp_path / "out"
    code = main(["sweep", str(scene), "--set", "simulation.dt=0.004,0.002", "--plot", plot,
                 "--out", str(out), "--quiet"])
    if ok:
        assert code == 0 and (out / f"{plot}.png").exists()
    else:
        assert code == 2 and "no body 'nobody'; bodies: ball" in capsys.readouterr().err
        assert not out.exists()


def test_ctrl_c_stops_a_sweep_with_one_line_and_no_worker_tracebacks(tmp_path):
    """Ctrl-C goes to the terminal's whole process group: the workers, given it too, printed
    pages of Dask tracebacks as they closed. They start with it ignored; the study stops them."""
    scene = tmp_path / "long.toml"
    scene.write_text(DROP.replace("duration = 0.25", "duration = 1000.0"))
    cli = Path(sys.executable).with_name("hybrid")
    run = subprocess.Popen([str(cli), "sweep", str(scene), "--set", "simulation.dt=0.004,0.002",
                            "--workers", "2", "--out", str(tmp_path / "out")],
                           env=dict(os.environ, OPENBLAS_NUM_THREADS="1"), start_new_session=True,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        end = time.time() + 60          # until both runs have started writing
        while len(list((tmp_path / "out").glob("runs/*/*.pvd"))) < 2 and time.time() < end:
            time.sleep(0.2)
        os.killpg(run.pid, signal.SIGINT)
        _, err = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
    err = err.decode()
    assert run.returncode == 130 and "interrupted (Ctrl-C)" in err
    assert "Traceback" not in err and "ERROR" not in err, err


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"])
def test_a_sweep_stopped_by_ctrl_c_writes_its_table_with_the_runs_it_finished(tmp_path, monkeypatch,
                                                                              signal_name):
    """Ctrl-C on a sweep wrote no results.csv, though runs had finished: the table is written
    (the unfinished runs as `interrupted`, without the partial files' figures) and the
    interruption goes on to the caller (the command line exits 130). SIGTERM (a batch
    scheduler's) did the same without even the table; now as Ctrl-C, then exit 143."""
    from hybrid.app import study as study_module
    from hybrid.app.entry import Terminated
    stop = KeyboardInterrupt if signal_name == "SIGINT" else Terminated

    def one_then_ctrl_c(todo, texts, total, workers, scheduler, progress):
        record, text = todo[0], texts[0]
        Path(record["folder"]).mkdir(parents=True)
        Path(record["scene_file"]).write_text(text)
        record.update(study_module.run_variant(record["scene_file"], record["folder"]))
        raise stop

    monkeypatch.setattr(study_module, "_dispatch", one_then_ctrl_c)
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    with pytest.raises(stop):
        sweep(scene, ["bodies.ball.restitution=0.2,0.8"], out=tmp_path / "out", workers=1)
    table = list(csv.DictReader(open(tmp_path / "out" / "results.csv")))
    assert [t["status"] for t in table] == ["ok", "interrupted"]
    assert table[0]["ball.z"] != "" and table[1].get("ball.z", "") == ""
    assert ("Ctrl-C" if signal_name == "SIGINT" else "SIGTERM") in table[1]["error"]


def test_a_value_given_twice_is_refused_before_anything_runs(tmp_path, capsys):
    """0.3,0.30,3e-1 ran one variant three times into one folder and gave three identical rows."""
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    code = main(["sweep", str(scene), "--set", "simulation.duration=0.3,0.30,3e-1", "--out",
                 str(tmp_path / "out"), "--quiet"])
    assert code == 2 and "more than once" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_setting_names_a_body_whose_name_has_dots():
    """``bodies.ball.v2.density`` was read as body 'ball', field 'v2': "no body 'ball'". The key
    takes the longest body name it begins with."""
    from hybrid.app.variants import SettingError, apply_setting
    data = {"bodies": [{"name": "ball"}, {"name": "ball.v2", "shape": {"type": "sphere"}}]}
    apply_setting(data, "bodies.ball.v2.density", 500.0)
    apply_setting(data, "bodies.ball.v2.shape.radius", 0.1)
    apply_setting(data, "bodies.ball.density", 300.0)
    assert data["bodies"][1]["density"] == 500.0 and data["bodies"][1]["shape"]["radius"] == 0.1
    assert data["bodies"][0] == {"name": "ball", "density": 300.0}
    with pytest.raises(SettingError, match="no body 'bal'"):
        apply_setting(data, "bodies.bal.v2.density", 1.0)


def test_a_run_that_ended_as_ctrl_c_came_is_tabled_ok(tmp_path, monkeypatch):
    """A run whose worker wrote its `ok` summary as Ctrl-C came, before the study collected its
    result, was tabled `interrupted` (a rerun then listed it ok): it is tabled from its files."""
    from hybrid.app import study as study_module

    def both_end_then_ctrl_c(todo, texts, total, workers, scheduler, progress):
        for record, text in zip(todo, texts):
            Path(record["folder"]).mkdir(parents=True)
            Path(record["scene_file"]).write_text(text)
            study_module.run_variant(record["scene_file"], record["folder"])   # not collected
        raise KeyboardInterrupt

    monkeypatch.setattr(study_module, "_dispatch", both_end_then_ctrl_c)
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    with pytest.raises(KeyboardInterrupt):
        sweep(scene, ["bodies.ball.restitution=0.2,0.8"], out=tmp_path / "out", workers=1)
    table = list(csv.DictReader(open(tmp_path / "out" / "results.csv")))
    assert [t["status"] for t in table] == ["ok", "ok"]
    assert all(t["ball.z"] != "" for t in table)


@pytest.mark.parametrize("scene_changed", [False, True])
def test_a_run_a_stop_left_a_checkpoint_goes_on_from_it_in_a_rerun(tmp_path, scene_changed):
    """A study run stopped after its first 10 s of wall time leaves a checkpoint, and every rerun
    of the study failed it ("holds a run that did not finish"): a rerun continues it to the files
    an unstopped run writes, or, its checkpoint being of another scene text, runs it anew."""
    from hybrid import Simulation
    from hybrid.app import checkpoint
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    setting = ["bodies.ball.restitution=0.5"]
    whole = sweep(scene, setting, out=tmp_path / "whole", workers=1)[0]
    folder = tmp_path / "out" / "runs" / whole["id"]
    folder.mkdir(parents=True)
    variant = folder / "drop.toml"
    text = (Path(whole["folder"]) / "drop.toml").read_text()
    variant.write_text(text.replace("0.3]", "0.4]") if scene_changed else text)
    request = checkpoint.StopRequest()
    request.set()
    with pytest.raises(checkpoint.Stopped):
        Simulation.from_toml(variant).run(out=folder, progress=False, log=lambda m: None, stop=request)
    assert (folder / "checkpoint.npz").is_file()
    again = sweep(scene, setting, out=tmp_path / "out", workers=1)[0]
    assert again["status"] == "ok", again["error"]
    assert not (folder / "checkpoint.npz").exists()
    assert (folder / "bodies.csv").read_bytes() == (Path(whole["folder"]) / "bodies.csv").read_bytes()
    assert json.loads((folder / "summary.json").read_text())["steps"] == \
        json.loads((Path(whole["folder"]) / "summary.json").read_text())["steps"]


def test_every_bad_set_key_is_named_not_only_the_first(tmp_path, capsys):
    """A sweep with two keys that lead nowhere named only the first, though every problem of
    the input is listed elsewhere: both are named, once each, and nothing runs."""
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    code = main(["sweep", str(scene), "--set", "bodies.nobody.restitution=0.1,0.2",
                 "--set", "planes.3.friction=0.1,0.2", "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "no body 'nobody'" in err and "planes.3.friction" in err, err
    assert err.count("no body 'nobody'") == 1 and "nothing was run" in err
    assert not (tmp_path / "out" / "runs").exists()


def test_a_plot_without_a_key_is_drawn_against_the_first_key_swept_over_several_values():
    """A --set with one value came first and was the x axis: one point per line, all at x = 0.02."""
    from hybrid.app.plots import _plot_parts
    keys = ["simulation.duration", "bodies.slab.shape.resolution", "bodies.jelly.young"]
    rows = [{"simulation.duration": 0.02, "bodies.slab.shape.resolution": r, "bodies.jelly.young": y}
            for r in (0.1, 0.05) for y in (5e4, 1e5)]
    values = [[row[k] for row in rows] for k in keys]
    assert _plot_parts("slab.z", keys, values) == ("slab.z", "bodies.slab.shape.resolution")
    assert _plot_parts("slab.z:bodies.jelly.young", keys, values) == ("slab.z", "bodies.jelly.young")
    assert _plot_parts("cracks", keys[:1], values[:1]) == ("cracks", "simulation.duration")


def test_a_study_into_a_folder_another_study_uses_is_refused_before_it_runs(tmp_path, capsys):
    """Two studies into one folder at once: the second's runs failed on the first's run folders
    (writing error.txt there) and whichever ended last wrote the table. The study folder is
    locked for a study's runs: the second is refused with exit 2, nothing run or written."""
    import socket
    import subprocess
    from hybrid.app import run_lock
    scene = tmp_path / "drop.toml"
    scene.write_text(DROP)
    out = tmp_path / "out"
    out.mkdir()
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (out / run_lock.LOCK_FILE).write_text(f"{other.pid} {socket.gethostname()}\n")
        code = main(["sweep", str(scene), "--set", "simulation.dt=0.01", "--workers", "1",
                     "--out", str(out), "--quiet"])
        err = capsys.readouterr().err
        assert code == 2 and f"another run (process {other.pid}) writes there" in err
        assert "nothing was run" in err
        assert sorted(p.name for p in out.iterdir()) == [run_lock.LOCK_FILE]
    finally:
        other.kill()
        other.wait()
