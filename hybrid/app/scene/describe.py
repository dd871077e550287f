"""Describing fields in words: values as TOML, allowed ranges and defaults, for error messages
and the reference docs alike."""
from .schema import REQUIRED


def printable(text):
    """``text`` with the characters a terminal would not show as themselves (control characters,
    line breaks) escaped as TOML escapes them (``\\u000A``): one problem stays on one line."""
    return "".join(c if c.isprintable() else f"\\u{ord(c):04X}" if ord(c) < 0x10000 else f"\\U{ord(c):08X}"
                   for c in text)


def toml_text(value):
    """A value as it would be written in TOML (strings escaped, on one line)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + printable(value.replace("\\", "\\\\").replace('"', '\\"')) + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_text(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{printable(str(k))} = {toml_text(v)}" for k, v in value.items()) + " }"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def range_text(f):
    """The numeric range of field ``f`` in words ('> 0', 'in [0, 1)', '<= 5'); '' if unbounded."""
    low = None if f.low is None else f"{f.low:g}"
    high = None if f.high is None else f"{f.high:g}"
    if low is not None and high is not None:
        return f"in {'(' if f.low_open else '['}{low}, {high}{')' if f.high_open else ']'}"
    if low is not None:
        return f"{'>' if f.low_open else '>='} {low}"
    if high is not None:
        return f"{'<' if f.high_open else '<='} {high}"
    return ""


def allowed_text(f):
    """Allowed values in a few words: '> 0', 'in [0, 1]', '"rigid", "fem"', 'non-zero'."""
    if f.kind == "choice":
        return ", ".join(toml_text(c) for c in f.choices)
    parts = [range_text(f)] if range_text(f) else []
    if f.kind == "vector" and parts:
        parts = [f"each {parts[0]}"]
    if f.nonzero:
        parts.append("non-zero")
    if f.kind == "quaternion":
        parts.append("unit norm")
    if f.kind == "box":
        parts.append("min <= max on each axis")
    return ", ".join(parts)


def describe(f):
    """What a field must be, for error messages: 'a number > 0', 'one of "rigid", "fem"'."""
    span = range_text(f)
    span = f" {span}" if span else ""
    if f.kind == "number":
        return f"a number{span}"
    if f.kind == "integer":
        return f"an integer{span}"
    if f.kind == "string":
        return "a non-empty string"
    if f.kind == "boolean":
        return "true or false"
    if f.kind == "vector":
        return f"a {'non-zero ' if f.nonzero else ''}list of 3 numbers{span}"
    if f.kind == "quaternion":
        return "a unit quaternion [w, x, y, z]"
    if f.kind == "box":
        return "a box [[xmin, ymin, zmin], [xmax, ymax, zmax]] with min <= max on each axis"
    if f.kind == "choice":
        return "one of " + ", ".join(toml_text(c) for c in f.choices)
    if f.kind == "path":
        return "a file path string"
    return "a table" if f.kind == "table" else "an array of tables"


TYPE_NAMES = {"number": "number", "integer": "integer", "string": "string", "boolean": "boolean",
               "vector": "3 numbers", "quaternion": "4 numbers", "box": "2 x 3 numbers",
               "choice": "choice", "path": "path", "table": "table", "tables": "array of tables"}


def default_text(f):
    """The default of field ``f`` as the reference shows it: its ``default_text`` if set,
    'required', 'none' for an empty array of tables, else the value as TOML."""
    if f.default_text is not None:
        return f.default_text
    if f.default is REQUIRED:
        return "required"
    if f.kind == "tables" and f.default == ():
        return "none"
    if isinstance(f.default, float):
        return f"{f.default:g}"
    if isinstance(f.default, tuple):
        return "[" + ", ".join(f"{c:g}" for c in f.default) + "]"
    return toml_text(f.default)
