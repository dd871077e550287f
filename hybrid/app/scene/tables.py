"""Reading one TOML table against its schema section: unknown keys, required keys, types and
ranges, every problem recorded with where it is."""
import difflib
import math
from pathlib import Path

from .describe import describe, printable, toml_text
from .schema import INVALID, QUATERNION_TOLERANCE, REQUIRED


class Where:
    """Where a problem is: the file, a table label such as ``[bodies] "box" (bodies[2])`` and a
    prefix for fields of inline tables (``shape.``)."""

    def __init__(self, source, label, prefix=""):
        self.source, self.label, self.prefix = source, label, prefix

    def nested(self, name):
        """The place of the fields of inline table ``name`` within this one (prefix ``name.``)."""
        return Where(self.source, self.label, f"{self.prefix}{name}.")

    def general(self, text):
        """A problem message about the table as a whole: ``<source>: <label>: <text>``."""
        return f"{self.source}: {self.label}: {text}"

    def problem(self, name, text):
        """A problem message about field ``name`` of the table (with its inline-table prefix)."""
        return self.general(f"field '{self.prefix}{name}' {text}")


def table_entries(value, name, source, problems, where=None):
    """The tables of an array of tables; non-tables are reported and skipped."""
    if value is None or value is INVALID:
        return []
    where = where or Where(source, "top level")
    if isinstance(value, dict):
        problems.append(where.problem(name, f"must be an array of tables ([[{name}]]), got a single table"))
        return []
    if not isinstance(value, (list, tuple)):
        problems.append(where.problem(name, f"must be an array of tables ([[{name}]]), got {toml_text(value)}"))
        return []
    good = []
    for i, entry in enumerate(value):
        if isinstance(entry, dict):
            good.append(entry)
        else:
            problems.append(where.problem(f"{name}[{i}]", f"must be a table, got {toml_text(entry)}"))
    return good


def read_table(table, section, where, problems, base_dir=None, only=None):
    """Check ``table`` against ``section``: unknown keys, required keys, types and ranges.

    Returns {field name: value} with defaults filled in and INVALID for fields that failed.
    Nested tables are returned unchecked (or None when absent) for the caller to read.
    ``only`` restricts the fields read (unknown keys are still judged against all of the section).
    """
    fields = section.fields if only is None else only
    allowed = section.names()
    if not isinstance(table, dict):
        problems.append(where.general(f"must be a table, got {toml_text(table)}"))
        table = {}
    for key in table:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), allowed, n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            problems.append(where.general(f"unknown key '{where.prefix}{printable(str(key))}'{hint}; allowed: "
                                          + ", ".join(allowed)))
    values = {}
    for f in fields:
        if f.name not in table:
            if f.default is REQUIRED:
                problems.append(where.problem(f.name, f"is required: {describe(f)}"))
                values[f.name] = INVALID
            else:
                values[f.name] = f.default
        elif f.kind == "table":
            value = table[f.name]
            if not isinstance(value, dict):
                problems.append(where.problem(f.name, f"must be a table, got {toml_text(value)}"))
                value = INVALID
            values[f.name] = value
        elif f.kind == "tables":
            values[f.name] = table[f.name]
        else:
            values[f.name] = _convert(f, table[f.name], where, problems, base_dir)
    return values


def _convert(f, value, where, problems, base_dir):
    """The checked Python value of one scalar/vector field, or INVALID after recording a problem."""
    try:
        return _CONVERTERS[f.kind](f, value, base_dir)
    except _Bad as bad:
        problems.append(where.problem(f.name, f"must be {describe(f)}, got {toml_text(value)}{bad.note}"))
        return INVALID


class _Bad(Exception):
    """A value that does not fit its field; ``note`` is appended to the message."""

    def __init__(self, note=""):
        self.note = note


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _in_range(f, x):
    if f.low is not None and (x < f.low or (f.low_open and x == f.low)):
        return False
    if f.high is not None and (x > f.high or (f.high_open and x == f.high)):
        return False
    return True


def _number(f, value, _):
    if not _is_number(value) or not _in_range(f, value):
        raise _Bad()
    return float(value)


def _integer(f, value, _):
    if not isinstance(value, int) or isinstance(value, bool) or not _in_range(f, value):
        raise _Bad()
    return value


def _string(f, value, _):
    if not isinstance(value, str) or not value.strip():
        raise _Bad()
    return value


def _boolean(f, value, _):
    if not isinstance(value, bool):
        raise _Bad()
    return value


def _numbers(value, count):
    if not isinstance(value, list) or len(value) != count or not all(_is_number(c) for c in value):
        raise _Bad()
    return tuple(float(c) for c in value)


def _vector(f, value, _):
    vector = _numbers(value, 3)
    if not all(_in_range(f, c) for c in vector) or (f.nonzero and not any(vector)):
        raise _Bad()
    return vector


def _quaternion(f, value, _):
    q = _numbers(value, 4)
    norm = math.sqrt(sum(c * c for c in q))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise _Bad(f" with norm {norm:.9g} (allowed: within {QUATERNION_TOLERANCE:g} of 1)")
    return tuple(c / norm for c in q)


def _box(f, value, _):
    if not isinstance(value, list) or len(value) != 2:
        raise _Bad()
    low, high = _numbers(value[0], 3), _numbers(value[1], 3)
    if any(a > b for a, b in zip(low, high)):
        raise _Bad()
    return low, high


def _choice(f, value, _):
    if not any(value == c and type(value) is type(c) for c in f.choices):
        raise _Bad()
    return value


def _path(f, value, base_dir):
    if not isinstance(value, str) or not value.strip():
        raise _Bad()
    if "\0" in value:          # no file system takes one (os calls raise ValueError)
        raise _Bad(" (a path cannot contain a NUL character)")
    path = Path(value).expanduser()
    return path if path.is_absolute() else (Path(base_dir or ".") / path).resolve()


_CONVERTERS = {"number": _number, "integer": _integer, "string": _string, "boolean": _boolean,
               "vector": _vector, "quaternion": _quaternion, "box": _box, "choice": _choice, "path": _path}


def valid(*values):
    """Whether every value was read successfully (none is INVALID or missing), so checks that
    combine fields may run."""
    return all(v is not INVALID and v is not None for v in values)
