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

Frames are written off the stepping thread: ``RunWriter.write_frame`` checks its input, merges the
pieces into one mesh of copied arrays and formats the CSV rows, then hands them to a writer thread
that writes the ``.vtu``, rewrites the ``.pvd`` and appends the rows, in order, while the stepping
goes on (docs/output.md, "Writing off the stepping thread").

``read_run`` is the matching reader used by rendering and tests.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import meshio
import numpy as np

from .text_files import (atomic_write_text as _atomic_write_text, csv_rows as _csv_rows, plain as _plain,
                         temporary_path)
from .vtu import (VtuEncoder, field_array as _field_array, merge_blocks as _merge_blocks, pvd_document,
                  pvd_line, pvd_text as _pvd_text, write_vtu)
from .writer_thread import WriterThread

BODY_COLUMNS = (
    "time", "body", "x", "y", "z", "qw", "qx", "qy", "qz",
    "vx", "vy", "vz", "wx", "wy", "wz", "kinetic_energy", "model",
)
REGION_COLUMNS = ("time", "body", "region", "fx", "fy", "fz", "ux", "uy", "uz")

FRAMES_DIR = "frames"
FRAME_PATTERN = re.compile(r"^frame_\d{5,}\.vtu$")
BODIES_CSV = "bodies.csv"
REGIONS_CSV = "regions.csv"
SUMMARY_JSON = "summary.json"


