"""Frames written by a writer process: the same files as writing them in place on a scene with
rigid and FEM bodies, a writer error raised on the stepping side with the frames before it kept,
an interrupted run keeping its frames, and no child process left once a run has ended."""

import errno
import io
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import meshio
import multiprocessing
import numpy as np
import pytest

from hybrid import Simulation
from hybrid.app import run as run_module, writer_pool
from hybrid.app.output import FramePiece, RunWriter
from hybrid.app.run_files import read_run
from hybrid.app.output_resume import ResumableWriter

SCENE = """
[simulation]
name = "mixed"
duration = 0.06
dt = 0.002
output_fps = 100

[[planes]]
point = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]

[[bodies]]
name = "jelly"
model = "fem"
shape = {{ type = "box", size = [0.2, 0.2, 0.2], resolution = 0.1 }}
young = 1e5
density = 1000.0
position = [0.0, 0.0, 0.1005]
velocity = [0.0, 0.0, -1.0]

[[bodies]]
name = "brick"
model = "rigid"
shape = {{ type = "box", size = [0.1, 0.1, 0.1] }}
position = [0.0, 0.0, {brick_z}]
density = 500.0
"""


@pytest.fixture(autouse=True)
def no_idle_writer():
    """Each test starts without an idle writer process kept from an earlier test's run
    (writer_pool.pool), as a process's first run does."""
    writer_pool.pool.clear()


def scene_file(tmp_path, brick_z=0.3):
    path = tmp_path / "mixed.toml"
    path.write_text(SCENE.format(brick_z=brick_z))
    return path


def run_with(tmp_path, monkeypatch, background, name):
    """Run the scene with the run's writer in the way ``background``; its folder."""
    out = tmp_path / name
    monkeypatch.setattr(run_module, "ResumableWriter",
                        lambda out_dir, scene: ResumableWriter(out_dir, scene, background=background))
    Simulation.from_toml(scene_file(tmp_path)).run(out=out, progress=False, log=lambda m: None,
                                                   checkpoint_every=0)
    return out


def children():
    """Live child processes of this one but the idle writer process kept for the next run
    (writer_pool.pool; multiprocessing's fork server aside)."""
    idle = writer_pool.pool.idle_pid
    return [p for p in multiprocessing.active_children() if p.pid != idle]


@pytest.mark.parametrize("keep_bytes", [16 << 10, 0])
def test_a_run_written_by_the_writer_process_equals_the_run_written_in_place(tmp_path, monkeypatch, keep_bytes):
    """keep_bytes 0: every read-only array (the brick's surface) is sent once and kept."""
    from hybrid.app import frame_input
    monkeypatch.setattr(frame_input, "KEEP_BYTES", keep_bytes)
    inline = run_with(tmp_path, monkeypatch, False, "inline")
    process = run_with(tmp_path, monkeypatch, "process", "process")
    files = sorted(p.relative_to(inline) for p in inline.rglob("*") if p.is_file())
    assert len([f for f in files if f.suffix == ".vtu"]) == 7       # 0.06 s at 100 frames/s, and t = 0
    for name in files:
        if name.name == "summary.json":           # wall times differ; the rest is the same
            continue
        assert (process / name).read_bytes() == (inline / name).read_bytes(), name
    import meshio
    mesh = meshio.read(process / "frames" / "frame_00006.vtu")
    assert {b.type for b in mesh.cells} == {"tetra", "triangle"}
    assert np.concatenate(mesh.cell_data["principal_stress"]).any()      # computed by the writer
    assert not children()


ONE_TET = np.array([[0, 1, 2, 3]])
ONE_TET.flags.writeable = False     # (a model's cells: frames after the first go as their values)


def piece(t, rng):
    points = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]) + [0, 0, t]
    return FramePiece(body_id=1, points=points, cells=[("tetra", ONE_TET)],
                      cell_data={"von_mises": rng.uniform(size=1)},
                      point_data={"velocity": rng.normal(size=(4, 3))})


def rows(t):
    return [(t, "jelly", 0.0, 0.0, t, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, "fem")]


def test_a_writer_process_error_is_raised_on_the_caller_with_the_frames_before_it_kept(tmp_path):
    run_dir = tmp_path / "run"
    rng = np.random.default_rng(2)
    writer = RunWriter(run_dir, "drop", background="process")
    with writer:
        writer.write_frame(0.0, [piece(0.0, rng)], rows(0.0))
        pid = writer.writer_pid
        # a directory where frame 3 goes: the writer process cannot put the file there
        (run_dir / "frames" / "frame_00003.vtu").mkdir()
        with pytest.raises(IsADirectoryError) as raised:
            for k in range(1, 40):
                writer.write_frame(0.01 * k, [piece(0.01 * k, rng)], rows(0.01 * k))
            writer.flush()
        assert f"writer process, pid {pid}" in " ".join(raised.value.__notes__)
        assert "frame_00003" in str(raised.value.__cause__)              # its traceback there
        assert writer.frames_written == 3
        writer.close({"status": "failed"})
    times, paths, summary = read_run(run_dir)
    assert times == [0.0, 0.01, 0.02] and summary == {"status": "failed"}
    assert [p.name for p in paths] == [f"frame_0000{k}.vtu" for k in range(3)]
    lines = (run_dir / "bodies.csv").read_text().splitlines()
    assert [float(line.split(",")[0]) for line in lines[1:]] == times
    assert not list((run_dir / "frames").glob(".*.tmp"))
    assert not children()


