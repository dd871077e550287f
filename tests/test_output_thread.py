"""Frames written off the stepping thread: the same files as writing them in place, the caller's
arrays free to change at once, and a failing disk surfacing on the caller's thread with the
frames written before it kept."""

import threading

import meshio
import numpy as np
import pytest

from hybrid.app import output
from hybrid.app.output import FramePiece, RunWriter
from hybrid.app.run_files import read_run
from hybrid.app.output_resume import ResumableWriter

TET_POINTS = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
TETS = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])


def piece(t, rng):
    return FramePiece(body_id=2, points=TET_POINTS + rng.normal(0.0, 0.1, TET_POINTS.shape) + [0, 0, t],
                      cells=[("tetra", TETS)],
                      cell_data={"von_mises": rng.uniform(0.0, 1e6, 2)},
                      point_data={"velocity": rng.normal(size=(5, 3))})


def rows(t):
    return [(t, "jelly", 0.1, 0.2, t, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -t, 0.0, 0.0, 0.0, 0.5, "fem")]


def write_run(run_dir, background, frames=6, summary=True):
    rng = np.random.default_rng(7)
    with ResumableWriter(run_dir, "drop", background=background) as writer:
        for k in range(frames):
            t = 0.01 * k
            writer.write_frame(t, [piece(t, rng)], rows(t))
            writer.write_regions([(t, "jelly", "anchor0", 1.0, 2.0, 3.0, 0.0, 0.0, t)])
        if summary:
            writer.close({"frames": frames})


def test_frames_written_by_the_thread_are_byte_identical_to_writing_them_in_place(tmp_path):
    write_run(tmp_path / "thread", background=True)
    write_run(tmp_path / "inline", background=False)
    files = sorted(p.relative_to(tmp_path / "inline") for p in (tmp_path / "inline").rglob("*")
                   if p.is_file())
    assert len(files) == 6 + 4          # six frames, the index, two tables, the summary
    for name in files:
        assert (tmp_path / "thread" / name).read_bytes() == (tmp_path / "inline" / name).read_bytes(), name


def test_the_caller_may_change_its_arrays_as_soon_as_write_frame_returns(tmp_path):
    """The writer thread is held until the caller has overwritten every array it passed: the
    frame on disk still holds the values at the call."""
    release = threading.Event()
    real_write = output.write_vtu

    def held_write(*args, **kwargs):
        assert release.wait(10.0)
        return real_write(*args, **kwargs)

    rng = np.random.default_rng(1)
    p = piece(0.0, rng)
    expected_points, expected_stress = p.points.copy(), p.cell_data["von_mises"].copy()
    writer = RunWriter(tmp_path / "run", "drop")
    try:
        output.write_vtu = held_write
        writer.write_frame(0.0, [p], rows(0.0))
        p.points[:] = -1.0
        p.cell_data["von_mises"][:] = -1.0
        release.set()
        writer.close()
    finally:
        output.write_vtu = real_write
    mesh = meshio.read(tmp_path / "run" / "frames" / "frame_00000.vtu")
    np.testing.assert_array_equal(mesh.points, expected_points)
    np.testing.assert_array_equal(mesh.cell_data["von_mises"][0], expected_stress)


def test_a_writer_error_surfaces_on_the_callers_thread_and_the_frames_before_it_stay(tmp_path, monkeypatch):
    real_write = output.write_vtu

    def full_disk(path, *args, **kwargs):
        if "frame_00003" in str(path):
            raise OSError(28, "No space left on device")
        return real_write(path, *args, **kwargs)

    monkeypatch.setattr(output, "write_vtu", full_disk)
    run_dir = tmp_path / "run"
    rng = np.random.default_rng(3)
    writer = RunWriter(run_dir, "drop")
    with writer:
        with pytest.raises(OSError, match="No space left"):
            for k in range(40):          # the error stops the run within a few frames
                writer.write_frame(0.01 * k, [piece(0.01 * k, rng)], rows(0.01 * k))
        assert writer.frames_written == 3
        times, paths, summary = read_run(run_dir)
        assert times == [0.0, 0.01, 0.02] and summary is None
        assert sorted(p.name for p in (run_dir / "frames").iterdir()) == [p.name for p in paths]
        lines = (run_dir / "bodies.csv").read_text().splitlines()
        assert [float(line.split(",")[0]) for line in lines[1:]] == times
        # raised once, as a synchronous write raises: the run that caught it still ends with
        # its summary (status and error), as hybrid.simulation does
        writer.close({"status": "failed"})
    assert read_run(run_dir)[2] == {"status": "failed"}