@dataclass
class FramePiece:
    """One body's contribution to a frame.

    body_id: integer id written as cell data ``body_id`` on every cell of the piece.
    points: (n, 3) world coordinates in m.
    cells: list of (meshio cell type, (m, k) int array of indices into ``points``), e.g.
        ``[("triangle", faces)]`` for a rigid body, ``[("tetra", tets)]`` for an FEM body.
    cell_data: name -> (cell_count,) or (cell_count, k) array, one value or row per cell over
        all of the piece's blocks in order; a 0-d value is broadcast to every cell.
    point_data: name -> (n,) or (n, k) array, one value or row per point.
    """

    body_id: int
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

    Writing happens on a writer thread (started when there is work, ended when there is none, so
    it never keeps the interpreter alive): ``write_frame`` and ``write_regions`` check and copy
    their input on the caller's thread, raise ValueError for bad input at once, and queue the
    files' work; at most ``queue_frames`` frames wait, beyond that the caller waits for the disk.
    The files are written in the order of the calls, exactly as a synchronous writer writes them.
    An error in the writer thread (a full disk) stops the writing, keeping the frames written
    before it and the ``.pvd`` that lists them, and is raised on the caller's thread by the next
    ``write_frame``, ``write_regions``, ``flush`` or ``close``. ``flush()`` waits until every
    queued frame is on disk; reading ``frames_written`` (or the other file state a subclass
    reads) does so too, so what is read matches the files. ``background=False`` writes on the
    caller's thread instead (the same files, byte for byte).
    """

    queue_frames = 8
    index_every = 0.2       # s of wall time, at least, between rewrites of the .pvd during a run

    def __init__(self, out_dir: Path | str, scene_name: str, background: bool = True):
        self.out_dir = Path(out_dir)
        self.scene_name = str(scene_name)
        self._cell_fields: dict[str, tuple[int, ...]] = {}
        self._point_fields: dict[str, tuple[int, ...]] = {}
        self._started = False
        self._closed = False
        # the writer thread's side: files as written so far (read through the properties below)
        self._count = 0                       # frames on disk
        self._frame_times: list[float] = []
        self._frame_files: list[str] = []
        self._bodies: io.TextIOWrapper | None = None
        self._regions: io.TextIOWrapper | None = None
        self._encoder = VtuEncoder()
        self._pvd_lines: list[str] = []       # the .pvd's lines of the frames written
        self._pvd_listed = 0                  # frames the .pvd on disk lists
        self._index_time = -math.inf          # time.monotonic() of its last rewrite
        self._queued = 0                      # frames handed over (written or waiting)
        self._writer = WriterThread(background, self.queue_frames, "RunWriter")

    @property
    def writer_seconds(self) -> float:
        """Wall time (s) spent writing files so far, on whichever thread wrote them."""
        return self._writer.seconds

    # -- file state, as on disk once the queued work is done -----------------------------
    @property
    def frames_written(self) -> int:
        """Frames written so far (waits for the frames handed over to reach the disk)."""
        self._writer.wait()
        return self._count

    @frames_written.setter
    def frames_written(self, value: int) -> None:
        self._writer.wait()
        self._count = self._queued = int(value)

    def _state_property(name: str, doc: str):          # noqa: N805 (a property factory)
        def get(self):
            self._writer.wait()
            return getattr(self, name)

        def put(self, value):
            self._writer.wait()
            setattr(self, name, value)
        return property(get, put, doc=doc)

    _times = _state_property("_frame_times", "Times (s) of the frames written.")
    _files = _state_property("_frame_files", "The .pvd's file entries of the frames written.")
    _bodies_file = _state_property("_bodies", "bodies.csv, open once its first row is written.")
    _regions_file = _state_property("_regions", "regions.csv, open once its first row is written.")
    del _state_property

    # -- paths ---------------------------------------------------------------------------
    @property
    def pvd_path(self) -> Path:
        """The run's ParaView index, ``<out_dir>/<scene_name>.pvd``."""
        return self.out_dir / f"{self.scene_name}.pvd"

    @property
    def frames_dir(self) -> Path:
        """The folder of the frame files, ``<out_dir>/frames``."""
        return self.out_dir / FRAMES_DIR

    def frame_path(self, index: int) -> Path:
        """Path of frame number ``index`` (0-based): ``frames/frame_00000.vtu`` and on."""
        return self.frames_dir / f"frame_{index:05d}.vtu"

    # -- lifecycle -----------------------------------------------------------------------
    def _start(self) -> None:
        """Create the run directory on first output and clear an earlier run's files."""
        if self._closed:
            raise RuntimeError("RunWriter is closed")
        if self._started:
            return
        self.frames_dir.mkdir(parents=True, exist_ok=True)
        for stale in self.frames_dir.iterdir():
            if FRAME_PATTERN.match(stale.name):
                stale.unlink()
        for name in (BODIES_CSV, REGIONS_CSV, SUMMARY_JSON, self.pvd_path.name):
            (self.out_dir / name).unlink(missing_ok=True)
        # another scene's index in the same directory named the frames just removed
        for index in self.out_dir.glob("*.pvd"):
            if f'file="{FRAMES_DIR}/' in index.read_text(errors="replace"):
                index.unlink()
        self._started = True

    def __enter__(self) -> "RunWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self._writer.wait()
            if exc_type is None:
                self._write_index()
        finally:
            self._close_files()
        if exc_type is None:
            self._writer.raise_error()           # a writer error nobody has seen yet

    def _close_files(self) -> None:
        for f in (self._bodies, self._regions):
            if f is not None and not f.closed:
                f.close()

    def flush(self) -> None:
        """Wait until everything handed over is on disk; raise the writer thread's error if it
        has not been raised yet."""
        self._writer.wait()
        self._writer.raise_error()
        self._write_index()

    def close(self, summary: Mapping[str, Any] | None = None) -> None:
        """Wait for the frames handed over, write ``summary.json`` (if a summary is given) and
        close the CSV files. Raises the writer thread's error (if not raised yet) instead of
        writing the summary."""
        try:
            self.flush()
            if summary is not None:
                self._start()
                text = json.dumps(_plain(summary), indent=2, allow_nan=False) + "\n"
                _atomic_write_text(self.out_dir / SUMMARY_JSON, text)
        finally:
            self._close_files()
            self._closed = True

    # -- frames --------------------------------------------------------------------------
    def _register(self, registry: dict[str, tuple[int, ...]], name: str, array: np.ndarray, kind: str) -> None:
        trailing = array.shape[1:]
        known = registry.setdefault(name, trailing)
        if known != trailing:
            raise ValueError(f"{kind} field {name!r} has row shape {trailing}, earlier pieces gave {known}")

    def build_mesh(self, pieces: Sequence[FramePiece]) -> meshio.Mesh:
        """Merge pieces into one meshio mesh (cell data ``body_id`` plus every known field).

        Every array of the mesh is a new one (concatenated or converted), so the pieces' arrays
        may change as soon as this returns."""
        arrays = []
        for piece in pieces:
            points = np.asarray(piece.points, dtype=float)
            if points.ndim != 2 or points.shape[1] != 3:
                raise ValueError(f"body {piece.body_id}: points have shape {points.shape}, expected (n, 3)")
            cell_count = sum(len(np.asarray(c)) for _, c in piece.cells)
            cdata = {n: _field_array(n, v, cell_count, f"body {piece.body_id} cell")
                     for n, v in piece.cell_data.items()}
            pdata = {n: _field_array(n, v, len(points), f"body {piece.body_id} point")
                     for n, v in piece.point_data.items()}
            for name, array in cdata.items():
                self._register(self._cell_fields, name, array, "cell")
            for name, array in pdata.items():
                self._register(self._point_fields, name, array, "point")
            arrays.append((piece, points, cell_count, cdata, pdata))

        blocks = []
        offset = 0
        for piece, points, cell_count, cdata, pdata in arrays:
            start = 0
            for cell_type, conn in piece.cells:
                conn = np.asarray(conn, dtype=np.int64)
                if conn.ndim != 2:
                    raise ValueError(f"body {piece.body_id}: {cell_type} cells must be a 2-d index array")
                if conn.size and (conn.min() < 0 or conn.max() >= len(points)):
                    raise ValueError(f"body {piece.body_id}: {cell_type} cell index out of range")
                stop = start + len(conn)
                data = {"body_id": np.full(len(conn), piece.body_id, dtype=np.int32)}
                for name, trailing in self._cell_fields.items():
                    if name in cdata:
                        data[name] = cdata[name][start:stop].astype(float)
                    else:
                        data[name] = np.zeros((len(conn), *trailing))
                blocks.append((cell_type, conn + offset, data))
                start = stop
            offset += len(points)

        points = np.concatenate([a[1] for a in arrays]) if arrays else np.zeros((0, 3))
        point_data = {}
        for name, trailing in self._point_fields.items():
            parts = [a[4][name].astype(float) if name in a[4] else np.zeros((len(a[1]), *trailing))
                     for a in arrays]
            point_data[name] = np.concatenate(parts) if parts else np.zeros((0, *trailing))
        cells, cell_data = _merge_blocks(blocks)
        if not cells or not sum(len(block.data) for block in cells):
            # meshio cannot write (or read back) an empty unstructured grid.
            raise ValueError("a frame needs at least one body with at least one cell")
        return meshio.Mesh(points, cells, point_data=point_data, cell_data=cell_data)

    def write_frame(self, time: float, pieces: Sequence[FramePiece], body_rows: Iterable[Any] = ()) -> Path:
        """Write one frame: the merged ``.vtu``, the updated ``.pvd`` and the frame's body rows.

        ``body_rows`` are tuples in the order of ``BODY_COLUMNS`` or dicts with exactly those keys.
        The input is checked (ValueError) and copied here; the files are written by the writer
        thread. Returns the path the frame file gets.
        """
        self._writer.raise_error()
        mesh = self.build_mesh(pieces)
        rows_text = _csv_rows(body_rows, BODY_COLUMNS)
        self._start()
        path = self.frame_path(self._queued)
        self._queued += 1
        self._writer.submit(lambda: self._job(self._write_frame_files, float(time), path, mesh, rows_text))
        return path

    def _job(self, work, *args) -> None:
        """Run ``work(*args)`` (the writer thread's part of a call), then bring the ``.pvd`` up to
        date if no more work waits and it was last written ``index_every`` s ago: replacing a
        file costs a few ms of disk wait (ext4 flushes it). Always before the writer stops on an
        error, and in ``flush`` / ``close``."""
        try:
            work(*args)
        except BaseException:
            self._write_index()
            raise
        if not self._writer.pending() and time.monotonic() - self._index_time >= self.index_every:
            self._write_index()

    def _write_index(self) -> None:
        """Write the ``.pvd`` listing every frame written, if the one on disk lists fewer."""
        if self._pvd_listed != len(self._pvd_lines):
            _atomic_write_text(self.pvd_path, pvd_document(self._pvd_lines))
            self._pvd_listed = len(self._pvd_lines)
        self._index_time = time.monotonic()

    def _write_frame_files(self, time: float, path: Path, mesh: meshio.Mesh, rows_text: str) -> None:
        """The writer thread's part of a frame: ``.vtu``, ``.pvd`` and body rows, in that order."""
        tmp = temporary_path(path)
        try:
            write_vtu(tmp, mesh, self._encoder)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

        self._frame_times.append(time)
        self._frame_files.append(f"{FRAMES_DIR}/{path.name}")
        self._count += 1
        if len(self._pvd_lines) != self._count - 1:          # files taken back by a resume
            self._pvd_lines = [pvd_line(t, f) for t, f in zip(self._frame_times[:-1], self._frame_files[:-1])]
        self._pvd_lines.append(pvd_line(time, self._frame_files[-1]))

        if self._bodies is None:
            self._bodies = open(self.out_dir / BODIES_CSV, "w", encoding="utf-8", newline="")
            rows_text = ",".join(BODY_COLUMNS) + "\n" + rows_text
        self._bodies.write(rows_text)
        self._bodies.flush()

    def write_regions(self, rows: Iterable[Any]) -> None:
        """Append region rows (``REGION_COLUMNS`` order, or dicts); creates regions.csv on first rows."""
        self._writer.raise_error()
        text = _csv_rows(rows, REGION_COLUMNS)
        if not text:
            return
        self._start()
        self._writer.submit(lambda: self._job(self._write_region_rows, text))

    def _write_region_rows(self, text: str) -> None:
        """The writer thread's part of :meth:`write_regions`."""
        if self._regions is None:
            self._regions = open(self.out_dir / REGIONS_CSV, "w", encoding="utf-8", newline="")
            text = ",".join(REGION_COLUMNS) + "\n" + text
        self._regions.write(text)
        self._regions.flush()


