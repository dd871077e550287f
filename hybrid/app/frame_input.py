"""The checks of a frame's input on the stepping thread, before it is handed over to the writer
(:mod:`hybrid.app.writer_process`): pieces, fields and rows, each refused with a ValueError that
names what is wrong, and the copy a writer thread takes."""
from __future__ import annotations

from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from .vtu import Deferred


def check_pieces(pieces: Sequence[Any], cell_fields: Mapping, point_fields: Mapping) -> tuple[list, dict, dict]:
    """``(checked, cell_fields, point_fields)``: the pieces
    (:class:`hybrid.app.output.FramePiece`) as :func:`hybrid.app.vtu.merge_pieces` takes them,
    and the field registries (name -> row shape) with their fields added (ValueError if any
    piece is bad; the registries given are not changed)."""
    cell_fields, point_fields = dict(cell_fields), dict(point_fields)
    checked, cell_total = [], 0
    for piece in pieces:
        body_id, owner = _owner(piece)
        points = np.asarray(piece.points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"{owner}: points have shape {points.shape}, expected (n, 3)")
        blocks = []
        for cell_type, conn in piece.cells:
            conn = np.asarray(conn, dtype=np.int64)
            if conn.ndim != 2:
                raise ValueError(f"{owner}: {cell_type} cells must be a 2-d index array")
            if conn.size and (conn.min() < 0 or conn.max() >= len(points)):
                raise ValueError(f"{owner}: {cell_type} cell index out of range")
            blocks.append((str(cell_type), conn))
        cell_count = sum(len(c) for _, c in blocks)
        if body_id.ndim and len(body_id) != cell_count:
            raise ValueError(f"{owner}: {len(body_id)} body ids for {cell_count} cells")
        cell_total += cell_count
        cdata = {n: check_field(n, v, cell_count, f"{owner} cell", cell_fields) for n, v in piece.cell_data.items()}
        pdata = {n: check_field(n, v, len(points), f"{owner} point", point_fields)
                 for n, v in piece.point_data.items()}
        checked.append((int(body_id) if body_id.ndim == 0 else body_id, points, blocks, cdata, pdata))
    if not cell_total:
        # VTK readers cannot read back an empty unstructured grid.
        raise ValueError("a frame needs at least one body with at least one cell")
    return checked, cell_fields, point_fields


def _owner(piece) -> tuple[np.ndarray, str]:
    """A piece's body id (0-d) or ids per cell (1-d) as integers, and its name in messages."""
    body_id = np.asarray(piece.body_id)
    if body_id.ndim > 1 or body_id.dtype.kind not in "iu":
        raise ValueError(f"body_id must be an integer or a 1-d integer array, not {piece.body_id!r}")
    if body_id.ndim == 0:
        return body_id, f"body {int(body_id)}"
    named = f"bodies {int(body_id.min())}-{int(body_id.max())}" if len(body_id) else "bodies (none)"
    return body_id, named


def check_field(name: str, value: Any, count: int, owner: str, registry: dict) -> np.ndarray:
    """A piece's field checked: a 0-d value (the same on every cell or point), (count,) or
    (count, k), or a :class:`hybrid.app.vtu.Deferred` of ``count`` rows; its row shape registered
    in ``registry`` (ValueError if it differs from before)."""
    if isinstance(value, Deferred):
        array, trailing = value, tuple(value.trailing)
        if len(value.trailing) > 1 or len(value) != count:
            raise ValueError(f"{owner} field {name!r} has {len(value)} rows, expected {count}")
    else:
        array = np.asarray(value)
        if array.ndim != 0 and (array.ndim not in (1, 2) or len(array) != count):
            raise ValueError(f"{owner} field {name!r} has shape {array.shape}, expected ({count},) or ({count}, k)")
        trailing = array.shape[1:]
    known = registry.setdefault(name, trailing)
    if known != trailing:
        kind = owner.rsplit(" ", 1)[-1]
        raise ValueError(f"{kind} field {name!r} has row shape {trailing}, earlier pieces gave {known}")
    return array


def check_rows(rows: Iterable[Any], columns: Sequence[str]) -> list[tuple]:
    """Rows as tuples in ``columns`` order (dicts must have exactly ``columns``; ValueError)."""
    out = []
    for row in rows:
        if isinstance(row, Mapping):
            if set(row) != set(columns):
                missing = sorted(set(columns) - set(row))
                extra = sorted(set(row) - set(columns))
                raise ValueError(f"row keys do not match columns: missing {missing}, extra {extra}")
            row = tuple(row[c] for c in columns)
        else:
            row = tuple(row)
            if len(row) != len(columns):
                raise ValueError(f"row has {len(row)} values, expected {len(columns)}: {columns}")
        out.append(row)
    return out


def owned(job: tuple) -> tuple:
    """``job`` with its frame's arrays copied (a job run later by the writer thread)."""
    if job[0] != "frame":
        return job
    pieces = [(np.copy(body_id) if np.ndim(body_id) else body_id, points.copy(), [(t, c.copy()) for t, c in blocks],
               {n: v.copy() for n, v in cdata.items()}, {n: v.copy() for n, v in pdata.items()})
              for body_id, points, blocks, cdata, pdata in job[3]]
    return job[:3] + (pieces,) + job[4:]
