"""A long run survives being stopped (issue 25): SIGTERM stops ``hybrid run`` after a whole step
with a checkpoint, ``--resume`` continues it to the files an uninterrupted run writes, bit for
bit; checkpoints of another scene, damaged ones and ones of another format version are refused."""
import json
import os
import shlex
import signal
import subprocess
import sys
import time
import zipfile

import numpy as np
import pytest

from hybrid import Simulation
from hybrid.app import checkpoint
from hybrid.app.cli import main

# plasticity with two reference-shape updates (t = 0.027 and 0.04 s) and a tear that splits the
# bar in two (t = 0.047 s), then 0.2 s more; meanwhile a ball rolls over a soft slab, whose contact
# response the solver learns node by node as the ball reaches them (a run resumed at t = 0.1 s
# without what was learnt drifts from t = 0.119 s: CHOLMOD's columns solved in other batches
# differ in the last bits)
SCENE = """\
[simulation]
name = "split"
duration = 0.25
dt = 0.001
output_fps = 200

[[planes]]
friction = 0.5

[[bodies]]
name = "bar"
model = "fem"
shape = { type = "box", size = [0.2, 0.02, 0.02], resolution = 0.01 }
position = [0.0, 0.0, 0.3]
young = 1.0e8
poisson = 0.3
density = 1000.0
yield_stress = 1.0e6
tearing_strain = 0.05
fracture_stress = 1.5e6

[[bodies.anchors]]
box = [[-1, -1, -1], [-0.099999, 1, 1]]

[[bodies.anchors]]
box = [[0.099999, -1, -1], [1, 1, 1]]
velocity = [0.2, 0.0, 0.0]

[[bodies]]
name = "slab"
model = "fem"
shape = { type = "box", size = [0.3, 0.1, 0.02], resolution = 0.02 }
position = [0.3, 0.0, 0.0105]
young = 1.0e6
density = 500.0

[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.03 }
position = [0.2, 0.0, 0.052]
velocity = [2.0, 0.0, 0.0]
"""

# a quick scene for the refusals: one ball falling onto the ground
QUICK = """\
[simulation]
name = "quick"
duration = 0.05
dt = 0.005

[[planes]]

[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.05 }
position = [0.0, 0.0, 0.2]
"""


