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

import csv
import io
import json
import math
import os
import re
import tempfile
import threading
import time
import xml.etree.ElementTree as ET
import zlib
from base64 import b64encode
from collections import deque
from xml.sax.saxutils import quoteattr
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import meshio
import numpy as np

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


def _plain(value: Any) -> Any:
    """Convert numpy scalars/arrays, tuples and paths to JSON-ready Python values.

    Non-finite floats become None so that the file is strict JSON.
    """
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, (list, tuple, set, frozenset)):
        return [_plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value


def _csv_value(value: Any) -> Any:
    """Python value for the csv module: ints exact, floats at full precision (repr)."""
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return value


def _csv_rows(rows: Iterable[Any], columns: Sequence[str]) -> str:
    """Format rows (tuples in column order, or dicts with exactly ``columns``) as CSV text."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    for row in rows:
        if isinstance(row, Mapping):
            if set(row) != set(columns):
                missing = sorted(set(columns) - set(row))
                extra = sorted(set(row) - set(columns))
                raise ValueError(f"row keys do not match columns: missing {missing}, extra {extra}")
            values = [row[c] for c in columns]
        else:
            values = list(row)
            if len(values) != len(columns):
                raise ValueError(f"row has {len(values)} values, expected {len(columns)}: {columns}")
        writer.writerow([_csv_value(v) for v in values])
    return buffer.getvalue()


def _atomic_write_text(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _field_array(name: str, value: Any, count: int, owner: str) -> np.ndarray:
    """Field values as a (count,) or (count, k) float array (0-d values are broadcast)."""
    array = np.asarray(value)
    if array.ndim == 0:
        array = np.full(count, array)
    if array.ndim not in (1, 2) or len(array) != count:
        raise ValueError(f"{owner} field {name!r} has shape {array.shape}, expected ({count},) or ({count}, k)")
    return array


def _merge_blocks(blocks: list[tuple[str, np.ndarray, dict[str, np.ndarray]]]):
    """Join consecutive blocks of the same cell type (keeps cell order)."""
    merged: list[tuple[str, list[np.ndarray], dict[str, list[np.ndarray]]]] = []
    for cell_type, conn, data in blocks:
        if merged and merged[-1][0] == cell_type:
            merged[-1][1].append(conn)
            for name, values in data.items():
                merged[-1][2][name].append(values)
        else:
            merged.append((cell_type, [conn], {n: [v] for n, v in data.items()}))
    cells = [meshio.CellBlock(t, np.concatenate(c)) for t, c, _ in merged]
    names = merged[0][2].keys() if merged else []
    cell_data = {n: [np.concatenate(d[n]) for _, _, d in merged] for n in names}
    return cells, cell_data


# -- VTK XML unstructured grid (.vtu) ---------------------------------------------------------
# The frames' own writer: the file meshio writes (binary, zlib-compressed blocks, UInt32 headers,
# which meshio, VTK and ParaView read), at zlib's fastest level, and with each array's encoding
# kept from the frame before: connectivity, offsets, cell types and fields that do not change
# (body ids, fragment_of, a body's plastic strain at rest) are compressed once per run, not once
# per frame. Compressing every array of every frame took most of the writing time.
VTK_CELL_TYPES = {"triangle": 5, "tetra": 10, "tetra10": 24}   # VTK's cell type ids (same node order as meshio)
_VTU_TYPES = {"f8": "Float64", "f4": "Float32", "i8": "Int64", "i4": "Int32", "i2": "Int16", "i1": "Int8",
              "u8": "UInt64", "u4": "UInt32", "u2": "UInt16", "u1": "UInt8"}
_VTU_BLOCK = 32768          # bytes per compressed block, as VTK writes them


class VtuEncoder:
    """Encodes arrays as base64 zlib blocks of a ``.vtu`` file, reusing the previous encoding of
    an array (by key) whose bytes did not change."""

    def __init__(self, level: int = 1):
        self.level = level
        self._last: dict[Any, tuple[bytes, str]] = {}

    def encode(self, key: Any, array: np.ndarray) -> tuple[str, str]:
        """``(VTK type name, encoded text)`` of ``array`` (little-endian, C order)."""
        array = np.ascontiguousarray(array)
        array = array.astype(array.dtype.newbyteorder("<"), copy=False)
        vtk_type = _VTU_TYPES[f"{array.dtype.kind}{array.dtype.itemsize}"]
        raw = array.tobytes()
        last = self._last.get(key)
        if last is not None and last[0] == raw:
            return vtk_type, last[1]
        blocks = [zlib.compress(raw[i:i + _VTU_BLOCK], self.level) for i in range(0, len(raw), _VTU_BLOCK)]
        last_size = len(raw) - (len(blocks) - 1) * _VTU_BLOCK if blocks else 0
        header = np.array([len(blocks), _VTU_BLOCK, last_size] + [len(b) for b in blocks], dtype="<u4")
        text = b64encode(header.tobytes()).decode() + b64encode(b"".join(blocks)).decode()
        self._last[key] = (raw, text)
        return vtk_type, text


def _vtu_array(encoder: VtuEncoder, key: Any, name: str, array: np.ndarray) -> str:
    array = np.asarray(array)
    if array.dtype == bool:
        array = array.astype(np.uint8)
    vtk_type, text = encoder.encode(key, array)
    components = f' NumberOfComponents="{int(np.prod(array.shape[1:]))}"' if array.ndim > 1 else ""
    return (f'<DataArray type="{vtk_type}" Name={quoteattr(name)}{components} format="binary">\n'
            f"{text}\n</DataArray>\n")


def write_vtu(path: Path | str, mesh: meshio.Mesh, encoder: VtuEncoder | None = None) -> None:
    """Write ``mesh`` (triangle, tetra and tetra10 blocks; anything else through meshio) as a
    ``.vtu`` file at ``path``; ``encoder`` carries unchanged arrays over from the last frame."""
    if any(block.type not in VTK_CELL_TYPES for block in mesh.cells):
        meshio.write(path, mesh, file_format="vtu")
        return
    encoder = encoder or VtuEncoder()
    conn = [np.asarray(block.data, dtype=np.int64) for block in mesh.cells]
    sizes = np.concatenate([np.full(len(c), c.shape[1], dtype=np.int64) for c in conn])
    types = np.concatenate([np.full(len(c), VTK_CELL_TYPES[b.type], dtype=np.uint8)
                            for b, c in zip(mesh.cells, conn)])
    parts = ['<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="0.1" '
             'byte_order="LittleEndian" compressor="vtkZLibDataCompressor">\n<UnstructuredGrid>\n'
             f'<Piece NumberOfPoints="{len(mesh.points)}" NumberOfCells="{len(types)}">\n<Points>\n',
             _vtu_array(encoder, "points", "Points", np.asarray(mesh.points, dtype=float)),
             "</Points>\n<Cells>\n",
             _vtu_array(encoder, "connectivity", "connectivity", np.concatenate([c.ravel() for c in conn])),
             _vtu_array(encoder, "offsets", "offsets", np.cumsum(sizes)),
             _vtu_array(encoder, "types", "types", types),
             "</Cells>\n"]
    if mesh.point_data:
        parts.append("<PointData>\n")
        parts += [_vtu_array(encoder, ("point", n), n, v) for n, v in mesh.point_data.items()]
        parts.append("</PointData>\n")
    if mesh.cell_data:
        parts.append("<CellData>\n")
        parts += [_vtu_array(encoder, ("cell", n), n, np.concatenate(v)) for n, v in mesh.cell_data.items()]
        parts.append("</CellData>\n")
    parts.append("</Piece>\n</UnstructuredGrid>\n</VTKFile>\n")
    with open(path, "w", encoding="ascii") as f:
        f.write("".join(parts))


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

    def __init__(self, out_dir: Path | str, scene_name: str, background: bool = True):
        self.out_dir = Path(out_dir)
        self.scene_name = str(scene_name)
        self.background = bool(background)
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
        # hand-over: queued jobs, the caller's frame count, the thread and its first error
        self._queued = 0                      # frames handed over (written or waiting)
        self._jobs: deque = deque()
        self._busy = False                    # the worker is running a job it has taken
        self._worker: threading.Thread | None = None
        self._error: BaseException | None = None
        self._error_raised = False
        self._lock = threading.Condition()
        self.writer_seconds = 0.0             # wall time spent writing files (either thread)

    # -- file state, as on disk once the queued work is done -----------------------------
    @property
    def frames_written(self) -> int:
        """Frames written so far (waits for the frames handed over to reach the disk)."""
        self._wait_idle()
        return self._count

    @frames_written.setter
    def frames_written(self, value: int) -> None:
        self._wait_idle()
        self._count = self._queued = int(value)

    def _state_property(name: str, doc: str):          # noqa: N805 (a property factory)
        def get(self):
            self._wait_idle()
            return getattr(self, name)

        def put(self, value):
            self._wait_idle()
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
            self._wait_idle()
        finally:
            self._close_files()
        if exc_type is None:
            self._raise_error()           # a writer error nobody has seen yet

    def _close_files(self) -> None:
        for f in (self._bodies, self._regions):
            if f is not None and not f.closed:
                f.close()

    def flush(self) -> None:
        """Wait until everything handed over is on disk; raise the writer thread's error if it
        has not been raised yet."""
        self._wait_idle()
        self._raise_error()

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

    # -- the writer thread ---------------------------------------------------------------
    def _submit(self, job) -> None:
        """Queue ``job`` (a callable without arguments) for the writer thread, starting it if
        none runs; waits while ``queue_frames`` jobs are waiting. Without ``background``: runs
        it now."""
        if not self.background:
            start = time.perf_counter()
            try:
                job()
            except BaseException as error:
                self._error, self._error_raised = error, True
                raise
            finally:
                self.writer_seconds += time.perf_counter() - start
            return
        with self._lock:
            while len(self._jobs) >= self.queue_frames and self._error is None:
                self._lock.wait()
            if self._error is not None:
                return                    # writing stopped; the caller hears of it via _raise_error
            self._jobs.append(job)
            if self._worker is None:
                self._worker = threading.Thread(target=self._work, name="RunWriter", daemon=False)
                self._worker.start()

    def _work(self) -> None:
        """The writer thread: run the jobs in order until none is left (or one fails)."""
        while True:
            with self._lock:
                if not self._jobs or self._error is not None:
                    self._jobs.clear()
                    self._worker = None
                    self._lock.notify_all()
                    return
                job = self._jobs.popleft()
                self._busy = True
                self._lock.notify_all()
            start = time.perf_counter()
            try:
                job()
            except BaseException as error:     # noqa: BLE001 (kept for the caller's thread)
                with self._lock:
                    self._error = error
            finally:
                with self._lock:
                    self._busy = False
                    self.writer_seconds += time.perf_counter() - start

    def _wait_idle(self) -> None:
        """Block until the writer thread has nothing left to do."""
        if self._worker is None:
            return
        if self._worker is threading.current_thread():
            return
        with self._lock:
            while self._jobs or self._busy or self._worker is not None:
                self._lock.wait()

    def _raise_error(self) -> None:
        """Raise the writer thread's error on the caller's thread, once."""
        with self._lock:
            error = None if self._error_raised else self._error
            self._error_raised = self._error_raised or error is not None
        if error is not None:
            raise error

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
        self._raise_error()
        mesh = self.build_mesh(pieces)
        rows_text = _csv_rows(body_rows, BODY_COLUMNS)
        self._start()
        path = self.frame_path(self._queued)
        self._queued += 1
        self._submit(lambda: self._write_frame_files(float(time), path, mesh, rows_text))
        return path

    def _write_frame_files(self, time: float, path: Path, mesh: meshio.Mesh, rows_text: str) -> None:
        """The writer thread's part of a frame: ``.vtu``, ``.pvd`` and body rows, in that order."""
        fd, tmp = tempfile.mkstemp(dir=self.frames_dir, prefix=f".{path.name}.", suffix=".tmp")
        os.close(fd)
        try:
            write_vtu(tmp, mesh, self._encoder)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

        self._frame_times.append(time)
        self._frame_files.append(f"{FRAMES_DIR}/{path.name}")
        self._count += 1
        _atomic_write_text(self.pvd_path, _pvd_text(self._frame_times, self._frame_files))

        if self._bodies is None:
            self._bodies = open(self.out_dir / BODIES_CSV, "w", encoding="utf-8", newline="")
            rows_text = ",".join(BODY_COLUMNS) + "\n" + rows_text
        self._bodies.write(rows_text)
        self._bodies.flush()

    def write_regions(self, rows: Iterable[Any]) -> None:
        """Append region rows (``REGION_COLUMNS`` order, or dicts); creates regions.csv on first rows."""
        self._raise_error()
        text = _csv_rows(rows, REGION_COLUMNS)
        if not text:
            return
        self._start()
        self._submit(lambda: self._write_region_rows(text))

    def _write_region_rows(self, text: str) -> None:
        """The writer thread's part of :meth:`write_regions`."""
        if self._regions is None:
            self._regions = open(self.out_dir / REGIONS_CSV, "w", encoding="utf-8", newline="")
            text = ",".join(REGION_COLUMNS) + "\n" + text
        self._regions.write(text)
        self._regions.flush()


def _pvd_text(times: Sequence[float], files: Sequence[str]) -> str:
    """The ``.pvd`` index listing ``files`` at ``times`` (built as text: it is rewritten at
    every frame)."""
    lines = [f'    <DataSet timestep={quoteattr(repr(float(time)))} group="" part="0" file={quoteattr(file)} />\n'
             for time, file in zip(times, files)]
    head = '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
    if not lines:
        return head + '  <Collection />\n</VTKFile>\n'
    return head + "  <Collection>\n" + "".join(lines) + "  </Collection>\n</VTKFile>\n"


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