class FillingFile(io.FileIO):
    """A file on a disk with ``room`` bytes left: a write past it writes what fits and fails."""
    room = 1500

    def write(self, data):
        left = self.room - self.tell()
        if len(data) > left:
            super().write(bytes(data[:max(left, 0)]))
            raise OSError(errno.ENOSPC, "No space left on device")
        return super().write(data)


def test_a_full_disk_keeps_whole_frames_each_with_its_whole_rows_and_the_index_listing_them(
        tmp_path, monkeypatch):
    """The table's write that fails part way is cut back off, the frame whose rows failed goes
    too, and closing writes nothing more (a writer process printed a traceback closing it)."""
    from hybrid.app import vtu
    def tables_open(path, mode, *args, **kwargs):      # the tables' files fill the disk
        return FillingFile(path, mode[0]) if mode in ("wb", "ab") else open(path, mode, *args, **kwargs)
    monkeypatch.setattr(vtu, "open", tables_open, raising=False)
    rng = np.random.default_rng(5)
    run_dir = tmp_path / "run"
    writer = RunWriter(run_dir, "drop", background="inline")
    with writer:
        with pytest.raises(OSError, match="No space"):
            for k in range(100):
                writer.write_frame(0.01 * k, [piece(0.01 * k, rng)], rows(0.01 * k))
        writer.close({"status": "failed"})
    times, paths, _ = read_run(run_dir)
    text = (run_dir / "bodies.csv").read_text()
    assert text.endswith("\n") and 0 < len(text) <= FillingFile.room
    assert [float(line.split(",")[0]) for line in text.splitlines()[1:]] == times
    assert sorted(p.name for p in (run_dir / "frames").iterdir()) == [p.name for p in paths]
    assert len(times) == len(text.splitlines()) - 1 > 3


def test_bad_input_raises_at_once_and_writes_nothing_of_that_frame(tmp_path):
    rng = np.random.default_rng(4)
    with RunWriter(tmp_path / "run", "drop", background="process") as writer:
        writer.write_frame(0.0, [piece(0.0, rng)], rows(0.0))
        bad = piece(0.1, rng)
        bad.cell_data["von_mises"] = np.zeros(5)
        with pytest.raises(ValueError, match="von_mises"):
            writer.write_frame(0.1, [bad], rows(0.1))
        with pytest.raises(ValueError, match="row has 3 values"):
            writer.write_frame(0.1, [piece(0.1, rng)], [(0.1, "jelly", 1.0)])
        writer.write_frame(0.2, [piece(0.2, rng)], rows(0.2))
        writer.close()
    times, paths, _ = read_run(tmp_path / "run")
    assert times == [0.0, 0.2] and [p.name for p in paths] == ["frame_00000.vtu", "frame_00001.vtu"]


