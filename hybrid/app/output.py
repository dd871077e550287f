"""Run output: the one place that writes simulation results to disk.

A run directory looks like this::

    DIR/
      frames/frame_00000.vtu ...   one unstructured grid per written frame (all bodies merged)
      <scene>.pvd                  ParaView collection: frame files with their times
      bodies.csv                   one row per body per frame (pose, velocity, kinetic energy)
      regions.csv                  per-region reaction forces and mean displacements (if any)
      summary.json                 parameters, timings, conserved quantities (written by close)

Every file is written so that an interrupted run leaves readable files behind: frames, the pvd
index and the summary are written to a temporary file in the same folder and moved into place
with ``os.replace``; CSV rows of one frame go out in one ``write`` followed by ``flush``, so only
whole lines reach the disk.

Frames are written off the stepping thread: ``RunWriter.write_frame`` checks its input and hands
the pieces' arrays and the rows over, as plain data, to a writer process (or thread) that merges
them, writes the ``.vtu``, rewrites the ``.pvd`` and appends the rows, in order, while the stepping
goes on (:mod:`hybrid.app.writer_process`; docs/output.md, "Writing off the stepping thread").
``read_run`` is the matching reader used by rendering and tests.
"""

from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from . import run_lock, writer_pool, writer_process
from .text_files import atomic_write_text as _atomic_write_text, check_rows, plain as _plain
from .vtu import FRAMES_DIR, FrameFiles, merge_pieces, write_vtu
from .frame_input import check_pieces, owned
from .frame_layout import LastFrame
from .writer_process import WriterProcess
from .writer_thread import WriterThread
from .run_files import BODIES_CSV, BODY_COLUMNS, FRAME_PATTERN, REGION_COLUMNS, REGIONS_CSV, SUMMARY_JSON



@dataclass
class FramePiece:
    """One body's contribution to a frame, or several bodies' at once.

    body_id: integer id written as cell data ``body_id`` on every cell of the piece, or a
        ``(cell_count,)`` integer array of each cell's id (many rigid bodies in one piece: one
        check and one hand-over for all of them).
    points: (n, 3) world coordinates in m, or a :class:`hybrid.app.vtu.Deferred` of n rows the
        writer computes (rigid surfaces posed by the writer).
    cells: list of (meshio cell type, (m, k) int array of indices into ``points``), e.g.
        ``[("triangle", faces)]`` for a rigid body, ``[("tetra", tets)]`` for an FEM body.
    cell_data: name -> (cell_count,) or (cell_count, k) array, one value or row per cell over
        all of the piece's blocks in order; a 0-d value is broadcast to every cell.
    point_data: name -> (n,) or (n, k) array, one value or row per point.
    """

    body_id: int | np.ndarray
    points: np.ndarray
    cells: list[tuple[str, np.ndarray]]
    cell_data: dict[str, np.ndarray] = field(default_factory=dict)
    point_data: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def point_count(self) -> int:
        """Number of points of the piece."""
        return len(self.points)

    @property
    def cell_count(self) -> int:
        """Number of cells of the piece over all its blocks."""
        return sum(len(c) for _, c in self.cells)