def test_an_error_in_the_last_frame_is_raised_by_close_instead_of_a_summary(tmp_path, monkeypatch):
    real_write = output.write_vtu

    def fail_second(path, *args, **kwargs):
        if "frame_00001" in str(path):
            raise OSError(5, "Input/output error")
        return real_write(path, *args, **kwargs)

    monkeypatch.setattr(output, "write_vtu", fail_second)
    rng = np.random.default_rng(5)
    writer = RunWriter(tmp_path / "run", "drop")
    writer.write_frame(0.0, [piece(0.0, rng)], rows(0.0))
    writer.write_frame(0.1, [piece(0.1, rng)], rows(0.1))
    with pytest.raises(OSError, match="Input/output"):
        writer.close({"frames": 2})
    times, _, summary = read_run(tmp_path / "run")
    assert times == [0.0] and summary is None
    assert not list((tmp_path / "run" / "frames").glob(".*.tmp"))


def test_frames_read_back_exactly_when_unchanged_arrays_reuse_the_last_frames_encoding(tmp_path):
    """The .vtu writer compresses an array again only when its bytes changed: every frame still
    reads back (meshio) to exactly the arrays given, changed or not, mixed cell types included."""
    rng = np.random.default_rng(11)
    triangles = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    frames = []
    with RunWriter(tmp_path / "run", "mixed") as writer:
        for k in range(4):
            tets = TETS if k < 2 else TETS[::-1]           # the topology changes at frame 2
            pieces = [FramePiece(0, rng.normal(size=(4, 3)), [("triangle", triangles)]),
                      FramePiece(1, TET_POINTS + k, [("tetra", tets)],
                                 cell_data={"von_mises": np.full(2, 5.0) if k % 2 else rng.normal(size=2)},
                                 point_data={"velocity": np.ones((5, 3))})]
            writer.write_frame(0.1 * k, pieces)
            frames.append(pieces)
        writer.close()
    _, paths, _ = read_run(tmp_path / "run")
    for pieces, path in zip(frames, paths):
        mesh = meshio.read(path)
        np.testing.assert_array_equal(mesh.points, np.vstack([p.points for p in pieces]))
        assert [b.type for b in mesh.cells] == ["triangle", "tetra"]
        np.testing.assert_array_equal(mesh.cells[0].data, triangles)
        np.testing.assert_array_equal(mesh.cells[1].data, pieces[1].cells[0][1] + 4)
        np.testing.assert_array_equal(mesh.cell_data["von_mises"][1], pieces[1].cell_data["von_mises"])
        np.testing.assert_array_equal(mesh.cell_data["von_mises"][0], np.zeros(4))
        np.testing.assert_array_equal(mesh.cell_data["body_id"][1], [1, 1])
        np.testing.assert_array_equal(mesh.point_data["velocity"][4:], np.ones((5, 3)))


def test_one_writer_thread_serves_frames_that_come_close_together_and_ends_at_wait():
    """A new thread for every frame cost its start on the stepping thread each time: jobs
    submitted within the linger reuse one thread, in order, and wait() ends it at once."""
    import time
    from hybrid.app.writer_thread import LINGER, WriterThread
    writer = WriterThread()
    threads, order = set(), []
    for k in range(5):
        writer.submit(lambda k=k: (threads.add(threading.get_ident()), order.append(k)))
        time.sleep(0.2 * LINGER)
    start = time.perf_counter()
    writer.wait()
    assert time.perf_counter() - start < 0.5 * LINGER
    assert order == list(range(5)) and len(threads) == 1
    assert not any(t.name == "writer" for t in threading.enumerate())


def test_the_index_keeps_up_while_frames_keep_coming(tmp_path, monkeypatch):
    """The .pvd was rewritten only when no frame waited, so a run whose frames came faster than
    its writer wrote them listed 219 of 1,763 frames on disk when killed outright. A writer that
    is never idle now rewrites it every BUSY_INDEX times index_every: frames written busy for
    longer than that are listed before the run closes."""
    import time
    from hybrid.app import vtu
    (tmp_path / "frames").mkdir()
    files = vtu.FrameFiles(str(tmp_path), "busy.pvd", index_every=0.01)
    rng = np.random.default_rng(3)
    checked = RunWriter(tmp_path / "check", "c", background=False)._check_pieces([piece(0.0, rng)])
    start = time.monotonic()
    k = 0
    while time.monotonic() - start < 3 * vtu.BUSY_INDEX * 0.01:
        files.run(("frame", 0.01 * k, f"frame_{k:05d}.vtu", checked, {"von_mises": ()},
                   {"velocity": (3,)}, output.BODIES_CSV, output.BODY_COLUMNS, []), idle=False)
        k += 1
    listed = (tmp_path / "busy.pvd").read_text().count("<DataSet ")
    assert k > 3 and listed > 0               # never idle: before, no .pvd until the run closed
