"""One run at a time in a run folder (hybrid.app.run_lock): a second run into a folder another
live run writes in is refused before it touches anything there (the writer, the Python API and
the command line), a lock left by a process that has ended is taken over, and the lock is gone
once a run's files are closed."""
import os
import socket
import subprocess
import sys

import numpy as np
import pytest

from hybrid import Simulation
from hybrid.app import run_lock
from hybrid.app.output import FramePiece, RunWriter

TETS = np.array([[0, 1, 2, 3]])
POINTS = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
ROW = (0.0, 7, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, "fem")
SCENE = """\
[simulation]
name = "locked"
duration = 0.05
dt = 0.01
output_fps = 100
[[planes]]
[[bodies]]
name = "box"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
position = [0.0, 0.0, 0.2]
"""


def piece():
    return FramePiece(body_id=7, points=POINTS, cells=[("tetra", TETS)])


def folder_contents(folder):
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def live_process():
    """A live process of this host that is not this one (its id)."""
    process = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    yield process.pid
    process.kill()
    process.wait()


def ended_pid():
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def test_a_second_writer_in_the_same_process_is_refused_and_touches_nothing(tmp_path):
    with RunWriter(tmp_path, "first", background=False) as first:
        first.write_frame(0.0, [piece()], [ROW])
        first.flush()
        before = folder_contents(tmp_path)
        second = RunWriter(tmp_path, "second", background=False)
        with pytest.raises(run_lock.RunFolderBusy, match="another run of this process"):
            with second:
                second.write_frame(0.0, [piece()], [ROW])
        assert folder_contents(tmp_path) == before      # the first run's frame and index kept
        first.write_frame(0.1, [piece()], [ROW])
        first.close({"status": "ok"})
    assert not (tmp_path / run_lock.LOCK_FILE).exists()
    assert (tmp_path / "frames" / "frame_00001.vtu").is_file()
    with RunWriter(tmp_path, "third", background=False) as third:     # free again once closed
        third.write_frame(0.0, [piece()], [ROW])
        third.close({"status": "ok"})


def test_a_lock_whose_process_ended_is_taken_over(tmp_path):
    (tmp_path / run_lock.LOCK_FILE).write_text(f"{ended_pid()} {socket.gethostname()}\n")
    assert run_lock.holder(tmp_path) is None
    scene = tmp_path.parent / "locked.toml"
    scene.write_text(SCENE)
    summary = Simulation.from_toml(scene).run(out=tmp_path, progress=False, log=lambda m: None)
    assert summary["status"] == "ok" and summary["frames"] == 6
    assert not (tmp_path / run_lock.LOCK_FILE).exists()


def test_the_api_refuses_a_folder_a_live_process_writes_in(tmp_path, live_process):
    (tmp_path / run_lock.LOCK_FILE).write_text(f"{live_process} {socket.gethostname()}\n")
    (tmp_path / "checkpoint.npz").write_bytes(b"another run's")
    before = folder_contents(tmp_path)
    scene = tmp_path.parent / "locked.toml"
    scene.write_text(SCENE)
    sim = Simulation.from_toml(scene)
    with pytest.raises(run_lock.RunFolderBusy, match=f"process {live_process}"):
        sim.run(out=tmp_path, progress=False, log=lambda m: None)
    assert folder_contents(tmp_path) == before
    # the lock taken between the check and the first frame: the writer refuses as well
    writer = RunWriter(tmp_path / "inner", "x", background=False)
    (tmp_path / "inner").mkdir()
    (tmp_path / "inner" / run_lock.LOCK_FILE).write_text(f"{live_process} {socket.gethostname()}\n")
    with pytest.raises(run_lock.RunFolderBusy):
        writer.write_frame(0.0, [piece()], [ROW])
    assert sorted(p.name for p in (tmp_path / "inner").iterdir()) == [run_lock.LOCK_FILE]


def test_a_lock_of_another_host_is_refused_with_what_to_do(tmp_path):
    (tmp_path / run_lock.LOCK_FILE).write_text(f"{os.getpid()} some-other-host\n")
    why = run_lock.holder(tmp_path)
    assert "some-other-host" in why and "delete that file" in why


def test_the_command_line_refuses_before_building_with_exit_2(tmp_path, live_process):
    (tmp_path / "scene.toml").write_text(SCENE)
    out = tmp_path / "out"
    out.mkdir()
    (out / run_lock.LOCK_FILE).write_text(f"{live_process} {socket.gethostname()}\n")
    (out / "bodies.csv").write_text("another run's rows\n")
    (out / "checkpoint.npz").write_bytes(b"the live run's periodic checkpoint")
    before = folder_contents(out)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-m", "hybrid", "run", "scene.toml", "--out", "out", "--quiet"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    assert f"another run (process {live_process}) writes there" in done.stderr
    assert "Traceback" not in done.stderr and "building" not in done.stdout
    assert folder_contents(out) == before


def test_a_lock_older_than_the_live_process_its_id_names_is_stale(tmp_path, live_process):
    """A lock naming a process id that a later process has taken (the run killed long ago) was
    refused for ever: the process started after the lock was written, so it is not its run."""
    lock = tmp_path / run_lock.LOCK_FILE
    lock.write_text(f"{live_process} {socket.gethostname()}\n")
    assert "delete" in run_lock.holder(tmp_path)        # (the way out is said in any case)
    hour_ago = lock.stat().st_mtime - 3600.0
    os.utime(lock, (hour_ago, hour_ago))
    if os.path.exists(f"/proc/{live_process}/stat"):
        assert run_lock.holder(tmp_path) is None


def test_a_run_refused_by_the_lock_leaves_the_folder_free_for_a_later_run(tmp_path, live_process):
    """A run refused by the lock (taken between run's check and its first frame) marked the folder
    as its own last run's, so a later run there was refused as replacing its frames."""
    scene = tmp_path.parent / "locked.toml"
    scene.write_text(SCENE)
    sim = Simulation.from_toml(scene)
    out = tmp_path / "out"
    real_holder = run_lock.holder
    run_lock_holder_calls = []

    def holder_free_at_first(folder):       # the check passes, the writer's lock is refused
        run_lock_holder_calls.append(folder)
        return None if len(run_lock_holder_calls) == 1 else real_holder(folder)
    out.mkdir()
    (out / run_lock.LOCK_FILE).write_text(f"{live_process} {socket.gethostname()}\n")
    try:
        run_lock.holder = holder_free_at_first
        with pytest.raises(run_lock.RunFolderBusy):
            sim.run(until=0.01, out=out, progress=False, log=lambda m: None)
    finally:
        run_lock.holder = real_holder
    (out / run_lock.LOCK_FILE).unlink()
    summary = sim.run(until=0.01, out=out, progress=False, log=lambda m: None)
    assert summary["status"] == "ok"


def test_a_folder_that_takes_no_lock_is_an_exit_2_error_with_nothing_left(tmp_path, monkeypatch, capsys):
    """A full disk as the lock is written printed a traceback (exit 1) and left the lock's
    temporary file behind: one line and exit 2, the folder as it was."""
    import errno
    from pathlib import Path
    from hybrid.app.cli import main
    (tmp_path / "scene.toml").write_text(SCENE)
    out = tmp_path / "out"
    out.mkdir()

    def full(self, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(Path, "write_text", full)
    assert main(["run", str(tmp_path / "scene.toml"), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"--out {out}: cannot write there: No space left on device" in err and "Traceback" not in err
    assert list(out.iterdir()) == []
