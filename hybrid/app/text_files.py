"""Plain-text files of a run: JSON-ready values, CSV rows at full precision, atomic writes and
whole appends.

Used by :mod:`hybrid.app.output` for ``summary.json``, ``bodies.csv``, ``regions.csv`` and the
``.pvd`` index.
"""
from __future__ import annotations

import csv
import io
import math
import os
import threading
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np


def plain(value: Any) -> Any:
    """Convert numpy scalars/arrays, tuples and paths to JSON-ready Python values.

    Non-finite floats become None so that the file is strict JSON.
    """
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, (list, tuple, set, frozenset)):
        return [plain(v) for v in value]
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


def csv_value(value: Any) -> Any:
    """Python value for the csv module: ints exact, floats at full precision (repr)."""
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return value


def check_rows(rows: Iterable[Any], columns: Sequence[str]) -> list[tuple]:
    """Rows as tuples in ``columns`` order (dicts must have exactly ``columns``; ValueError)."""
    out = []
    for row in rows:
        if type(row) is not tuple and isinstance(row, Mapping):      # (an ABC check: 1 us a row)
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


def csv_rows(rows: Iterable[Any], columns: Sequence[str]) -> str:
    """Format rows (tuples in column order, or dicts with exactly ``columns``) as CSV text."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    for values in check_rows(rows, columns):
        # Python floats, ints and strings go as they are (the csv module writes a float as its
        # repr): most of a table's values, and a call each cost 20 ms a frame of 1,000 bodies
        writer.writerow([v if type(v) in _AS_THEY_ARE else csv_value(v) for v in values])
    return buffer.getvalue()


_AS_THEY_ARE = frozenset((float, int, str))


def temporary_path(path: Path) -> Path:
    """Where ``path`` is written before it is renamed into place: a hidden file beside it, named
    after this process and thread (mkstemp's random names cost a third of a millisecond each)."""
    return path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same folder and a rename, so the
    file on disk is always whole (the old one or the new one)."""
    tmp = temporary_path(path)
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def append_whole(f, data: bytes) -> None:
    """Append ``data`` to the unbuffered binary file ``f``, all of it or none: a write that fails
    part way (a full disk) is cut back off before the error is raised."""
    start = f.tell()
    view = memoryview(data)
    try:
        while view:
            view = view[f.write(view) or 0:]
    except BaseException:
        f.truncate(start)
        raise
