"""VTK XML files of a run: frames (``.vtu`` unstructured grids) and the ``.pvd`` index, the
merging of bodies' cells and fields into one frame mesh (:func:`merge_pieces`), and
:class:`FrameFiles`, which writes a run's frames, index and CSV tables as the writer's jobs come.

The frames' own writer: the file meshio writes (binary, zlib-compressed blocks, UInt32 headers,
which meshio, VTK and ParaView read), at zlib's fastest level, and with each array's encoding
kept from the frame before: connectivity, offsets, cell types and fields that do not change
(body ids, fragment_of, a body's plastic strain at rest) are compressed once per run, not once
per frame. Compressing every array of every frame took most of the writing time.
"""
from __future__ import annotations

import math
import os
import time
import zlib
from base64 import b64encode
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence
from xml.sax.saxutils import quoteattr

import numpy as np

from .text_files import append_whole, atomic_write_text, csv_rows, temporary_path

# meshio (a quarter of a second to import) is imported only where it is used, so that the writer
# process (hybrid.app.writer_process) starts without it.

def field_array(name: str, value: Any, count: int, owner: str) -> np.ndarray:
    """Field values as a (count,) or (count, k) float array (0-d values are broadcast)."""
    array = np.asarray(value)
    if array.ndim == 0:
        array = np.full(count, array)
    if array.ndim not in (1, 2) or len(array) != count:
        raise ValueError(f"{owner} field {name!r} has shape {array.shape}, expected ({count},) or ({count}, k)")
    return array


def merge_blocks(blocks: list[tuple[str, np.ndarray, dict[str, np.ndarray]]]):
    """Join consecutive blocks ``(cell type, connectivity, cell data)`` of the same cell type
    (keeps cell order): ``(meshio cell blocks, cell data by name, one array per block)``."""
    merged: list[tuple[str, list[np.ndarray], dict[str, list[np.ndarray]]]] = []
    for cell_type, conn, data in blocks:
        if merged and merged[-1][0] == cell_type:
            merged[-1][1].append(conn)
            for name, values in data.items():
                merged[-1][2][name].append(values)
        else:
            merged.append((cell_type, [conn], {n: [v] for n, v in data.items()}))
    import meshio
    cells = [meshio.CellBlock(t, np.concatenate(c)) for t, c, _ in merged]
    names = merged[0][2].keys() if merged else []
    cell_data = {n: [np.concatenate(d[n]) for _, _, d in merged] for n in names}
    return cells, cell_data


VTK_CELL_TYPES = {"triangle": 5, "tetra": 10, "tetra10": 24}   # VTK's cell type ids (same node order as meshio)
_VTU_TYPES = {"f8": "Float64", "f4": "Float32", "i8": "Int64", "i4": "Int32", "i2": "Int16", "i1": "Int8",
              "u8": "UInt64", "u4": "UInt32", "u2": "UInt16", "u1": "UInt8"}
_VTU_BLOCK = 32768          # bytes per compressed block, as VTK writes them


# an array is compressed when zlib shrinks a sample of it (SAMPLE bytes in four slices spread over
# it) to at most WORTH of its size; else its blocks are stored (zlib's level 0: the same format,
# read by every reader, at memory speed). Compressing costs about 12 us a kB at zlib's fastest
# level, storing 0.4: a deforming body's float64 positions shrink by a fifth, a rigid scene's
# posed surfaces by a third (the default scene's 44 kB of points: 0.5 ms compressed against 0.02
# stored, a writer process's time the stepping thread shares its machine with)
SAMPLE = 4096
WORTH = 0.5


def _sample(raw: bytes) -> bytes:
    """SAMPLE bytes of ``raw`` in four slices spread over it (all of it if shorter): the
    first kB of a frame's points is one body's, often a fixed one's."""
    if len(raw) <= SAMPLE:
        return raw
    piece = SAMPLE // 4
    return b"".join(raw[i:i + piece] for i in np.linspace(0, len(raw) - piece, 4).astype(int).tolist())


class VtuEncoder:
    """Encodes arrays as base64 zlib blocks of a ``.vtu`` file, reusing the previous encoding of
    an array (by key) whose bytes did not change; an array that compresses poorly is stored in
    its blocks uncompressed (SAMPLE, WORTH)."""

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
        sample = _sample(raw)
        level = self.level if len(zlib.compress(sample, self.level)) <= WORTH * len(sample) else 0
        blocks = [zlib.compress(raw[i:i + _VTU_BLOCK], level) for i in range(0, len(raw), _VTU_BLOCK)]
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