def find_pvd(run_dir: Path | str, summary: Mapping[str, Any] | None = None) -> Path:
    """The run's ``.pvd`` index (the scene's own if several are present, else the newest)."""
    run_dir = Path(run_dir)
    candidates = sorted(run_dir.glob("*.pvd"))
    if not candidates:
        raise FileNotFoundError(f"no .pvd index in {run_dir} (is it a run directory?)")
    if len(candidates) == 1:
        return candidates[0]
    scene = (summary or {}).get("scene")
    name = scene.get("name") if isinstance(scene, Mapping) else None
    for c in candidates:
        if name and c.stem == name:
            return c
    return max(candidates, key=lambda c: c.stat().st_mtime)      # the latest run's


def read_summary(run_dir: Path | str) -> dict | None:
    """``summary.json`` of a run, or None when the run did not finish."""
    path = Path(run_dir) / SUMMARY_JSON
    if not path.exists():
        return None
    return json.loads(path.read_text(encoding="utf-8"))


def read_run(run_dir: Path | str) -> tuple[list[float], list[Path], dict | None]:
    """Read a run directory: (frame times in s, frame file paths, summary dict or None)."""
    run_dir = Path(run_dir)
    summary = read_summary(run_dir)
    pvd = find_pvd(run_dir, summary)
    root = ET.parse(pvd).getroot()
    times, paths = [], []
    for dataset in root.iter("DataSet"):
        times.append(float(dataset.get("timestep", "0")))
        paths.append(pvd.parent / dataset.get("file"))
    return times, paths, summary
