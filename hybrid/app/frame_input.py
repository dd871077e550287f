"""A frame on its way to the writer (:mod:`hybrid.app.writer_process`): the checks of its pieces
and fields on the stepping thread (each refused with a ValueError that names what is wrong; its
rows: :func:`hybrid.app.text_files.check_rows`), the copy a writer thread takes, and the arrays
a writer process keeps from frame to frame (:class:`KeptArrays`)."""
from __future__ import annotations

import io
import pickle
import weakref
from typing import Any, Mapping, Sequence

import numpy as np

from .vtu import Deferred, owned_array


def check_pieces(pieces: Sequence[Any], cell_fields: Mapping, point_fields: Mapping) -> tuple[list, dict, dict]:
    """``(checked, cell_fields, point_fields)``: the pieces
    (:class:`hybrid.app.output.FramePiece`) as :func:`hybrid.app.vtu.merge_pieces` takes them,
    and the field registries (name -> row shape) with their fields added (ValueError if any
    piece is bad; the registries given are not changed)."""
    cell_fields, point_fields = dict(cell_fields), dict(point_fields)
    checked, cell_total = [], 0
    for piece in pieces:
        body_id, owner = _owner(piece)
        if isinstance(piece.points, Deferred):        # posed by the writer
            points = piece.points
            shape = (len(points), *points.trailing)
        else:
            points = np.asarray(piece.points, dtype=float)
            shape = points.shape
        if len(shape) != 2 or shape[1] != 3:
            raise ValueError(f"{owner}: points have shape {shape}, expected (n, 3)")
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


def owned(job: tuple) -> tuple:
    """``job`` with its frame's arrays copied (a job run later by the writer thread); read-only
    arrays that own their data (a model's surfaces, kept from frame to frame) cannot change and
    are not copied."""
    if job[0] != "frame":
        return job
    pieces = [(_kept(body_id) if np.ndim(body_id) else body_id, _kept(points), [(t, _kept(c)) for t, c in blocks],
               {n: _kept(v) for n, v in cdata.items()}, {n: _kept(v) for n, v in pdata.items()})
              for body_id, points, blocks, cdata, pdata in job[3]]
    return job[:3] + (pieces,) + job[4:]


def _kept(value):
    return value.copy() if isinstance(value, Deferred) else owned_array(value)


# read-only arrays at least this large are sent once and kept by the writer process
KEEP_BYTES = 16 << 10


class KeptArrays:
    """One side of the pipe's memory of large read-only arrays (a model's surfaces, handed over
    with every frame): the stepping side pickles such an array once, then only its number while
    the same array (the same object, read-only and owning its data, so unchanged) comes again in
    the next frame; the writer side keeps them by number. Each side forgets what a frame did not
    use, so both keep the same arrays, those of the last frame."""

    def __init__(self):
        self.kept: dict = {}            # stepping side: id -> (weak reference, number); writer: number -> array
        self.count = 0

    def dumps(self, job: tuple) -> bytes:
        """``job`` pickled (the stepping side); a frame's pieces (``job[3]``) with their kept
        arrays by number, pickled apart from the rest (the rows, thousands of small objects, go
        through the plain pickler: a Python hook called for each costs more than it saves)."""
        if job[0] != "frame":
            return pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL)
        buffer = io.BytesIO()
        pickler = pickle.Pickler(buffer, protocol=pickle.HIGHEST_PROTOCOL)
        used, sending = {}, set()

        def persistent_id(obj):
            if type(obj) is not np.ndarray or obj.flags.writeable or obj.base is not None \
                    or obj.nbytes < KEEP_BYTES or id(obj) in sending:
                return None
            known = used.get(id(obj)) or self.kept.get(id(obj))
            if known is not None and known[0]() is obj:
                used[id(obj)] = known
                return ("kept", known[1])
            sending.add(id(obj))        # pickled itself inside ("new", ...)
            self.count += 1
            used[id(obj)] = (weakref.ref(obj), self.count)
            return ("new", self.count, obj)

        pickler.persistent_id = persistent_id
        pickler.dump(job[3])
        payload = pickle.dumps(job[:3] + (buffer.getvalue(),) + job[4:], protocol=pickle.HIGHEST_PROTOCOL)
        self.kept = used
        return payload

    def loads(self, payload: bytes) -> tuple:
        """A job from :meth:`dumps` (the writer side)."""
        job = pickle.loads(payload)
        if job[0] != "frame":
            return job
        unpickler = pickle.Unpickler(io.BytesIO(job[3]))
        used = {}

        def persistent_load(pid):
            array = used.get(pid[1], self.kept.get(pid[1])) if pid[0] == "kept" else pid[2]
            used[pid[1]] = array
            return array

        unpickler.persistent_load = persistent_load
        pieces = unpickler.load()
        self.kept = used
        return job[:3] + (pieces,) + job[4:]