@dataclass
class FrameMesh:
    """One frame's mesh as plain arrays (what :func:`write_vtu` writes).

    points: (n, 3) m. cells: ``(cell type, (m, k) int64 indices into points)`` blocks in order.
    point_data: name -> (n,) or (n, k). cell_data: name -> (cell_count,) or (cell_count, k), one
    value or row per cell over all blocks in order."""

    points: np.ndarray
    cells: list[tuple[str, np.ndarray]]
    point_data: dict[str, np.ndarray] = field(default_factory=dict)
    cell_data: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def of(cls, mesh: Any) -> "FrameMesh":
        """A FrameMesh of a ``meshio.Mesh`` (its cell data joined over the blocks), or ``mesh``."""
        if isinstance(mesh, cls):
            return mesh
        return cls(np.asarray(mesh.points), [(b.type, np.asarray(b.data)) for b in mesh.cells],
                   dict(mesh.point_data), {n: np.concatenate(v) for n, v in mesh.cell_data.items()})

    def to_meshio(self):
        """The same mesh as a ``meshio.Mesh`` (consecutive blocks of one cell type joined)."""
        import meshio
        sizes = [len(c) for _, c in self.cells]
        splits = np.cumsum(sizes)[:-1]
        blocks = [(t, c, {n: v for n, v in zip(self.cell_data, parts)})
                  for (t, c), *parts in zip(self.cells, *(np.split(a, splits) for a in self.cell_data.values()))]
        cells, cell_data = merge_blocks(blocks)
        return meshio.Mesh(self.points, cells, point_data=self.point_data, cell_data=cell_data)


Piece = tuple       # (body id or ids per cell, points (n, 3) float, [(cell type, (m, k) int64)], cell data, point data)


@dataclass
class Deferred:
    """Values computed by the writer: ``function(argument)`` (or ``function(*argument)`` for a
    tuple of arrays), ``rows`` rows (default ``len(argument)``) of ``trailing`` shape each.
    ``function`` must be a module-level function (pickled by name for the writer process), e.g.
    ``Deferred(fem.stress.principal_stress_max, sigma)``: the stepping thread hands over the
    stresses and the writer computes their largest eigenvalues. A piece's fields and points may
    be deferred."""

    function: Any
    argument: Any
    trailing: tuple = ()
    rows: int | None = None

    def __len__(self) -> int:
        return len(self.argument) if self.rows is None else self.rows

    def value(self) -> np.ndarray:
        """The values."""
        if isinstance(self.argument, tuple):
            return np.asarray(self.function(*self.argument))
        return np.asarray(self.function(self.argument))

    def copy(self) -> "Deferred":
        """The same values with their arguments copied (read-only arrays that own their data,
        which cannot change, are kept as they are)."""
        argument = tuple(map(owned_array, self.argument)) if isinstance(self.argument, tuple) else owned_array(self.argument)
        return Deferred(self.function, argument, self.trailing, self.rows)


def owned_array(array):
    """``array`` as a writer may keep it: a copy, unless it is read-only and owns its data."""
    array = np.asarray(array)
    return array if array.base is None and not array.flags.writeable else array.copy()


def _value(field_value):
    return field_value.value() if isinstance(field_value, Deferred) else field_value


def merge_pieces(pieces: Sequence[Piece], cell_fields: Mapping[str, tuple[int, ...]],
                 point_fields: Mapping[str, tuple[int, ...]]) -> FrameMesh:
    """Merge checked pieces (see :meth:`hybrid.app.output.RunWriter.write_frame`) into one frame:
    cell data ``body_id`` (int32) and every field of ``cell_fields`` / ``point_fields`` (name ->
    row shape, in order) as float64, 0 where a piece does not supply it; a piece's field may be
    0-d (the same value on every cell or point). Every array returned is a new one."""
    conn, body_ids = [], []
    cell_parts = {name: [] for name in cell_fields}
    offset = 0
    for body_id, points, blocks, cdata, pdata in pieces:
        cdata = {n: _value(v) for n, v in cdata.items()}
        start = 0
        for cell_type, c in blocks:
            stop = start + len(c)
            conn.append((cell_type, c + offset))
            body_ids.append(np.full(len(c), body_id, dtype=np.int32) if np.ndim(body_id) == 0
                            else body_id[start:stop].astype(np.int32))
            for name, trailing in cell_fields.items():
                value = cdata.get(name)
                if value is None:
                    part = np.zeros((len(c), *trailing))
                elif np.ndim(value) == 0:
                    part = np.full(len(c), value).astype(float)
                else:
                    part = value[start:stop].astype(float)
                cell_parts[name].append(part)
            start = stop
        offset += len(points)
    point_data = {}
    for name, trailing in point_fields.items():
        parts = []
        for _, points, _, _, pdata in pieces:
            value = _value(pdata.get(name))
            if value is None:
                parts.append(np.zeros((len(points), *trailing)))
            elif np.ndim(value) == 0:
                parts.append(np.full(len(points), value).astype(float))
            else:
                parts.append(value.astype(float))
        point_data[name] = np.concatenate(parts) if parts else np.zeros((0, *trailing))
    points = np.concatenate([_value(p[1]) for p in pieces]) if pieces else np.zeros((0, 3))
    cell_data = {"body_id": np.concatenate(body_ids)} | {n: np.concatenate(v) for n, v in cell_parts.items()}
    return FrameMesh(points, conn, point_data, cell_data)


