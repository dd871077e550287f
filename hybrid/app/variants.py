"""Variants of one scene: ``--set KEY=V1,V2`` settings, the grid (or zip) of them, and each
variant written back as a scene file of its own.

A KEY addresses a field of the scene file by its path: ``simulation.dt``,
``simulation.solver.iterations``, ``bodies.<name>.<field>`` (``bodies.plate.yield_stress``),
``bodies.<name>.shape.resolution``, ``bodies.<name>.anchors.<k>.velocity`` (the k-th anchor,
from 0), ``planes.<k>.friction``. Values are TOML values (``1e-3``, ``true``, ``"corotated"``;
a bare word is a string) separated by commas; a vector is written ``[0, 0, 1]`` or with
semicolons, ``0;0;1``. Every variant is validated (the scene loader's checks) before any runs.
"""
import copy
import hashlib
import itertools
import json
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from .scene import SceneError, parse_scene


class SettingError(ValueError):
    """A ``--set`` that cannot be applied: the message names the key and what is allowed."""


@dataclass(frozen=True)
class Variant:
    """One scene of a study. id: its folder name under ``runs/``. settings: ``{key: value}`` it
    was made with (in ``--set`` order). data: the scene's TOML data with those settings applied
    and mesh paths made absolute. file_name: the scene file's name (the original's)."""
    id: str
    settings: dict
    data: dict
    file_name: str

    def text(self):
        """The variant's scene file (TOML text), opening with a comment line per mesh file it
        reads giving the file's SHA-256: a study run again reruns the variants whose meshes
        changed, as it does those whose scene text did (:func:`hybrid.app.study.finished`)."""
        return "".join(f"# {path}: sha256 {_file_digest(path)}\n" for path in _mesh_paths(self.data)) \
            + toml_text(self.data)


def _mesh_paths(data):
    """The mesh files ``data``'s bodies read (absolute paths, in body order)."""
    bodies = data.get("bodies") if isinstance(data.get("bodies"), list) else []
    return [b["mesh"] for b in bodies if isinstance(b, dict) and isinstance(b.get("mesh"), str)]


def _file_digest(path):
    """SHA-256 of the file at ``path`` (hex), or ``missing``."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return "missing"


def split_values(text):
    """``"1,2,[0,0,1]"`` -> ``["1", "2", "[0,0,1]"]``: commas outside brackets and quotes."""
    out, depth, quote, start = [], 0, None, 0
    for i, ch in enumerate(text):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(text[start:i].strip())
            start = i + 1
    out.append(text[start:].strip())
    return out


def parse_value(text):
    """One ``--set`` value: a TOML value, else ``;``-separated components of a vector, else the
    bare text as a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        pass
    if ";" in text:
        return [parse_value(part.strip()) for part in text.split(";")]
    return text


def parse_setting(text):
    """``"KEY=V1,V2"`` -> ``(KEY, [v1, v2])``; SettingError when it has no ``=`` or no value."""
    key, sep, values = text.partition("=")
    key = key.strip()
    if not sep or not key or not values.strip():
        raise SettingError(f"--set {text}: give KEY=V1,V2,... (for example simulation.dt=1e-3,5e-4)")
    parts = split_values(values)
    if any(p == "" for p in parts):
        raise SettingError(f"--set {key}: empty value in '{values}'")
    return key, [parse_value(p) for p in parts]


def setting_pairs(settings):
    """``[(key, values)]`` of settings given as ``["KEY=V1,V2", ...]`` (:func:`parse_settings`) or
    from Python as ``{key: values}`` (a value alone or a list, tuple or numpy array of them; numpy
    numbers become Python ones, which the scene loader checks by type)."""
    if isinstance(settings, (list, tuple)):
        return parse_settings(settings)

    def plain(value):
        return value.tolist() if hasattr(value, "tolist") else value
    pairs = []
    for key, values in settings.items():
        values = plain(values)
        values = list(values) if isinstance(values, (list, tuple)) else [values]
        if not values:              # (the study ran nothing and returned an empty table)
            raise SettingError(f"{key}: no values given; give a value or a list of them")
        pairs.append((key, [plain(v) for v in values]))
    return pairs