def hybrid(*args, cwd, **popen):
    """``python -m hybrid ARGS`` in ``cwd``, started (a Popen)."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, "-m", "hybrid", *map(str, args)], cwd=cwd, env=env,
                            text=True, **popen)


def stopped_after_split(root):
    """``hybrid run`` of SCENE into ``root/stopped`` sent SIGTERM once it has written its first
    checkpoint (t = 0.1 s, after the split; the ball is still rolling over the slab): (exit
    code, stderr lines)."""
    with open(root / "stopped.log", "w") as log:
        run = hybrid("run", "scene.toml", "--out", "stopped", "--quiet", "--checkpoint-every",
                     "0.1", cwd=root, stdout=subprocess.DEVNULL, stderr=log)
        deadline = time.monotonic() + 120
        while not (root / "stopped" / "checkpoint.npz").exists() and run.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.02)
        run.send_signal(signal.SIGTERM)
        code = run.wait(timeout=120)
    return code, (root / "stopped.log").read_text().splitlines(keepends=True)


def test_a_run_stopped_by_sigterm_after_a_fracture_resumes_to_the_uninterrupted_files(tmp_path):
    (tmp_path / "scene.toml").write_text(SCENE)
    whole = hybrid("run", "scene.toml", "--out", "whole", "--quiet", "--checkpoint-every", "0",
                   cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    code, lines = stopped_after_split(tmp_path)
    assert whole.wait(timeout=120) == 0, whole.stderr.read()
    text = "".join(lines)
    assert code == 143, text
    assert any("took its plastic deformation" in line for line in lines)     # before the split
    split = float(next(line for line in lines if "split off" in line).split()[2])
    stopped = tmp_path / "stopped"
    manifest = json.loads(np.load(stopped / "checkpoint.npz")["manifest"].tobytes())
    assert split < 0.1 <= manifest["time"] < 0.2 and manifest["version"] == checkpoint.VERSION
    assert json.loads((stopped / "summary.json").read_text())["status"] == "stopped"
    command = shlex.split(text.split("Resume with:")[1].strip().splitlines()[0])
    assert command[:2] == ["hybrid", "run"] and "--resume" in command
    # what a run killed after its checkpoint leaves is dropped: a frame and half a row more
    frames = sorted((stopped / "frames").glob("frame_*.vtu"))
    (stopped / "frames" / f"frame_{len(frames):05d}.vtu").write_bytes(frames[-1].read_bytes())
    with open(stopped / "bodies.csv", "a") as f:
        f.write("0.3,bar,1.0,2.")
    resumed = hybrid(*command[1:], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    output = resumed.communicate(timeout=120)[0]
    assert resumed.returncode == 0, output
    whole = tmp_path / "whole"
    for name in ("bodies.csv", "regions.csv", "split.pvd"):
        assert (stopped / name).read_bytes() == (whole / name).read_bytes(), name
    last = sorted((whole / "frames").glob("frame_*.vtu"))
    assert [p.name for p in sorted((stopped / "frames").glob("frame_*.vtu"))] == [p.name for p in last]
    assert (stopped / "frames" / last[-1].name).read_bytes() == last[-1].read_bytes()
    assert "bar.1" in (whole / "bodies.csv").read_text()
    summary = json.loads((stopped / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["steps"] == 250
    assert summary["events"] == json.loads((whole / "summary.json").read_text())["events"]
    assert not (stopped / "checkpoint.npz").exists()          # a finished run leaves none


@pytest.fixture
def stopped_quick(tmp_path):
    """A checkpoint of QUICK after one step (a stop asked before the run): (folder, scene)."""
    scene = tmp_path / "quick.toml"
    scene.write_text(QUICK)
    request = checkpoint.StopRequest()
    request.set()                   # as on SIGINT
    with pytest.raises(checkpoint.Stopped) as stopped:
        Simulation.from_toml(scene).run(out=tmp_path / "run", progress=False, log=lambda m: None,
                                        stop=request)
    assert stopped.value.exit_code == 130 and stopped.value.checkpoint.is_file()
    return tmp_path / "run", scene


def resume_code(capsys, scene, out):
    """``hybrid run SCENE --out OUT --resume`` in this process: (exit code, stderr)."""
    code = main(["run", str(scene), "--out", str(out), "--resume", "--quiet"])
    return code, capsys.readouterr().err


def test_a_checkpoint_resumes_to_the_end_of_its_run(capsys, stopped_quick):
    out, scene = stopped_quick
    code, err = resume_code(capsys, scene, out)
    assert code == 0, err
    assert json.loads((out / "summary.json").read_text())["steps"] == 10


def test_a_checkpoint_of_another_scene_is_refused(capsys, stopped_quick):
    out, scene = stopped_quick
    scene.write_text(QUICK.replace("0.2]", "0.3]"))
    code, err = resume_code(capsys, scene, out)
    assert code == 2 and "checkpoint.npz" in err and "content differs" in err, err
    assert "Traceback" not in err


def test_a_truncated_checkpoint_is_refused(capsys, stopped_quick):
    out, scene = stopped_quick
    data = (out / "checkpoint.npz").read_bytes()
    (out / "checkpoint.npz").write_bytes(data[:len(data) // 2])
    code, err = resume_code(capsys, scene, out)
    assert code == 2 and "truncated or corrupted" in err, err


def test_a_corrupted_checkpoint_is_refused(capsys, stopped_quick):
    out, scene = stopped_quick
    data = bytearray((out / "checkpoint.npz").read_bytes())
    middle = len(data) // 2
    data[middle:middle + 16] = bytes(255 - b for b in data[middle:middle + 16])
    (out / "checkpoint.npz").write_bytes(bytes(data))
    code, err = resume_code(capsys, scene, out)
    assert code == 2 and "truncated or corrupted" in err, err


def test_a_checkpoint_overwritten_with_junk_is_refused_without_advice_to_load_it_unsafely(capsys, stopped_quick):
    """numpy takes a file that is no archive for pickled data, and its message advises loading it
    with allow_pickle=True: a checkpoint is never loaded so, and the message says what it is."""
    out, scene = stopped_quick
    (out / "checkpoint.npz").write_bytes(b"not a checkpoint at all\n" * 40)
    code, err = resume_code(capsys, scene, out)
    assert code == 2 and "truncated or corrupted" in err and "not a .npz archive" in err, err
    assert "allow_pickle" not in err and "unsafe" not in err, err


@pytest.mark.parametrize("damage", ["garbage", "cut short"])
def test_a_damaged_frame_the_checkpoint_counts_is_refused(capsys, stopped_quick, damage):
    """A frame the checkpoint counts, overwritten with garbage or cut short since: the resume
    refuses it, naming the file (it went on, and left a frame no reader opens), before it says
    it is resuming, and leaves the folder as it was."""
    out, scene = stopped_quick
    frame = sorted((out / "frames").glob("frame_*.vtu"))[0]
    data = frame.read_bytes()
    frame.write_bytes(b"garbage" * 100 if damage == "garbage" else data[:len(data) // 2])
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    code = main(["run", str(scene), "--out", str(out), "--resume", "--quiet"])
    said = capsys.readouterr()
    assert code == 2 and frame.name in said.err and "not a whole .vtu file" in said.err, said.err
    assert "Traceback" not in said.err
    assert "resuming" not in said.out, said.out
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def rewritten(path, change):
    """Rewrite checkpoint ``path`` with its manifest passed through ``change``."""
    with np.load(path) as z:
        arrays = {name: z[name] for name in z.files}
    manifest = change(json.loads(arrays.pop("manifest").tobytes()))
    data = np.frombuffer(json.dumps(manifest).encode(), dtype=np.uint8)
    with open(path, "wb") as f:
        np.savez(f, manifest=data, **arrays)


def test_a_checkpoint_of_another_format_version_is_refused(capsys, stopped_quick):
    out, scene = stopped_quick
    rewritten(out / "checkpoint.npz", lambda m: m | {"version": checkpoint.VERSION + 1})
    code, err = resume_code(capsys, scene, out)
    assert code == 2 and f"format version {checkpoint.VERSION + 1}" in err, err


def test_a_checkpoint_naming_a_class_outside_the_project_is_refused_without_importing_it(
        capsys, stopped_quick):
    out, scene = stopped_quick

    def evil(manifest):
        manifest["content"]["dict"][0][1] = {"id": 999, "dataclass": "subprocess:Popen",
                                             "fields": {"args": "touch pwned"}, "rebuilt": []}
        return manifest

    rewritten(out / "checkpoint.npz", evil)
    code, err = resume_code(capsys, scene, out)
    assert code == 2 and "subprocess:Popen" in err and "not one a checkpoint may hold" in err, err
    assert not (out.parent / "pwned").exists()


def test_a_missing_checkpoint_and_an_object_array_are_refused(capsys, stopped_quick):
    out, scene = stopped_quick
    with zipfile.ZipFile(out / "checkpoint.npz") as z:
        assert "manifest.npy" in z.namelist()
    with open(out / "checkpoint.npz", "wb") as f:
        np.savez(f, manifest=np.array([object()], dtype=object))
    code, err = resume_code(capsys, scene, out)
    assert code == 2 and "truncated or corrupted" in err, err
    (out / "checkpoint.npz").unlink()
    code, err = resume_code(capsys, scene, out)
    assert code == 2 and "no checkpoint to resume from" in err, err


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_swallowed_before_the_run_steps_stops_the_run_at_once(tmp_path, signum):
    """A SIGTERM or SIGINT whose exception the entry point raised inside a callback (an import
    lock's, or a library's bare ``except``: the command went on) still stops the run: its stop
    request is set as the run takes the signals over, so it writes its checkpoint after its
    first step and stops (the run had gone on to its end, exit 0; for SIGINT seen once in the
    suite, with Python's own handler, which keeps no record)."""
    from hybrid.app import entry
    error = entry.Terminated if signum == signal.SIGTERM else KeyboardInterrupt
    handler = entry._OnSignal(error)
    with pytest.raises(error):
        handler(signum, None)
    previous = signal.signal(signum, handler)
    try:
        sim = Simulation.from_toml("default")
        with checkpoint.stop_on_signals() as request:
            assert request.signal == signum
            with pytest.raises(checkpoint.Stopped) as stopped:
                sim.run(out=tmp_path / "out", progress=False, log=lambda line: None, stop=request)
    finally:
        signal.signal(signum, previous)
    assert sim.steps == 1 and (tmp_path / "out" / "checkpoint.npz").exists()
    assert stopped.value.exit_code == 128 + signum


def test_a_fresh_run_into_a_stopped_runs_folder_is_refused_and_keeps_its_checkpoint(capsys, stopped_quick):
    """``hybrid run`` without --resume into a stopped run's folder removed its checkpoint and
    summary at once, and started again from t = 0: one missing flag lost the run. It is refused
    (exit 2), the checkpoint kept, and the message says both ways on; the resume still works."""
    out, scene = stopped_quick
    before = (out / "checkpoint.npz").read_bytes()
    code = main(["run", str(scene), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "holds a run that did not finish" in err and "--resume" in err, err
    assert (out / "checkpoint.npz").read_bytes() == before
    assert json.loads((out / "summary.json").read_text())["status"] == "stopped"
    code, err = resume_code(capsys, scene, out)
    assert code == 0, err


def test_a_python_run_into_a_stopped_runs_folder_is_refused_and_keeps_its_checkpoint(capsys, stopped_quick):
    """``Simulation.run(out=...)`` into a stopped run's folder removed its checkpoint without a
    word, where ``hybrid run`` refuses; a resumed simulation still continues there."""
    out, scene = stopped_quick
    before = (out / "checkpoint.npz").read_bytes()
    with pytest.raises(ValueError, match="holds a run that did not finish"):
        Simulation.from_toml(scene).run(out=out, progress=False, log=lambda m: None)
    assert (out / "checkpoint.npz").read_bytes() == before
    assert Simulation.resume(scene, out).run(out=out, progress=False, log=lambda m: None)["status"] == "ok"
    assert not (out / "checkpoint.npz").exists()


def test_a_run_stopped_early_gives_no_rigid_hint(tmp_path):
    """A soft block stopped after its first step had not strained yet, and the log told it to be
    rigid; the hint waits for a run that ends."""
    scene = tmp_path / "block.toml"
    scene.write_text("""[simulation]
duration = 0.1
dt = 0.005
[[planes]]
[[bodies]]
name = "block"
model = "fem"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
position = [0.0, 0.0, 0.2]
young = 1e6
""")
    request = checkpoint.StopRequest()
    request.signal = signal.SIGINT
    lines = []
    with pytest.raises(checkpoint.Stopped):
        Simulation.from_toml(scene).run(out=tmp_path / "run", progress=False, log=lines.append,
                                        stop=request)
    assert not any("model = \"rigid\"" in line for line in lines), lines
    lines.clear()
    Simulation.from_toml(scene).run(progress=False, log=lines.append, until=0.01)
    assert any("model = \"rigid\"" in line for line in lines), lines      # a run that ends is told


def test_a_stop_signal_swallowed_in_a_callback_prints_no_traceback(monkeypatch):
    """Ctrl-C landing in a ctypes callback of numba's compiler printed llvmlite's "Exception
    ignored ... KeyboardInterrupt" traceback: the entry point's handler has recorded it, and the
    run stops on it, so the report is left out; other swallowed errors are still told."""
    from hybrid.app import cli, entry

    class Callback:
        def __init__(self, error):
            self.error = error

        def __del__(self):
            raise self.error

    def command(argv):
        Callback(KeyboardInterrupt()), Callback(entry.Terminated())    # dropped at once
        Callback(ValueError("still told"))
        return 0

    told = []
    monkeypatch.setattr(sys, "unraisablehook", lambda unraisable: told.append(type(unraisable.exc_value)))
    monkeypatch.setattr(cli, "main", command)
    assert entry.main([]) == 0
    assert told == [ValueError]


def test_a_checkpoint_file_has_the_mode_of_the_runs_other_files(stopped_quick):
    """checkpoint.npz was created 0600 (a temporary file's mode) where the run's other files
    follow the umask (0644 with the usual 022): another user allowed to read the outputs could
    not resume from it."""
    out, _ = stopped_quick
    mode = (out / "checkpoint.npz").stat().st_mode & 0o777
    assert mode == (out / "bodies.csv").stat().st_mode & 0o777


def test_a_checkpoint_resumed_from_a_renamed_copy_of_its_scene_is_refused(capsys, tmp_path):
    """The same content under another file name (a scene named after its file) resumed, and
    wrote its frames' index under the new name beside the old one, which listed a third of the
    frames. A copy naming the same scene resumes."""
    scene = tmp_path / "quick.toml"
    scene.write_text(QUICK.replace('name = "quick"\n', ""))
    request = checkpoint.StopRequest()
    request.set()
    with pytest.raises(checkpoint.Stopped):
        Simulation.from_toml(scene).run(out=tmp_path / "run", progress=False, log=lambda m: None,
                                        stop=request)
    copy = tmp_path / "copy.toml"
    copy.write_text(scene.read_text())
    code, err = resume_code(capsys, copy, tmp_path / "run")
    assert code == 2 and "checkpoint of scene 'quick'" in err and "resumed as 'copy'" in err
    assert not (tmp_path / "run" / "copy.pvd").exists()
    assert resume_code(capsys, scene, tmp_path / "run")[0] == 0


def test_a_threading_event_stops_a_run_and_what_is_no_stop_is_refused_before_it(tmp_path):
    """``stop=threading.Event()`` ran one step and failed as "unstable" ('Event' object has no
    attribute 'signal'): an event is a stop request as a StopRequest is; anything else is refused
    before the run writes a thing."""
    import threading
    scene = tmp_path / "quick.toml"
    scene.write_text(QUICK)
    for wrong in (True, "yes", 1):
        with pytest.raises(TypeError, match="stop must be"):
            Simulation.from_toml(scene).run(out=tmp_path / "wrong", progress=False, stop=wrong)
    assert not (tmp_path / "wrong").exists()
    event = threading.Event()
    event.set()
    sim = Simulation.from_toml(scene)
    with pytest.raises(checkpoint.Stopped) as stopped:
        sim.run(out=tmp_path / "run", progress=False, log=lambda m: None, stop=event)
    assert stopped.value.exit_code == 130 and stopped.value.checkpoint.is_file()
    # the same simulation run into its folder again is pointed to resume (it said "give another
    # folder", as for a run that had ended)
    with pytest.raises(ValueError, match="Simulation.resume continues it"):
        sim.run(out=tmp_path / "run", progress=False, log=lambda m: None)
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["status"] == "stopped"
    # no signal was sent: said so ("stopped by SIGINT" read as if one had been)
    assert str(stopped.value).startswith("stopped on request (as by SIGINT) at t = ")


def test_a_run_of_a_scene_changed_in_python_resumes_with_that_scene_only(tmp_path):
    """A run of a scene changed in Python (a ball thrown sideways) and stopped was resumed from
    its file: the run went on with the changed values (kept in the checkpoint) but its summary
    showed the file's, and the scene object itself could not be given (a pathlib TypeError).
    The file alone is refused; the changed scene resumes to the files an unstopped run writes."""
    from dataclasses import replace
    from hybrid.app.scene import load_scene
    scene_file = tmp_path / "quick.toml"
    scene_file.write_text(QUICK)
    base = load_scene(scene_file)
    thrown = replace(base, bodies=(replace(base.bodies[0], velocity=(1.5, 0.0, 0.0)),))
    Simulation(thrown).run(out=tmp_path / "whole", progress=False, log=lambda m: None)
    request = checkpoint.StopRequest()
    request.set()
    with pytest.raises(checkpoint.Stopped):
        Simulation(thrown).run(out=tmp_path / "run", progress=False, log=lambda m: None, stop=request)
    with pytest.raises(checkpoint.CheckpointError, match="values of a scene changed in Python"):
        Simulation.resume(scene_file, tmp_path / "run")
    resumed = Simulation.resume(thrown, tmp_path / "run")
    resumed.run(out=tmp_path / "run", progress=False, log=lambda m: None)
    assert (tmp_path / "run" / "bodies.csv").read_bytes() == (tmp_path / "whole" / "bodies.csv").read_bytes()
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["scene"]["bodies"][0]["velocity"] == [1.5, 0.0, 0.0]
    # the ball flew sideways at 1.5 m/s through the run (in the air all along: no friction)
    assert resumed.body("ball").position[0] == pytest.approx(1.5 * 0.05, rel=1e-9)


def test_a_run_with_set_fields_stops_and_resumes_with_them_to_the_files_of_a_run_never_stopped(
        tmp_path, capsys, monkeypatch):
    """``hybrid run SCENE --set KEY=VALUE`` runs the scene with those fields changed; stopped, it
    prints a resume command with the same --set, which continues it to the files an unstopped run
    writes; resumed without them, the checkpoint is of another scene and is refused."""
    import contextlib
    import shlex
    scene = tmp_path / "quick.toml"
    scene.write_text(QUICK)
    settings = ["--set", "simulation.duration=0.1", "--set", "bodies.ball.velocity=[0.5,0,0]"]
    assert main(["run", str(scene), "--out", str(tmp_path / "whole"), "--quiet", *settings]) == 0
    whole = json.loads((tmp_path / "whole" / "summary.json").read_text())
    assert whole["steps"] == 20 and whole["scene"]["bodies"][0]["velocity"] == [0.5, 0, 0]
    capsys.readouterr()

    @contextlib.contextmanager
    def stopped_at_once(signals=None):
        request = checkpoint.StopRequest()
        request.set()
        yield request
    monkeypatch.setattr(checkpoint, "stop_on_signals", stopped_at_once)
    out = tmp_path / "stopped"
    assert main(["run", str(scene), "--out", str(out), "--quiet", *settings]) == 130
    command = shlex.split(capsys.readouterr().err.strip().splitlines()[-1])
    assert command[:2] == ["hybrid", "run"] and command.count("--set") == 2
    monkeypatch.undo()
    code, err = resume_code(capsys, scene, out)             # the file's scene: another one
    assert code == 2 and "resume with the same --set" in err, err
    assert main(command[1:]) == 0, capsys.readouterr().err
    for name in ("bodies.csv", "quick.pvd"):
        assert (out / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()


@pytest.mark.parametrize("setting, said", [("simulation.duration=0.1,0.2", "run takes one value"),
                                           ("bodies.nope.density=5", "no body 'nope'"),
                                           # (read as "a single table, not an array" of anchors)
                                           ("bodies.ball.anchors.0.velocity=[1,0,0]",
                                            "'ball' has no anchors"),
                                           ("simulation.dt=-1", "field 'dt' must be a number > 0")])
def test_a_bad_set_is_refused_naming_it_and_nothing_is_written(tmp_path, capsys, setting, said):
    scene = tmp_path / "quick.toml"
    scene.write_text(QUICK)
    assert main(["run", str(scene), "--out", str(tmp_path / "run"), "--set", setting]) == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err, err
    assert not (tmp_path / "run").exists()