def write_vtu(path: Path | str, mesh: Any, encoder: VtuEncoder | None = None) -> None:
    """Write ``mesh`` (a :class:`FrameMesh` or ``meshio.Mesh``; triangle, tetra and tetra10
    blocks, anything else through meshio) as a ``.vtu`` file at ``path``; ``encoder`` carries
    unchanged arrays over from the last frame."""
    mesh = FrameMesh.of(mesh)
    if any(cell_type not in VTK_CELL_TYPES for cell_type, _ in mesh.cells):
        import meshio
        meshio.write(path, mesh.to_meshio(), file_format="vtu")
        return
    encoder = encoder or VtuEncoder()
    conn = [np.asarray(c, dtype=np.int64) for _, c in mesh.cells]
    sizes = np.concatenate([np.full(len(c), c.shape[1], dtype=np.int64) for c in conn])
    types = np.concatenate([np.full(len(c), VTK_CELL_TYPES[t], dtype=np.uint8)
                            for (t, _), c in zip(mesh.cells, conn)])
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
        parts += [_vtu_array(encoder, ("cell", n), n, v) for n, v in mesh.cell_data.items()]
        parts.append("</CellData>\n")
    parts.append("</Piece>\n</UnstructuredGrid>\n</VTKFile>\n")
    with open(path, "w", encoding="ascii") as f:
        f.write("".join(parts))


def pvd_line(time: float, file: str) -> str:
    """The ``.pvd`` index's line of one frame: ``file`` at ``time`` (s)."""
    return f'    <DataSet timestep={_attribute(repr(float(time)))} group="" part="0" file={_attribute(file)} />\n'


def _attribute(value: str) -> str:
    """An XML attribute value in double quotes (escaped only when it needs it: quoteattr is slow)."""
    return f'"{value}"' if not any(c in value for c in '&<>"\n\r\t') else quoteattr(value)


def pvd_document(lines: Sequence[str]) -> str:
    """The ``.pvd`` index made of :func:`pvd_line` lines."""
    head = '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
    if not lines:
        return head + '  <Collection />\n</VTKFile>\n'
    return head + "  <Collection>\n" + "".join(lines) + "  </Collection>\n</VTKFile>\n"


def pvd_text(times: Sequence[float], files: Sequence[str]) -> str:
    """The ``.pvd`` index listing ``files`` at ``times``."""
    return pvd_document([pvd_line(time, file) for time, file in zip(times, files)])


FRAMES_DIR = "frames"


# a writer that is never idle (frames keep coming) rewrites the .pvd every this many index_every
BUSY_INDEX = 10


