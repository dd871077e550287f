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
import xml.etree.ElementTree as ET
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


class RunWriter:
    """Write the frames, body and region tables and the summary of one run.

    ``RunWriter(out_dir, scene_name)`` creates nothing until the first frame, region rows or
    summary is written, so a run that fails validation leaves no directory behind. When it does
    create the run, stale outputs of an earlier run in the same directory (frame files, CSV
    tables, summary) are removed first. Use it as a context manager so the CSV files are closed
    on error::

        with RunWriter(out_dir, "drop") as writer:
            writer.write_frame(t, pieces, body_rows)
            writer.close(summary)

    Cell and point field names are discovered from the pieces: once a field has been seen, every
    later frame carries it, with 0 for bodies that do not supply it.
    """

    def __init__(self, out_dir: Path | str, scene_name: str):
        self.out_dir = Path(out_dir)
        self.scene_name = str(scene_name)
        self.frames_written = 0
        self._times: list[float] = []
        self._files: list[str] = []
        self._cell_fields: dict[str, tuple[int, ...]] = {}
        self._point_fields: dict[str, tuple[int, ...]] = {}
        self._bodies_file: io.TextIOWrapper | None = None
        self._regions_file: io.TextIOWrapper | None = None
        self._started = False
        self._closed = False

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
        self._close_files()

    def _close_files(self) -> None:
        for f in (self._bodies_file, self._regions_file):
            if f is not None and not f.closed:
                f.close()

    def close(self, summary: Mapping[str, Any] | None = None) -> None:
        """Write ``summary.json`` (if a summary is given) and close the CSV files."""
        try:
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
        """Merge pieces into one meshio mesh (cell data ``body_id`` plus every known field)."""
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
        Returns the path of the written frame file.
        """
        mesh = self.build_mesh(pieces)
        rows_text = _csv_rows(body_rows, BODY_COLUMNS)
        self._start()

        path = self.frame_path(self.frames_written)
        fd, tmp = tempfile.mkstemp(dir=self.frames_dir, prefix=f".{path.name}.", suffix=".tmp")
        os.close(fd)
        try:
            meshio.write(tmp, mesh, file_format="vtu")
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

        self._times.append(float(time))
        self._files.append(f"{FRAMES_DIR}/{path.name}")
        self.frames_written += 1
        _atomic_write_text(self.pvd_path, _pvd_text(self._times, self._files))

        if self._bodies_file is None:
            self._bodies_file = open(self.out_dir / BODIES_CSV, "w", encoding="utf-8", newline="")
            rows_text = ",".join(BODY_COLUMNS) + "\n" + rows_text
        self._bodies_file.write(rows_text)
        self._bodies_file.flush()
        return path

    def write_regions(self, rows: Iterable[Any]) -> None:
        """Append region rows (``REGION_COLUMNS`` order, or dicts); creates regions.csv on first rows."""
        text = _csv_rows(rows, REGION_COLUMNS)
        if not text:
            return
        self._start()
        if self._regions_file is None:
            self._regions_file = open(self.out_dir / REGIONS_CSV, "w", encoding="utf-8", newline="")
            text = ",".join(REGION_COLUMNS) + "\n" + text
        self._regions_file.write(text)
        self._regions_file.flush()


def _pvd_text(times: Sequence[float], files: Sequence[str]) -> str:
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    collection = ET.SubElement(root, "Collection")
    for time, file in zip(times, files):
        ET.SubElement(collection, "DataSet", timestep=repr(float(time)), group="", part="0", file=file)
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


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
