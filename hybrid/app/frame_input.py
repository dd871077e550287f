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
    if job[0] == "values":
        return job[:4] + ([_kept(v) for v in job[4]],) + job[5:]
    if job[0] != "frame":
        return job
    pieces = [(_kept(body_id) if np.ndim(body_id) else body_id, _kept(points), [(t, _kept(c)) for t, c in blocks],
               {n: _kept(v) for n, v in cdata.items()}, {n: _kept(v) for n, v in pdata.items()})
              for body_id, points, blocks, cdata, pdata in job[3]]
    return job[:3] + (pieces,) + job[4:]


def _kept(value):
    return value.copy() if isinstance(value, Deferred) else owned_array(value)


# read-only arrays at least this large are sent once and kept by the writer process
KEEP_BYTES = 4 << 10


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
        """``job`` pickled (the stepping side), a frame's kept arrays by number: the pickler's
        hook sees the objects that are not plain Python data (arrays, their wrappers), not each
        of the rows' thousands of numbers. Other jobs hold no kept arrays (a ``values`` job's
        arrays are those that change) and go by the plain pickler, without the hook."""
        if job[0] == "values":          # its arrays as bytes: half the time numpy's pickling takes
            job = (*job[:4], [(a.dtype.str, a.shape, a.tobytes()) for a in job[4]], *job[5:])
        if job[0] != "frame":
            return pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL)
        buffer = io.BytesIO()
        pickler = _KeepingPickler(buffer, self)
        pickler.dump(job)
        self.kept = pickler.used
        return buffer.getvalue()

    def loads(self, payload: bytes) -> tuple:
        """A job from :meth:`dumps` (the writer side)."""
        reader = _KeptReader(io.BytesIO(payload), self.kept)
        job = reader.load()
        if job[0] == "frame":
            self.kept = reader.used
        elif job[0] == "values":
            job = (*job[:4], [np.frombuffer(raw, dtype).reshape(shape) for dtype, shape, raw in job[4]], *job[5:])
        return job


class _KeepingPickler(pickle.Pickler):
    """The stepping side's pickler: a large read-only array the writer keeps goes as its number
    (``keeping``: the :class:`KeptArrays`), a new one with its number; ``used`` holds the arrays
    this job named (id -> (weak reference, number))."""

    def __init__(self, file, keeping):
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self.keeping, self.used, self.sending = keeping, {}, set()

    def reducer_override(self, obj):
        if type(obj) is not np.ndarray or obj.flags.writeable or obj.base is not None \
                or obj.nbytes < KEEP_BYTES or id(obj) in self.sending:
            return NotImplemented
        known = self.used.get(id(obj)) or self.keeping.kept.get(id(obj))
        if known is not None and known[0]() is obj:
            self.used[id(obj)] = known
            return _kept_array, (known[1],)
        self.sending.add(id(obj))        # pickled itself as _new_kept_array's argument
        self.keeping.count += 1
        self.used[id(obj)] = (weakref.ref(obj), self.keeping.count)
        return _new_kept_array, (self.keeping.count, obj)


def _kept_array(number):
    """Stands in a pickle for array ``number`` the writer keeps (:class:`_KeptReader` reads it)."""
    raise RuntimeError("a kept array is read by KeptArrays.loads")


def _new_kept_array(number, array):
    """Stands in a pickle for ``array``, to be kept as ``number`` (:class:`_KeptReader`)."""
    raise RuntimeError("a kept array is read by KeptArrays.loads")


class _KeptReader(pickle.Unpickler):
    """The writer side's unpickler: the kept arrays a frame names are looked up in ``kept``,
    new ones kept; ``used`` holds those the frame used (the writer keeps those only)."""

    def __init__(self, file, kept):
        super().__init__(file)
        self.kept, self.used = kept, {}

    def find_class(self, module, name):
        if module == __name__ and name == "_kept_array":
            return self._kept
        if module == __name__ and name == "_new_kept_array":
            return self._new
        return super().find_class(module, name)

    def _kept(self, number):
        array = self.used[number] = self.used.get(number, self.kept.get(number))
        return array

    def _new(self, number, array):
        self.used[number] = array
        return array
