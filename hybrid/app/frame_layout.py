"""Frames that repeat the last frame's layout go to the writer as their values alone.

A run's frames mostly repeat one layout: the same bodies, cells and fields, with new positions
and field values. :func:`layout` reads a frame's pieces (:class:`hybrid.app.output.FramePiece`)
into a signature: the identity of the read-only arrays that own their data (a model's cells and
surfaces, which cannot change), the shape and type of the other arrays (the frame's values) and
every other item (names, numbers, the functions of deferred values). A frame whose signature is
the last one's passes the same checks (:func:`hybrid.app.frame_input.check_pieces` depends on
nothing else), so ``RunWriter.write_frame`` hands it over as ``("values", time, file name,
paths, values, ...)`` without checking it again (:class:`LastFrame`), and the writer puts the
values into the last frame's pieces (:func:`filled`).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .vtu import Deferred

# what an array must be to go as a value: the dtype the checks leave it with (points are
# float64; fields keep theirs, so any), so that the checks of the first frame hold for it
_POINTS, _FIELD = np.dtype(float), None


def layout(pieces) -> tuple[tuple, list, list, list]:
    """``(signature, values, paths, kept)`` of a frame's pieces: ``values`` the arrays that are
    not kept (writeable, or views), in order; ``paths`` where each sits in the checked pieces
    (see :func:`filled`); ``kept`` the read-only arrays the signature names by identity (hold
    them while the signature is compared: a freed array's id may be reused)."""
    values, paths, kept = [], [], []
    signature = []
    for i, p in enumerate(pieces):
        body = p.body_id
        if isinstance(body, (int, np.integer)):
            body_sig = (int(body),)
        else:
            body_sig = _item(body, (i, 0), None, values, paths, kept)
        cells = tuple((str(t), _item(c, None, None, values, paths, kept)) for t, c in p.cells)
        signature.append((body_sig, _item(p.points, (i, 1), _POINTS, values, paths, kept), cells,
                          tuple((n, _item(v, (i, 3, n), _FIELD, values, paths, kept))
                                for n, v in p.cell_data.items()),
                          tuple((n, _item(v, (i, 4, n), _FIELD, values, paths, kept))
                                for n, v in p.point_data.items())))
    return tuple(signature), values, paths, kept


def _item(value, path, dtype, values, paths, kept):
    """The signature of one item; a value (with its ``path``; None: never a value, as cells
    are not) appended to ``values``."""
    if isinstance(value, np.ndarray):
        if value.base is None and not value.flags.writeable:
            kept.append(value)
            return ("kept", id(value))
        if path is None or value.ndim == 0 or (dtype is not None and value.dtype != dtype):
            return (object(),)                  # (never repeats: the frame is checked)
        values.append(value)
        paths.append(path)
        return ("value", value.shape, value.dtype.str)
    if isinstance(value, Deferred) and path is not None:
        args = value.argument if isinstance(value.argument, tuple) else (value.argument,)
        return ("deferred", value.function, value.trailing, value.rows, isinstance(value.argument, tuple),
                tuple(_item(a, path + (k,), None, values, paths, kept) for k, a in enumerate(args)))
    if isinstance(value, (int, float, str, np.generic)):
        return (type(value), value)
    return (object(),)


def filled(pieces: list, paths: list, values: list) -> list:
    """The checked ``pieces`` (``(body id, points, blocks, cell data, point data)``) of the
    frame before, with ``values`` put at ``paths``: ``(i, 0)`` piece i's body ids, ``(i, 1)`` its
    points, ``(i, 3, name)`` / ``(i, 4, name)`` a cell / point field, each followed by ``k``
    for argument k of a deferred value. The pieces given are not changed."""
    out = [[body, points, blocks, dict(cdata), dict(pdata)] for body, points, blocks, cdata, pdata in pieces]
    for path, value in zip(paths, values):
        i, part, *rest = path
        holder, key = (out[i], part) if part < 3 else (out[i][part], rest.pop(0))
        if rest:                                # argument k of a deferred value
            deferred, k = holder[key], rest[0]
            if isinstance(deferred.argument, tuple):
                argument = deferred.argument[:k] + (value,) + deferred.argument[k + 1:]
            else:
                argument = value
            value = replace(deferred, argument=argument)
        holder[key] = value
    return [tuple(p) for p in out]


class LastFrame:
    """The stepping side's memory of the last full frame handed over: its signature, its checked
    pieces and fields, and the writer that has them (a writer that takes over mid-run has not)."""

    def __init__(self):
        self.signature = self.frame = self.writer = None
        self.kept: list = []
        self._next = None

    def repeat(self, pieces) -> tuple[list, list] | None:
        """``(paths, values)`` of ``pieces`` when they repeat the last frame's layout, else None
        (their signature is then taken by :meth:`handed` with their full frame)."""
        signature, values, paths, kept = layout(pieces)
        if self.signature is not None and signature == self.signature:
            return paths, values
        self._next = (signature, kept)
        return None

    def handed(self, job: tuple, writer) -> tuple:
        """``job`` (``frame`` or ``values``) as ``writer`` takes it: a values job for a writer
        that does not have the last frame becomes that frame, filled."""
        if job[0] == "frame":
            (self.signature, self.kept), self._next = self._next, None
            self.frame, self.writer = job[3:6], writer
        elif job[0] == "restore":               # (files taken back: the next frame goes whole)
            self.writer = None
        elif job[0] == "values" and writer is not self.writer:
            pieces, cell_fields, point_fields = self.frame
            job = ("frame", *job[1:3], filled(pieces, *job[3:5]), cell_fields, point_fields, *job[5:])
            self.frame, self.writer = job[3:6], writer
        return job