class RunWriter:
    """Write the frames, body and region tables and the summary of one run.

    ``RunWriter(out_dir, scene_name)`` creates nothing until the first frame, region rows or
    summary is written, so a run that fails validation leaves no directory behind. When it does
    create the run, stale outputs of an earlier run in the same directory (frame files, CSV
    tables, summary) are removed first. Use it as a context manager so the CSV files are closed
    (and the frames handed over written) on error::

        with RunWriter(out_dir, "drop") as writer:
            writer.write_frame(t, pieces, body_rows)
            writer.close(summary)

    Cell and point field names are discovered from the pieces: once a field has been seen, every
    later frame carries it, with 0 for bodies that do not supply it.

    ``background`` says where the files are written (:mod:`hybrid.app.writer_process`):

    - ``"process"``: by a writer process, a child of this one (kept idle for its next run once the
      files are closed: ``writer_pool.pool``);
    - ``True`` or ``"thread"``: by a writer thread (started when there is work, ended when there
      is none, so it never keeps the interpreter alive);
    - ``"auto"``: on the caller's thread until multiprocessing's fork server is up, then by a
      writer process; the server is started once per process, by the first run that has written
      for a second or expects to write for 0.3 s more (:meth:`expect`; the server takes 0.15 s
      or so, a shorter run would be over first), or with a writer process by
      :func:`hybrid.app.writer_pool.start_early` (``hybrid run``, as it starts building the scene). On the caller's thread
      throughout in a daemonic process (a Dask worker, which cannot have children) and under a main
      script without an ``if __name__ == "__main__":`` guard (multiprocessing would run it again);
    - ``False`` or ``"inline"``: on the caller's thread.

    ``write_frame`` and ``write_regions`` check and copy their input on the caller's thread, raise
    ValueError for bad input at once (nothing of that call is written), and queue the files' work
    (beyond ``queue_frames`` frames waiting, for a process 64 MB and 8 frames, the caller waits).
    The files are written in the order of the calls, byte for byte as in place. A writer error (a full
    disk) stops the writing, keeping the frames before it and a ``.pvd`` listing them, and is
    raised on the caller's thread by the next call. ``flush()`` waits until every queued frame is
    on disk, and so does reading ``frames_written``. ``close()`` gives the writer process back."""

    queue_frames = 8
    index_every = 0.2       # s of wall time, at least, between rewrites of the .pvd during a run
    auto_after = 1.0        # s of wall time after its first output before "auto" starts the fork server
    auto_ahead = 0.3        # or s of wall time the run expects to write still (expect): the server is up in 0.15 s
    _MODES = {False: "inline", True: "thread", **{way: way for way in ("inline", "thread", "process", "auto")}}

    def __init__(self, out_dir: Path | str, scene_name: str, background: bool | str = True):
        if background not in self._MODES:
            raise ValueError(f"background must be one of False, True, 'inline', 'thread', 'process', "
                             f"'auto', not {background!r}")
        self.out_dir = Path(out_dir)
        self.scene_name = str(scene_name)
        self.mode = self._MODES[background]
        self._frames_dir = self.out_dir / FRAMES_DIR
        self._cell_fields: dict[str, tuple[int, ...]] = {}
        self._point_fields: dict[str, tuple[int, ...]] = {}
        self._started = self._closed = self._locked = False
        self._queued = 0                      # frames handed over (written or waiting)
        self._last_frame = LastFrame()        # a frame of its layout goes as its values
        # the files as written on this process (inline, thread, and "auto" until a process takes over)
        self._frame_files = FrameFiles(self.out_dir, self.pvd_path.name, self.index_every,
                                       write_vtu=lambda *args: write_vtu(*args))
        self._process: WriterProcess | None = None
        self._ended_seconds = 0.0           # writing time of the ended writer process (s)
        # "auto": when the fork server is to be started (never: None), the thread starting a writer process
        self._auto_from = math.inf if self.mode == "auto" and writer_process.unavailable() is None else None
        self._expected_end = -math.inf      # time.monotonic() the run expects to write until (expect)
        self._launch: threading.Thread | None = None
        self._launched: WriterProcess | BaseException | None = None
        # "auto" writes in place until (or unless) a writer process is up: a thread shares the interpreter
        # lock, and with it the writer's Python work costs the stepping more than that work (docs/output.md)
        self._writer = WriterThread(self.mode == "thread", self.queue_frames, "RunWriter")

    @property
    def writer_seconds(self) -> float:
        """Wall time (s) spent writing files so far, on whichever thread or process wrote them."""
        return self._writer.seconds + self._ended_seconds + (self._process.seconds if self._process else 0.0)

    @property
    def writer_pid(self) -> int | None:
        """The id of the writer process while one writes this run's files, else None."""
        return self._process.pid if self._process else None

    # -- file state, as on disk once the queued work is done -----------------------------
    def _file_state(self) -> dict:
        """:meth:`hybrid.app.vtu.FrameFiles.state` once the queued work is done."""
        if self._process is not None:
            return self._process.state()
        self._writer.wait()
        return self._frame_files.state()

    @property
    def frames_written(self) -> int:
        """Frames written so far (waits for the frames handed over to reach the disk)."""
        return self._file_state()["count"]

    # -- paths ---------------------------------------------------------------------------
    @property
    def pvd_path(self) -> Path:
        """The run's ParaView index, ``<out_dir>/<scene_name>.pvd``."""
        return self.out_dir / f"{self.scene_name}.pvd"

    @property
    def frames_dir(self) -> Path:
        """The folder of the frame files, ``<out_dir>/frames``."""
        return self._frames_dir

    def frame_path(self, index: int) -> Path:
        """Path of frame number ``index`` (0-based): ``frames/frame_00000.vtu`` and on."""
        return self._frames_dir / f"frame_{index:05d}.vtu"

    # -- lifecycle -----------------------------------------------------------------------
    def _start(self) -> None:
        """Create the run directory on first output and clear an earlier run's files."""
        if self._closed:
            raise RuntimeError("RunWriter is closed")
        if self._started:
            return
        self._take_lock()
        self.frames_dir.mkdir(parents=True, exist_ok=True)
        for stale in self.frames_dir.iterdir():
            if FRAME_PATTERN.match(stale.name):
                stale.unlink()
        for name in (BODIES_CSV, REGIONS_CSV, SUMMARY_JSON, self.pvd_path.name):
            (self.out_dir / name).unlink(missing_ok=True)
        # an earlier run's render (hybrid render) shows frames no longer there
        render = self.out_dir / "render"
        for stale in (*render.glob("frame_*.png"), *render.glob("*.mp4"), *render.glob("*.gif")):
            stale.unlink()
        # another scene's index in the same directory named the frames just removed
        for index in self.out_dir.glob("*.pvd"):
            if f'file="{FRAMES_DIR}/' in index.read_text(errors="replace"):
                index.unlink()
        self._started = True

    def _take_lock(self) -> None:
        """Take the run folder's lock (:mod:`hybrid.app.run_lock`), creating the folder; another run
        writing there: RunFolderBusy, this writer closed, nothing in the folder touched."""
        if self._locked:
            return
        self.out_dir.mkdir(parents=True, exist_ok=True)
        try:
            run_lock.acquire(self.out_dir)
        except run_lock.RunFolderBusy:
            self._closed = True
            raise
        self._locked = True

    def __enter__(self) -> "RunWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._closed:
            return
        try:
            self._wait()
            self._submit(("index",))            # every frame on disk listed, also on an error
            self._wait()
        finally:
            self._end()
        if exc_type is None:
            self._raise_error()                 # a writer error nobody has seen yet

    def _end(self) -> None:
        """Close the tables and give the writer process back (its files closed)."""
        self._frame_files.close()
        if self._launch is not None and self._process is None:      # started, not taken over
            self._launch.join()
            if isinstance(self._launched, WriterProcess):
                writer_pool.pool.give(self._launched)
        if self._process is not None:
            self._give_back()
        if self._locked:
            run_lock.release(self.out_dir)
            self._locked = False
        self._closed = True

    def _give_back(self) -> WriterProcess:
        """Give the writer process back, every job done and its files closed (kept for this
        process's next run, writer_pool.pool); it, for its error."""
        process, self._process = self._process, None
        writer_pool.pool.give(process)
        self._ended_seconds += process.seconds
        return process

    def flush(self) -> None:
        """Wait until everything handed over is on disk; raise the writer's error if it has not
        been raised yet."""
        self._submit(("index",))            # (dropped after a failure, as every later job)
        self._wait()
        self._raise_error()

    def close(self, summary: Mapping[str, Any] | None = None) -> None:
        """Wait for the frames handed over, write ``summary.json`` (if a summary is given), close
        the CSV files and give the writer process back. Raises the writer's error (if not raised
        yet) instead of writing the summary."""
        try:
            if self._process is not None:
                self._give_back().raise_error()     # (one wait: the frames, the index, the files closed)
            else:
                self.flush()
            if summary is not None:
                self.write_summary(summary)
        finally:
            self._end()

    def write_summary(self, summary: Mapping[str, Any]) -> None:
        """Write ``summary.json`` (atomically), also once closed by a failed write (the run's
        folder then holds the frames written before it)."""
        if not (self._closed and self._started):
            self._start()
        text = json.dumps(_plain(summary), indent=2, allow_nan=False) + "\n"
        _atomic_write_text(self.out_dir / SUMMARY_JSON, text)

    # -- the writer: here, on a thread, or in a process ----------------------------------
    def _submit(self, job: tuple) -> None:
        """Hand ``job`` (a :class:`hybrid.app.vtu.FrameFiles` job) to the writer."""
        if self._process is None and self._auto_from is not None:
            self._auto(time.monotonic())
        if self._process is None and self.mode == "process":
            self._process = self._new_process()
        job = self._last_frame.handed(job, self._process or self._writer)
        if self._process is not None:
            self._process.submit(job)
            return
        if self._writer.background:
            job = owned(job)            # the caller may change its arrays once this returns
        files, writer = self._frame_files, self._writer
        writer.submit(lambda: files.run(job, idle=not writer.pending()))

    def _auto(self, now: float) -> None:
        """``auto``: with the fork server up at the first job (a later run of this process), a writer process
        from that job on; otherwise start the server once this run has written for ``auto_after`` s or expects
        to write ``auto_ahead`` s more (a shorter run would end first), then a writer process on a thread,
        which takes the files over once started."""
        if self._auto_from == math.inf:
            self._auto_from = now + self.auto_after
            if writer_process.fork_server.ready():
                # the server is up (a later run of this process): the writer process from the first job
                self._auto_from = None
                self._start_process()
                self._take_over()
                return
        if now >= self._auto_from or self._expected_end - now >= self.auto_ahead:
            writer_process.fork_server.start()
        if self._launch is None and writer_process.fork_server.ready():
            self._launch = threading.Thread(target=self._start_process, args=(True,), name="RunWriter launch",
                                            daemon=True)
            self._launch.start()
            return      # taken over at a later job: when, not how fast the launch thread ran
        if self._launch is not None and not self._launch.is_alive():
            self._auto_from = None
            self._take_over()

    def expect(self, seconds: float) -> None:
        """The run expects to write for about ``seconds`` (wall) more: ``auto`` starts the fork server as
        soon as that is ``auto_ahead`` or more, rather than once it has written for ``auto_after``."""
        self._expected_end = time.monotonic() + seconds

    def _start_process(self, wait: bool = False) -> None:
        """A new writer process in ``_launched``, or why it could not start (the run goes on writing in
        place; without ``wait``, for the launching thread, a failed start is raised by a later call)."""
        try:
            process = self._new_process()
        except (OSError, RuntimeError) as error:
            self._launched = error
            return
        error = process.start_error() if wait else None
        if error is not None:
            process.stop()
        self._launched = error or process

    def _new_process(self) -> WriterProcess:
        """This process's idle writer process (writer_pool.pool), else a new one."""
        args = (self.out_dir, self.pvd_path.name, self.index_every)
        return writer_pool.pool.take(*args) or WriterProcess(*args)

    def _take_over(self) -> None:
        """Hand the files over to the launched writer process (``auto``; then only that is waited for);
        stay in place if it could not start."""
        process = self._launched
        if not isinstance(process, WriterProcess):
            self.mode = "inline"
            return
        self._writer.wait()
        if self._writer.failed():
            process.stop()
            return                       # its error is raised as it is
        state = self._frame_files.state()
        self._frame_files.close()
        process.submit(("restore", state))
        self._process, self._launched = process, None

    def _wait(self) -> None:
        (self._process or self._writer).wait()

    def _raise_error(self) -> None:
        (self._process or self._writer).raise_error()

    # -- frames --------------------------------------------------------------------------
    def _check_pieces(self, pieces: Sequence[FramePiece]) -> list[tuple]:
        """The pieces as :func:`hybrid.app.vtu.merge_pieces` takes them, checked (ValueError);
        registers their fields once all are good."""
        checked, self._cell_fields, self._point_fields = check_pieces(pieces, self._cell_fields,
                                                                      self._point_fields)
        return checked

    def build_mesh(self, pieces: Sequence[FramePiece]):
        """Merge pieces into one ``meshio.Mesh`` (cell data ``body_id`` plus every known field),
        as the frame files hold them. Every array of the mesh is a new one."""
        checked = self._check_pieces(pieces)
        return merge_pieces(checked, self._cell_fields, self._point_fields).to_meshio()

    def write_frame(self, time: float, pieces: Sequence[FramePiece], body_rows: Iterable[Any] = ()) -> Path:
        """Write one frame: the merged ``.vtu``, the updated ``.pvd`` and the frame's body rows.

        ``body_rows`` are tuples in the order of ``BODY_COLUMNS`` or dicts with exactly those keys.
        The input is checked (ValueError) and copied here; the files are written by the writer.
        Returns the path the frame file gets."""
        self._raise_error()
        repeat = self._last_frame.repeat(pieces)      # (the last frame's layout: checked then)
        body = repeat or (self._check_pieces(pieces), dict(self._cell_fields), dict(self._point_fields))
        rows = check_rows(body_rows, BODY_COLUMNS)
        self._start()
        path = self.frame_path(self._queued)
        self._submit(("values" if repeat else "frame", float(time), path.name, *body, BODIES_CSV, BODY_COLUMNS, rows))
        self._queued += 1
        return path

    def write_regions(self, rows: Iterable[Any]) -> None:
        """Append region rows (``REGION_COLUMNS`` order, or dicts); creates regions.csv on first rows."""
        self._raise_error()
        rows = check_rows(rows, REGION_COLUMNS)
        if not rows:
            return
        self._start()
        self._submit(("rows", REGIONS_CSV, REGION_COLUMNS, rows))