@pytest.mark.parametrize("stop, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_run_stopped_by_ctrl_c_keeps_its_frames_and_leaves_no_process(tmp_path, stop, code):
    """SIGINT to the whole process group, as Ctrl-C sends it (or SIGTERM, as a job scheduler
    may): the writer process ignores it, the run stops after its step, writes its checkpoint and
    closes its writer, which writes every frame handed over (SIGTERM ended the writer process,
    and the run with it as unstable, without a checkpoint)."""
    scene = tmp_path / "long.toml"
    scene.write_text(SCENE.format(brick_z=0.3).replace("duration = 0.06", "duration = 30.0"))
    out = tmp_path / "out"
    env = dict(os.environ, HYBRID_WRITER="process", OPENBLAS_NUM_THREADS="1")
    cli = Path(sys.executable).with_name("hybrid")
    run = subprocess.Popen([str(cli), "run", str(scene), "--out", str(out), "--quiet"], env=env,
                           start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while len(list((out / "frames").glob("frame_*.vtu"))) < 5:
            assert run.poll() is None and time.monotonic() < deadline, run.communicate()
            time.sleep(0.05)
        writers = _descendants(run.pid)         # the fork server and the writer process
        os.killpg(run.pid, stop)
        _, err = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
    assert run.returncode == code, err.decode()
    times, paths, summary = read_run(out)
    assert summary["status"] == "stopped" and len(times) == summary["frames"] >= 5
    assert (out / "checkpoint.npz").is_file()
    assert sorted(p.name for p in (out / "frames").glob("frame_*.vtu")) == [p.name for p in paths]
    assert len((out / "bodies.csv").read_text().splitlines()) == 1 + 2 * len(times)
    assert len(writers) >= 2
    deadline = time.monotonic() + 10
    while [p for p in writers if _alive(p)] and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [p for p in writers if _alive(p)]


def _parents():
    """{pid: parent pid} of the processes there are (from /proc)."""
    out = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                out[int(entry.name)] = int(entry.joinpath("stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                pass
    return out


def _descendants(pid):
    parents, found = _parents(), {pid}
    for _ in range(4):
        found |= {p for p, parent in parents.items() if parent in found}
    return sorted(found - {pid})


def _alive(pid):
    """Whether ``pid`` runs (a zombie waiting to be reaped does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


class FakeForkServer:
    """A stand-in for ``writer_process.fork_server``: ready from its ``after + 1``-th question on."""

    def __init__(self, after):
        self.after, self.calls = after, 0

    def start(self):
        pass

    def ready(self):
        self.calls += 1
        return self.calls > self.after


def write_auto_and_inline(tmp_path, frames, after_frame=lambda writer, k: None):
    """``frames`` frames (and region rows) written the ``auto`` way and in place, into
    ``tmp_path/auto`` and ``tmp_path/False``; ``after_frame(writer, k)`` runs after the auto way's
    frame k. The writer process's pid after each frame, the auto way's then the in-place way's;
    asserts the two ways wrote the same files, byte for byte."""
    pids = []
    for way in ("auto", False):
        rng = np.random.default_rng(9)
        with RunWriter(tmp_path / str(way), "drop", background=way) as writer:
            for k in range(frames):
                writer.write_frame(0.01 * k, [piece(0.01 * k, rng)], rows(0.01 * k))
                writer.write_regions([(0.01 * k, "jelly", "anchor0", 1.0, 2.0, 3.0, 0.0, 0.0, k)])
                if way == "auto":
                    after_frame(writer, k)
                pids.append(writer.writer_pid)
            writer.close({"frames": frames})
    inline = tmp_path / "False"
    files = sorted(p.relative_to(inline) for p in inline.rglob("*") if p.is_file())
    assert len(files) == frames + 4
    for name in files:
        assert (tmp_path / "auto" / name).read_bytes() == (inline / name).read_bytes(), name
    return pids


def test_auto_hands_the_files_over_to_a_process_mid_run_without_a_seam(tmp_path, monkeypatch):
    """``auto`` writes in place, on the stepping thread (no writer thread, which would share the
    interpreter lock), until the fork server is up, then moves the files (open tables, index,
    frame count) to a writer process: the files are those written in place."""
    import threading
    from hybrid.app import writer_process

    def launched(writer, k):
        assert "RunWriter" not in {t.name for t in threading.enumerate()}
        if k == 3:
            writer._launch.join()           # started: the next frame's call hands over

    monkeypatch.setattr(writer_process, "fork_server", FakeForkServer(6))  # up from the fourth frame on (2 asks a frame)
    monkeypatch.setattr(RunWriter, "auto_after", 0.0)
    pids = write_auto_and_inline(tmp_path, 7, launched)
    # the process is launched at the fourth frame and has taken over by the fifth
    assert pids[:3] == [None] * 3 and None not in pids[4:7] and pids[7:] == [None] * 7
    assert not children()


def test_auto_handing_over_at_the_close_keeps_every_frame_in_the_index(tmp_path, monkeypatch):
    """A writer process that takes the files over at the run's close (the fork server up only
    at the last frame) was told the thread's ``.pvd`` listed every frame, which the thread
    rewrites at most every ``index_every`` s: the final index left out frames on disk (seen
    after a resumed ``shatter``). It is told what the index lists and brings it up to date."""
    from hybrid.app import writer_process

    import threading
    release = threading.Event()
    real_start = RunWriter._start_process

    def held_start(writer, wait=False):     # (a loaded machine could start it before the close)
        assert release.wait(10.0)
        real_start(writer, wait)

    def launched(writer, k):
        if k == 4:
            release.set()
            writer._launch.join()           # started: the close's index job hands over

    monkeypatch.setattr(RunWriter, "_start_process", held_start)
    monkeypatch.setattr(writer_process, "fork_server", FakeForkServer(9))  # up at the fifth frame
    monkeypatch.setattr(RunWriter, "auto_after", 0.0)
    pids = write_auto_and_inline(tmp_path, 5, launched)      # (the .pvd byte for byte too)
    assert pids == [None] * 10
    assert not children()


def test_auto_writes_from_the_first_frame_in_a_process_when_the_fork_server_is_up(tmp_path):
    """A later run of a process (the fork server up) writes through a writer process from its
    first frame, nothing on the thread: the files are those written in place."""
    from hybrid.app import writer_process
    writer_process.fork_server.start()
    for _ in range(600):
        if writer_process.fork_server.ready():
            break
        time.sleep(0.01)
    assert writer_process.fork_server.ready()

    def nothing_on_the_thread(writer, k):
        assert writer._writer.pending() == 0 and writer._launch is None

    pids = write_auto_and_inline(tmp_path, 3, nothing_on_the_thread)
    assert None not in pids[:3] and len(set(pids[:3])) == 1 and pids[3:] == [None] * 3
    assert not children()


def test_auto_writes_in_place_in_a_daemonic_process_such_as_a_dask_worker(tmp_path, monkeypatch):
    """A daemonic process (Dask's workers) cannot have children: ``auto`` writes in place, on the
    stepping thread (a writer thread would share the interpreter lock with the stepping)."""
    import threading
    from hybrid.app import writer_process

    class Daemonic:
        daemon = True

    monkeypatch.setattr(writer_process.multiprocessing, "current_process", lambda: Daemonic())
    monkeypatch.setattr(RunWriter, "auto_after", 0.0)
    rng = np.random.default_rng(6)
    with RunWriter(tmp_path / "run", "drop", background="auto") as writer:
        for k in range(3):
            writer.write_frame(0.01 * k, [piece(0.01 * k, rng)], rows(0.01 * k))
            assert writer.writer_pid is None and "RunWriter" not in {t.name for t in threading.enumerate()}
        writer.close()
    assert read_run(tmp_path / "run")[0] == [0.0, 0.01, 0.02]
    with pytest.raises(RuntimeError, match="daemonic"):
        RunWriter(tmp_path / "other", "drop", background="process").write_frame(0.0, [piece(0.0, rng)])


def test_kept_arrays_go_over_once_while_they_stay_the_same_object():
    """A large read-only array is pickled once and then by number while it comes again; a new
    object (or a writable array) is pickled whole; each side forgets what a frame did not use."""
    from hybrid.app.frame_input import KeptArrays
    sender, receiver = KeptArrays(), KeptArrays()
    surface = np.arange(30000.0).reshape(-1, 3).copy()      # owns its data
    surface.flags.writeable = False
    moving = np.ones((10000, 3))

    def frame(*arrays):
        """A frame job whose pieces hold ``arrays``: (payload bytes, the job received)."""
        rows = [(0.1, "box", 1.0)] * 100
        payload = sender.dumps(("frame", 0.1, "frame_00001.vtu", list(arrays), rows))
        job = receiver.loads(payload)
        assert job[:3] == ("frame", 0.1, "frame_00001.vtu") and job[4] == rows
        for sent, got in zip(arrays, job[3]):
            np.testing.assert_array_equal(got, sent)
        return len(payload), job[3]

    first, _ = frame(surface, moving)
    second, job = frame(surface, moving)
    assert first - second > 0.95 * surface.nbytes           # the surface went over once
    assert job[0] is receiver.kept[next(iter(receiver.kept))]
    receiver.loads(sender.dumps(("rows", "bodies.csv", (), [])))
    third, _ = frame(surface, moving)                       # a job without arrays forgets nothing
    assert third == second
    other = surface.copy()
    other.flags.writeable = False
    fourth, _ = frame(other, moving)                        # another object: sent whole
    assert fourth == first
    frame(moving, moving)                                   # not used by a frame: forgotten
    assert not sender.kept and not receiver.kept
    writable = surface.copy()
    assert frame(writable)[0] > surface.nbytes and frame(writable)[0] > surface.nbytes


@pytest.mark.parametrize("stop, code, said", [(signal.SIGINT, 130, "interrupted"),
                                              (signal.SIGTERM, 143, "stopped (SIGTERM)")])
@pytest.mark.parametrize("after", [0.2, 1.5])
def test_a_run_stopped_before_it_steps_ends_with_one_line_and_writes_nothing(tmp_path, stop, code,
                                                                               said, after):
    """SIGINT or SIGTERM while `hybrid run` imports (0.2 s) or builds a large body (1.5 s): before
    the entry point handled them, Ctrl-C printed a KeyboardInterrupt traceback and SIGTERM ended
    the process without a word (exit -15). Now one line, the signal's exit code, no output. (A
    signal is handled between Python calls: one that arrives in a long compiled call, or on a
    loaded machine after the build, lands later; then the run's own stop writes a checkpoint.)"""
    scene = tmp_path / "big.toml"
    scene.write_text("""
[simulation]
duration = 0.01
[[planes]]
[[bodies]]
name = "block"
model = "fem"
shape = { type = "box", size = [1.0, 1.0, 1.0], resolution = 0.05 }
position = [0.0, 0.0, 0.5]
young = 1e6
""")
    out = tmp_path / "out"
    cli = Path(sys.executable).with_name("hybrid")
    run = subprocess.Popen([str(cli), "run", str(scene), "--out", str(out), "--quiet"],
                           env=dict(os.environ, OPENBLAS_NUM_THREADS="1"), start_new_session=True,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        time.sleep(after)
        os.killpg(run.pid, stop)
        _, err = run.communicate(timeout=180)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
    err = err.decode()
    assert run.returncode == code, err
    assert "Traceback" not in err
    if not (out / "checkpoint.npz").exists():
        assert said in err and not out.exists()


def test_the_fork_server_ignores_ctrl_c_while_it_imports(tmp_path):
    """A Ctrl-C to the process group while the writers' fork server imports the project printed
    its KeyboardInterrupt traceback into the run's output (the server ignores SIGINT only once its
    imports are done). It is spawned with SIGINT ignored: read from /proc right after it starts,
    before its imports are done, SIGINT is among its ignored signals."""
    script = tmp_path / "start.py"
    script.write_text(
        "import multiprocessing.forkserver as fs\n"
        "from hybrid.app.writer_process import fork_server\n"
        "if __name__ == '__main__':\n"
        "    fork_server.start()\n"
        "    pid = fs._forkserver._forkserver_pid\n"
        "    ignored = [l for l in open(f'/proc/{pid}/status') if l.startswith('SigIgn')][0]\n"
        "    print(int(ignored.split()[1], 16) >> 1 & 1)\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "1"


def test_writer_processes_do_not_run_the_main_script_again(tmp_path):
    """Each writer process ran the run's main script again on start (Python's fork server drops
    the script's path before 3.13.8): for the ``hybrid`` command, the project imported anew,
    0.3-0.6 s before a run's first frame was written, and a script's top-level code (removing
    its output folder, say) ran in every writer. Here a script counts its imports outside
    ``__main__`` while it starts three writer processes, each answering: none; then a process of
    its own with a function of the script, which imports it there: one."""
    imports = tmp_path / "imports.txt"
    script = tmp_path / "three_writers.py"
    script.write_text(
        "import multiprocessing, time\n"
        "from hybrid.app.writer_process import WriterProcess, fork_server\n"
        "if __name__ != '__main__':\n"
        f"    open({str(imports)!r}, 'a').write(__name__ + '\\n')\n"
        "def mine():\n"
        f"    open({str(tmp_path)!r} + '/mine.txt', 'w').write('ran')\n"
        "if __name__ == '__main__':\n"
        "    fork_server.start()\n"
        "    while not fork_server.ready():\n"
        "        time.sleep(0.01)\n"
        "    for k in range(3):\n"
        f"        writer = WriterProcess({str(tmp_path)!r} + f'/out{{k}}', 'run.pvd')\n"
        "        print(sorted(writer.state()) != [])\n"
        "        writer.stop()\n"
        f"    print(open({str(imports)!r}, 'a').tell())\n"
        "    own = multiprocessing.get_context('forkserver').Process(target=mine)\n"
        "    own.start()\n"
        "    own.join()\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True"] * 3 + ["0"]      # each writer answered; no import yet
    assert imports.read_text().split() == ["__mp_main__"]     # the own process's
    assert (tmp_path / "mine.txt").read_text() == "ran"


def test_a_run_whose_writer_process_is_killed_ends_as_an_output_failure(tmp_path, monkeypatch):
    """A writer process killed from outside ended the run as 'unstable' (exit 3), as if the
    physics had diverged: it is an output failure (status failed, as a full disk)."""
    import hybrid.app.writer_process as wp

    def killed(self, job, always=False):
        if self._process.exitcode is None:
            os.kill(self.pid, signal.SIGKILL)
            self._process.join(5.0)
        original(self, job, always)
        self._read(block=True)

    original = wp.WriterProcess.submit
    out = run_with(tmp_path, monkeypatch, "process", "first")          # a run that writes
    assert read_run(out)[2]["status"] == "ok"
    monkeypatch.setattr(wp.WriterProcess, "submit", killed)
    from hybrid.coupling.stability import OutputFailure
    with pytest.raises(OutputFailure, match="writer process"):
        run_with(tmp_path, monkeypatch, "process", "killed")
    from hybrid.app.run_files import read_summary
    assert read_summary(tmp_path / "killed")["status"] == "failed"


def test_frames_handed_over_while_the_writer_naps_and_after_it_blocks_are_all_written(tmp_path):
    """The writer process naps between jobs that come often and blocks once none has come for a
    while (writer_child.NAPPING): frames handed over at once, and after pauses longer than
    that, all reach the disk in order, and a flush after a pause returns."""
    from hybrid.app import writer_child
    tris = np.array([[0, 1, 2]])
    pauses = [0.0, 0.0, 3 * writer_child.NAPPING, 0.0, 3 * writer_child.NAPPING]
    with RunWriter(tmp_path / "run", "naps", background="process") as writer:
        for k, pause in enumerate(pauses):
            time.sleep(pause)
            writer.write_frame(0.1 * k, [FramePiece(1, np.full((3, 3), float(k)), [("triangle", tris)])])
        time.sleep(3 * writer_child.NAPPING)
        writer.flush()
        assert writer.frames_written == len(pauses)
        writer.close({})
    times, paths, _ = read_run(tmp_path / "run")
    assert times == [0.1 * k for k in range(len(pauses))]
    assert [meshio.read(p).points[0, 0] for p in paths] == [float(k) for k in range(len(pauses))]


def test_small_frames_written_at_once_and_large_ones_by_the_feeder_arrive_in_order(tmp_path):
    """Frames small enough for the pipe are written on the caller's thread, larger ones by the
    feeder thread; a small frame behind a large one still waiting for the feeder must not
    overtake it: every frame is on disk, in order, as it was handed over."""
    rng = np.random.default_rng(2)
    tris = np.array([[0, 1, 2]])
    frames = []
    with RunWriter(tmp_path / "run", "order", background="process") as writer:
        for k in range(12):
            n = 150_000 if k % 4 == 1 else 3                 # 3.6 MB: more than the pipe holds
            points = rng.random((n, 3))
            writer.write_frame(0.01 * k, [FramePiece(1, points, [("triangle", tris)])],
                               [(0.01 * k, 1, *points[0], 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                                 float(n), "rigid")])
            frames.append(points)
        writer.close({})
    times, paths, _ = read_run(tmp_path / "run")
    assert times == [0.01 * k for k in range(12)]
    for points, path in zip(frames, paths):
        np.testing.assert_array_equal(meshio.read(path).points, points)
    rows = (tmp_path / "run" / "bodies.csv").read_text().splitlines()[1:]
    assert [float(r.split(",")[2]) for r in rows] == [p[0, 0] for p in frames]


def test_a_job_written_at_once_never_overtakes_one_waiting_with_the_feeder(tmp_path, monkeypatch):
    """A job goes to the feeder thread when the pipe may not take it at once; a later one that
    would fit must still go after it (here the feeder is held back while both are handed over)."""
    import threading
    from hybrid.app import writer_process
    held, original = threading.Event(), writer_process._feed

    def feed(*args):
        held.wait(10.0)
        original(*args)

    monkeypatch.setattr(writer_process, "_feed", feed)
    writer = writer_process.WriterProcess(str(tmp_path), "order.pvd")
    try:
        writer._pipe_bytes = 0                  # the first job: to the feeder
        writer.submit(("rows", "order.csv", ("k",), [(1,)]))
        writer._pipe_bytes = 1 << 30            # the second would fit in the pipe
        writer.submit(("rows", "order.csv", ("k",), [(2,)]))
        held.set()
        writer.wait()
    finally:
        held.set()
        writer.stop()
    assert (tmp_path / "order.csv").read_text().split() == ["k", "1", "2"]


def test_a_writer_process_that_cannot_start_fails_the_output_and_auto_writes_on_in_place(tmp_path, monkeypatch):
    """The child is started off the caller's thread: a start that fails (no more processes)
    is raised by a later call as an output failure, with nothing written; ``auto``'s launching
    thread waits for the start and, when it fails, the run goes on writing in place."""
    import errno
    from hybrid.app import writer_process

    def refused(process):
        raise OSError(errno.EAGAIN, "Resource temporarily unavailable")

    monkeypatch.setattr(multiprocessing.process.BaseProcess, "start", refused)
    writer = writer_process.WriterProcess(str(tmp_path / "direct"), "x.pvd")
    writer.submit(("rows", "a.csv", ("k",), [(1,)]))
    writer.wait()
    with pytest.raises(writer_process.WriterProcessError, match="could not start: .*temporarily unavailable"):
        writer.raise_error()
    writer.stop()
    assert not (tmp_path / "direct" / "a.csv").exists() and not children()

    def launched(writer, k):
        if k == 0:
            writer._launch.join()           # its start failed: the next call stays in place

    monkeypatch.setattr(writer_process, "fork_server", FakeForkServer(2))  # up from the first frame's region rows
    monkeypatch.setattr(RunWriter, "auto_after", 0.0)
    pids = write_auto_and_inline(tmp_path, 4, launched)     # (byte for byte as in place)
    assert pids == [None] * 8 and not children()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_a_wait_for_a_writer_whose_feeder_thread_died_ends_with_an_error(tmp_path, monkeypatch):
    """A feeder thread that ends before sending its jobs (here it fails at once, so the child
    never starts) leaves the caller no reply to wait for: ``wait`` ends with an output failure
    instead of waiting for ever, and ``stop`` returns."""
    import threading
    from hybrid.app import writer_process

    def broken(*args):
        raise RuntimeError("the feeder broke")

    monkeypatch.setattr(writer_process, "_feed", broken)
    writer = writer_process.WriterProcess(str(tmp_path), "x.pvd")
    writer.submit(("rows", "a.csv", ("k",), [(1,)]))
    waiting = threading.Thread(target=writer.wait, daemon=True)      # (a hang fails, not blocks, the test)
    waiting.start()
    waiting.join(15.0)
    assert not waiting.is_alive()
    with pytest.raises(writer_process.WriterProcessError, match="feeder thread ended"):
        writer.raise_error()
    assert writer.pid is None and "feeder thread ended" in str(writer.start_error())
    writer.stop()
    assert not (tmp_path / "a.csv").exists()


def _wait_ended(pid, seconds=3.0):
    """Wait up to ``seconds`` for process ``pid`` to end (see :func:`_alive`)."""
    for _ in range(int(seconds / 0.01)):
        if not _alive(pid):
            return
        time.sleep(0.01)


def write_frames(run_dir, background, frames=5, seed=4):
    """``frames`` frames and region rows written the ``background`` way; the writer process's id."""
    rng = np.random.default_rng(seed)
    with RunWriter(run_dir, "drop", background=background) as writer:
        for k in range(frames):
            writer.write_frame(0.01 * k, [piece(0.01 * k, rng)], rows(0.01 * k))
            writer.write_regions([(0.01 * k, "jelly", "anchor0", 1.0, 2.0, 3.0, 0.0, 0.0, k)])
        pid = writer.writer_pid
        writer.close({"frames": frames})
    return pid


def same_files(a, b):
    names = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert names == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_a_later_run_takes_the_idle_writer_process_and_writes_its_own_files(tmp_path):
    """A run's writer process is kept, idle, for the process's next run (no start beside the
    stepping): the next run's files, a different folder and frame count, are those written in
    place, and none of the first run's state (frames, kept arrays, index) leaks into them."""
    first = write_frames(tmp_path / "first", "process", frames=5)
    assert writer_pool.pool.idle_pid == first and _alive(first)
    second = write_frames(tmp_path / "second", "process", frames=3, seed=5)
    assert second == first
    write_frames(tmp_path / "first_inline", False, frames=5)
    write_frames(tmp_path / "second_inline", False, frames=3, seed=5)
    same_files(tmp_path / "first", tmp_path / "first_inline")
    same_files(tmp_path / "second", tmp_path / "second_inline")
    assert not children()


def test_a_writer_process_whose_run_failed_or_that_ended_is_not_taken_again(tmp_path):
    rng = np.random.default_rng(2)
    with RunWriter(tmp_path / "failed", "drop", background="process") as writer:
        writer.write_frame(0.0, [piece(0.0, rng)], rows(0.0))
        failed = writer.writer_pid
        (tmp_path / "failed" / "frames" / "frame_00001.vtu").mkdir()     # frame 1 cannot go there
        writer.write_frame(0.01, [piece(0.01, rng)], rows(0.01))
        with pytest.raises(IsADirectoryError):
            writer.close({})
    assert writer_pool.pool.idle_pid is None
    kept = write_frames(tmp_path / "next", "process")
    assert kept != failed and writer_pool.pool.idle_pid == kept
    os.kill(kept, signal.SIGKILL)                       # ended while idle: a new one takes over
    _wait_ended(kept)
    fresh = write_frames(tmp_path / "after", "process")
    assert fresh not in (kept, failed)
    write_frames(tmp_path / "inline", False)
    same_files(tmp_path / "after", tmp_path / "inline")


def test_the_idle_writer_process_ends_with_the_python_process(tmp_path):
    script = tmp_path / "one_run.py"
    script.write_text(
        "import numpy as np\n"
        "from hybrid.app.output import FramePiece, RunWriter\n"
        "if __name__ == '__main__':\n"
        f"    with RunWriter({str(tmp_path / 'run')!r}, 'one', background='process') as writer:\n"
        "        writer.write_frame(0.0, [FramePiece(1, np.eye(3), [('triangle', np.array([[0, 1, 2]]))])])\n"
        "        print(writer.writer_pid)\n"
        "        writer.close({})\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    pid = int(done.stdout.split()[0])
    _wait_ended(pid)
    assert not _alive(pid)
    assert read_run(tmp_path / "run")[0] == [0.0]


def test_the_idle_writer_process_writes_a_relative_folder_where_the_run_is(tmp_path, monkeypatch):
    """A writer process kept from a run in another working directory writes a later run's
    relative folder under the later run's working directory, not its own."""
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        monkeypatch.chdir(tmp_path / name)
        write_frames(Path("out"), "process")
    assert read_run(tmp_path / "b" / "out")[0] == read_run(tmp_path / "a" / "out")[0] == [0.01 * k for k in range(5)]


def test_hybrid_run_writes_every_frame_by_the_writer_process_it_started_while_building(tmp_path, monkeypatch):
    """``hybrid run`` starts the writer process before it builds the scene (idle, touching no
    file); its run then writes every frame there, none in place, and keeps it for a later run.
    (The start is waited for here: a build as short as this one's could end before it.)"""
    from hybrid.app import cli, vtu, writer_pool, writer_process
    in_place, started = [], []
    original = vtu.FrameFiles.run
    monkeypatch.setattr(vtu.FrameFiles, "run", lambda self, job, idle: in_place.append(job[0]) or original(self, job, idle))
    start = writer_pool.start_early

    def start_and_wait():
        start()
        for _ in range(3000):
            if writer_pool.pool.idle_pid is not None and writer_process.fork_server.ready():
                break
            time.sleep(0.01)
        started.append(writer_pool.pool.idle_pid)

    monkeypatch.setattr(writer_pool, "start_early", start_and_wait)
    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    assert cli.main(["run", str(scene_file(tmp_path)), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    assert len(started) == 1 and started[0] is not None
    assert in_place == [] and writer_pool.pool.idle_pid == started[0] and _alive(started[0])
    times = read_run(tmp_path / "out")[0]
    assert len(times) == 7 and times == sorted(times)          # 0.06 s at 100 frames/s
    assert list((tmp_path / "cwd").iterdir()) == []


def test_a_process_that_ends_while_its_writer_process_starts_early_ends_quietly(tmp_path):
    """Ending the process (Ctrl-C during ``hybrid run``'s build) at any moment of the early
    writer's start prints nothing, leaves no file and no process behind."""
    script = tmp_path / "early.py"
    script.write_text(
        "import sys, time\n"
        "from hybrid.app import writer_pool\n"
        "if __name__ == '__main__':\n"
        "    writer_pool.start_early()\n"
        "    time.sleep(float(sys.argv[1]))\n"
        "    print(writer_pool.pool.idle_pid)\n")
    for delay in (0.0, 0.1, 0.15, 0.2, 0.3, 1.0):
        done = subprocess.run([sys.executable, str(script), str(delay)], capture_output=True, text=True,
                              timeout=120, cwd=tmp_path)
        assert done.returncode == 0 and done.stderr == "", (delay, done.stderr)
        idle = done.stdout.split()[0]
        if idle != "None":
            _wait_ended(int(idle))
            assert not _alive(int(idle))
    assert idle != "None"                   # (started within the second)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["early.py"]


class StartCounter(FakeForkServer):
    """A fork server that is never up, counting the starts asked of it."""

    def __init__(self):
        super().__init__(math.inf)
        self.starts = 0

    def start(self):
        self.starts += 1


def test_auto_starts_the_fork_server_once_the_run_expects_to_write_for_auto_ahead_more(tmp_path, monkeypatch):
    """``auto`` starts the fork server at the first frame after the run says it will write for
    ``auto_ahead`` s more (its first frames written in place), not only after writing for
    ``auto_after``; a run that expects less does not start it."""
    from hybrid.app import writer_process
    server = StartCounter()
    monkeypatch.setattr(writer_process, "fork_server", server)
    rng = np.random.default_rng(1)
    with RunWriter(tmp_path / "run", "drop", background="auto") as writer:
        writer.write_frame(0.0, [piece(0.0, rng)], rows(0.0))
        writer.expect(0.5 * RunWriter.auto_ahead)
        writer.write_frame(0.01, [piece(0.01, rng)], rows(0.01))
        assert server.starts == 0
        writer.expect(2.0 * RunWriter.auto_ahead)
        writer.write_frame(0.02, [piece(0.02, rng)], rows(0.02))
        assert server.starts == 1
        writer.close({})
    assert read_run(tmp_path / "run")[0] == [0.0, 0.01, 0.02]


def test_a_run_tells_its_writer_the_wall_time_left_at_its_rate(tmp_path, monkeypatch):
    """``Simulation.run`` tells the writer after each frame how long the rest of the run takes
    at its rate so far: positive while there is simulated time left, 0 at the end."""
    told = []
    monkeypatch.setattr(RunWriter, "expect", lambda writer, seconds: told.append(seconds))
    Simulation.from_toml(scene_file(tmp_path)).run(out=tmp_path / "out", progress=False, log=lambda m: None)
    frames = len(read_run(tmp_path / "out")[0])
    assert len(told) == frames - 1                  # (none at the first frame: no rate yet)
    assert all(s > 0 for s in told[:-1]) and abs(told[-1]) < 1e-9


POOL_WORKER = """
import concurrent.futures, multiprocessing, sys
from hybrid import Simulation

def run(out):
    summary = Simulation.from_toml("default").run(until=0.2, out=out, progress=False, log=lambda m: None)
    return summary["frames"]

if __name__ == "__main__":
    context = multiprocessing.get_context(sys.argv[1])
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=context) as pool:
        print(list(pool.map(run, [sys.argv[2]])), flush=True)
    print("pool shut down", flush=True)
"""


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_a_process_pool_worker_that_wrote_a_run_by_a_writer_process_exits(tmp_path, method):
    """A worker of a process pool ends by multiprocessing's exit function, not atexit: it joined
    the writer process kept idle for its next run (which ignores SIGTERM), which waited for jobs
    for ever, and the pool's shutdown never returned. The worker's exit stops it first."""
    script = tmp_path / "pool.py"
    script.write_text(POOL_WORKER)
    env = dict(os.environ, HYBRID_WRITER="process", OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, str(script), method, str(tmp_path / "out")], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["[7]", "pool shut down"], done.stdout
    assert read_run(tmp_path / "out")[2]["status"] == "ok"