def parse_settings(texts):
    """:func:`parse_setting` of each ``--set`` text; a KEY given twice is a SettingError (the later
    values would silently replace the earlier)."""
    pairs = [parse_setting(t) for t in texts]
    keys = [k for k, _ in pairs]
    for key in keys:
        if keys.count(key) > 1:
            raise SettingError(f"--set {key}: given more than once; give all its values in one "
                               f"--set {key}=V1,V2,...")
    return pairs


# the arrays of tables a key may index into (a body's anchors and loads, the planes)
LISTS = ("anchors", "loads", "planes", "bodies")


def _child(node, part, key, walked):
    """The table ``part`` names inside ``node`` (a table or a list of tables), created empty when
    it is a table the scene left out."""
    if isinstance(node, list):
        if walked == "bodies":
            named = [b for b in node if isinstance(b, dict) and b.get("name") == part]
            if not named:
                names = ", ".join(str(b.get("name")) for b in node if isinstance(b, dict))
                raise SettingError(f"--set {key}: no body '{part}'; bodies: {names}")
            return named[0]
        if not part.isdigit() or int(part) >= len(node):
            raise SettingError(f"--set {key}: '{walked}' has {len(node)} entries; give an index "
                               f"0 to {len(node) - 1} after it, got '{part}'")
        return node[int(part)]
    if part not in node:
        if part in LISTS:       # (an empty table there reads as "a single table, not an array")
            owner = f"'{walked}'" if walked else "the scene"
            raise SettingError(f"--set {key}: {owner} has no {part}: add them in the scene file")
        node[part] = {}
    if not isinstance(node[part], (dict, list)):
        raise SettingError(f"--set {key}: '{part}' is a value, not a table")
    return node[part]


def _body_name_joined(data, parts):
    """``parts`` of a key with a body's name that has dots in it (``bodies.ball.v2.density``) as
    one part: the longest name of a body of ``data`` the parts after ``bodies`` begin with."""
    bodies = data.get("bodies") if parts[0] == "bodies" else None
    if not isinstance(bodies, list):
        return parts
    names = {b.get("name") for b in bodies if isinstance(b, dict)}
    for end in range(len(parts) - 1, 2, -1):
        if ".".join(parts[1:end]) in names:
            return [parts[0], ".".join(parts[1:end]), *parts[end:]]
    return parts


def apply_setting(data, key, value):
    """Set the field ``key`` (a dotted path, see the module docs) of scene data ``data`` to
    ``value`` in place; SettingError naming the key when the path leads nowhere."""
    parts = key.split(".")
    if len(parts) < 2 or parts[0] not in ("simulation", "bodies", "planes"):
        raise SettingError(f"--set {key}: a key starts with simulation., bodies.<name>. or "
                           f"planes.<index>. and ends with a field name")
    parts = _body_name_joined(data, parts)
    node, walked = data, ""
    for part in parts[:-1]:
        node = _child(node, part, key, walked)
        walked = part
    if isinstance(node, list):
        raise SettingError(f"--set {key}: '{walked}' is a list of tables; name an entry and a field")
    node[parts[-1]] = copy.deepcopy(value)
    # a body has one of a shape or a mesh: setting one replaces the other
    if parts[0] == "bodies" and len(parts) == 3 and parts[-1] in ("mesh", "shape"):
        node.pop("shape" if parts[-1] == "mesh" else "mesh", None)


def combinations(settings, zipped=False):
    """The variants' settings: every combination of the values (``settings``: ``[(key,
    values)]``), or with ``zipped`` the i-th value of each key together (all lists equally
    long). A list of ``{key: value}``."""
    if not settings:
        return [{}]
    keys = [k for k, _ in settings]
    if zipped:
        lengths = {k: len(v) for k, v in settings}
        if len(set(lengths.values())) > 1:
            raise SettingError("--zip needs as many values for every --set key; got "
                               + ", ".join(f"{k}: {n}" for k, n in lengths.items()))
        rows = zip(*(v for _, v in settings))
    else:
        rows = itertools.product(*(v for _, v in settings))
    out = [dict(zip(keys, row)) for row in rows]
    # the same variant twice (0.3,0.30,3e-1) ran as one folder and gave identical rows
    for k, row in enumerate(out):
        if row in out[:k]:
            raise SettingError("the same variant is given more than once: "
                               + ", ".join(f"{key}={value!r}" for key, value in row.items()))
    return out