class FrameFiles:
    """The files of one run as written so far, and the jobs that write them.

    A job is a tuple ``(name, *args)`` naming a method: ``frame``, ``values``, ``rows``, ``index``,
    ``restore`` or ``state``. ``write_vtu``: the function that writes a frame file (the default
    :func:`hybrid.app.vtu.write_vtu`). ``index_every``: wall time (s), at least, between rewrites
    of the ``.pvd`` while frames come (replacing a file waits a few ms for the disk)."""

    def __init__(self, out_dir: str, pvd_name: str, index_every: float = 0.2, write_vtu=None):
        self.out_dir, self.pvd_path = Path(out_dir), Path(out_dir) / pvd_name
        self.index_every = index_every
        self.write_vtu = write_vtu or globals()["write_vtu"]
        self.count = 0                      # frames on disk
        self.times: list[float] = []        # their times (s)
        self.files: list[str] = []          # their .pvd entries (frames/frame_00000.vtu, ...)
        self.pvd_lines: list[str] = []      # the .pvd's lines of those frames
        self.pvd_listed = 0                 # frames the .pvd on disk lists
        self.index_time = -math.inf         # time.monotonic() of its last rewrite
        self.tables: dict[str, Any] = {}    # CSV file name -> open file
        self.encoder = VtuEncoder()
        self.last: tuple | None = None      # the last frame's pieces and fields (for ``values``)

    JOBS = ("frame", "values", "rows", "index", "restore", "state")

    def run(self, job: tuple, idle: bool) -> Any:
        """Run ``job``; then, when ``idle`` (no job waits) and the ``.pvd`` was last written
        ``index_every`` s ago (``BUSY_INDEX`` times that when not idle), bring it up to date. An error writes the ``.pvd`` first, so the
        index lists every frame on disk, and is raised."""
        if job[0] not in self.JOBS:
            raise ValueError(f"unknown writer job {job[0]!r}")
        try:
            result = getattr(self, job[0])(*job[1:])
        except BaseException:
            self.index()
            raise
        # while frames keep coming (none idle), at most every BUSY_INDEX times as long
        if time.monotonic() - self.index_time >= self.index_every * (1 if idle else BUSY_INDEX):
            self.index()
        return result

    def frame(self, t: float, name: str, pieces, cell_fields, point_fields, table, columns, rows) -> None:
        """Frame file ``frames/<name>`` of the checked ``pieces`` (merged with
        :func:`hybrid.app.vtu.merge_pieces`), its ``.pvd`` line, and its ``rows`` in ``table``."""
        self.last = (pieces, cell_fields, point_fields)
        mesh = merge_pieces(pieces, cell_fields, point_fields)
        path = self.out_dir / FRAMES_DIR / name
        tmp = temporary_path(path)
        try:
            self.write_vtu(tmp, mesh, self.encoder)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        try:        # the frame and its rows, or neither (a full disk may stop the rows)
            self.rows(table, columns, rows)
        except BaseException:
            path.unlink(missing_ok=True)
            raise
        self.times.append(float(t))
        self.files.append(f"{FRAMES_DIR}/{name}")
        self.pvd_lines.append(pvd_line(t, self.files[-1]))
        self.count += 1

    def values(self, t: float, name: str, paths, values, table, columns, rows) -> None:
        """A frame of the last frame's layout, its ``values`` at ``paths`` (:mod:`hybrid.app.frame_layout`)."""
        from .frame_layout import filled        # (which imports this module)
        pieces, cell_fields, point_fields = self.last
        self.frame(t, name, filled(pieces, paths, values), cell_fields, point_fields, table, columns, rows)

    def rows(self, table: str, columns, rows) -> None:
        """Append ``rows`` (checked tuples in ``columns`` order) to the CSV file ``table``, which
        gets its header when it is created. The file is unbuffered and a write that fails (a full
        disk) is cut back off, so only whole lines stay on disk and closing it writes nothing."""
        text = csv_rows(rows, columns)
        f = self.tables.get(table)
        if f is None:
            f = self.tables[table] = open(self.out_dir / table, "wb", buffering=0)
            text = ",".join(columns) + "\n" + text
        append_whole(f, text.encode("utf-8"))

    def index(self) -> None:
        """Write the ``.pvd`` listing every frame written, if the one on disk lists fewer."""
        if self.pvd_listed != len(self.pvd_lines):
            atomic_write_text(self.pvd_path, pvd_document(self.pvd_lines))
            self.pvd_listed = len(self.pvd_lines)
        self.index_time = time.monotonic()

    def state(self) -> dict:
        """Where the files stand: ``count``, ``times``, ``files``, ``tables`` (name -> bytes
        written), ``listed`` (frames the ``.pvd`` on disk lists), ``index_time``."""
        return {"count": self.count, "times": list(self.times), "files": list(self.files),
                "tables": {name: f.tell() for name, f in self.tables.items()},
                "listed": self.pvd_listed, "index_time": self.index_time}

    def restore(self, state: dict) -> None:
        """Continue files that stand at ``state`` (from :meth:`state`, or a checkpoint's files
        taken back to it): the ``.pvd`` on disk lists ``listed`` of its frames (all of them if
        not said), its tables exist with exactly those lengths and are appended to."""
        self.close()
        self.last = None
        self.count, self.times, self.files = int(state["count"]), list(state["times"]), list(state["files"])
        self.pvd_lines = [pvd_line(t, f) for t, f in zip(self.times, self.files)]
        self.pvd_listed = int(state.get("listed", len(self.pvd_lines)))
        self.index_time = state.get("index_time", -math.inf)
        for name in state["tables"]:
            self.tables[name] = open(self.out_dir / name, "ab", buffering=0)

    def close(self) -> None:
        """Close the tables."""
        tables, self.tables = self.tables, {}
        for f in tables.values():
            f.close()
