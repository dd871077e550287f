"""VTK XML files of a run: frames (``.vtu`` unstructured grids) and the ``.pvd`` index, and the
merging of bodies' cells and fields into one frame mesh.

The frames' own writer: the file meshio writes (binary, zlib-compressed blocks, UInt32 headers,
which meshio, VTK and ParaView read), at zlib's fastest level, and with each array's encoding
kept from the frame before: connectivity, offsets, cell types and fields that do not change
(body ids, fragment_of, a body's plastic strain at rest) are compressed once per run, not once
per frame. Compressing every array of every frame took most of the writing time.
"""
from __future__ import annotations

import zlib
from base64 import b64encode
from pathlib import Path
from typing import Any, Sequence
from xml.sax.saxutils import quoteattr

import meshio
import numpy as np

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
    cells = [meshio.CellBlock(t, np.concatenate(c)) for t, c, _ in merged]
    names = merged[0][2].keys() if merged else []
    cell_data = {n: [np.concatenate(d[n]) for _, _, d in merged] for n in names}
    return cells, cell_data


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