def _absolute_meshes(data, base_dir):
    """Mesh paths made absolute (resolved from the original scene's folder), so the variant's
    file loads from any folder."""
    for body in data.get("bodies", []) if isinstance(data.get("bodies"), list) else []:
        if isinstance(body, dict) and isinstance(body.get("mesh"), str):
            body["mesh"] = str((Path(base_dir) / body["mesh"]).resolve())


def _label(settings):
    """A short file-name-safe label of the settings (``dt=0.001_young=1e6``)."""
    text = "_".join(f"{k.rsplit('.', 1)[-1]}={_plain(v)}" for k, v in settings.items())
    return re.sub(r"[^A-Za-z0-9._=+-]", "-", text)[:60]


def _plain(value):
    """A value as the user would write it in ``--set`` (vectors with ``;``)."""
    if isinstance(value, list):
        return ";".join(_plain(v) for v in value)
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def make_variants(scene_path, rows):
    """Variants of the scene file ``scene_path``, one per ``{key: value}`` in ``rows``; each is
    validated. Raises SettingError for the keys that lead nowhere (each named), SceneError
    (problems prefixed with the variant's settings) for values the scene loader rejects."""
    scene_path = Path(scene_path)
    try:
        base = tomllib.loads(scene_path.read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as error:
        raise SceneError([f"{scene_path}: cannot read scene file ({error})"]) from None
    variants, problems, bad_keys = [], [], {}
    for settings in rows:
        data = copy.deepcopy(base)
        for key, value in settings.items():
            try:
                apply_setting(data, key, value)
            except SettingError as error:   # every key that leads nowhere is told, once
                bad_keys.setdefault(str(error), None)
        if bad_keys:
            continue
        _absolute_meshes(data, scene_path.parent)
        digest = hashlib.sha1(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()[:6]
        # named by what it is, not where it stands: a study run again with one more value keeps
        # the runs it had (numbered by position, every run after the new value ran again)
        label = _label(settings)
        variant_id = f"{label}_{digest}" if label else digest
        try:
            parse_scene(data, str(scene_path), scene_path.parent)
        except SceneError as error:
            where = ", ".join(f"{k}={_plain(v)}" for k, v in settings.items()) or "the scene"
            problems += [f"--set {where}: {p}" for p in error.problems]
        variants.append(Variant(variant_id, dict(settings), data, scene_path.name))
    if bad_keys:
        raise SettingError("; ".join(bad_keys))
    if problems:
        raise SceneError(problems)
    return variants


# ------------------------------------------------------------------------------ writing TOML
def _toml_scalar(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)          # round-trips exactly: a variant runs with the same numbers
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_scalar(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_scalar(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def _toml_key(key):
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _toml_string(key)


def _toml_string(text):
    """A TOML basic string: JSON's escapes for quotes, backslashes and control characters (TOML
    takes them), the rest as it is (JSON's ASCII escapes write a character past U+FFFF as two
    surrogate halves, which TOML refuses: a scene named with an emoji failed every variant), and
    DEL, which JSON leaves, escaped."""
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007F")


def toml_text(data):
    """Scene data as TOML text: top-level tables as ``[name]``, lists of tables as ``[[name]]``,
    anything nested inline. ``tomllib.loads(toml_text(d)) == d`` for the scene files' values."""
    lines = []
    tables = {k: v for k, v in data.items() if isinstance(v, dict)
              or (isinstance(v, list) and v and all(isinstance(e, dict) for e in v))}
    for key, value in data.items():
        if key not in tables:
            lines.append(f"{_toml_key(key)} = {_toml_scalar(value)}")
    for key, value in tables.items():
        for entry in [value] if isinstance(value, dict) else value:
            header = f"[{_toml_key(key)}]" if isinstance(value, dict) else f"[[{_toml_key(key)}]]"
            lines += ["", header] + [f"{_toml_key(k)} = {_toml_scalar(v)}" for k, v in entry.items()]
    return "\n".join(lines).lstrip("\n") + "\n"
