"""A scene back as the tables of a scene file, to check a scene changed in Python.

A scene changed with ``dataclasses.replace`` (docs/scenes.md) skips the checks a scene file gets:
a negative ``young`` stepped with a negative von Mises stress, a negative ``dt`` ran backwards.
:func:`rechecked` reads it back through :func:`hybrid.app.scene.parse.parse_scene`, so it is
refused as a scene file with the same values would be."""
from dataclasses import MISSING, fields, is_dataclass, replace
from pathlib import Path

import numpy as np

from .parse import SceneError, parse_scene
from .records import Scene


def scene_data(scene):
    """The TOML data (a dict of tables) that :func:`parse_scene` reads as ``scene``: the fields of
    its records not at their defaults, vectors and boxes as lists, paths as strings."""
    return {"simulation": _table(scene.simulation), "planes": [_table(p) for p in scene.planes],
            "bodies": [_table(b) for b in scene.bodies]}


def rechecked(scene):
    """``scene`` when its tables read back as a valid scene (SceneError naming every field a
    change made invalid), with its tables as ``raw`` (which ``summary.json`` shows) when it is
    no longer the scene its ``raw`` reads as (changed in Python). TypeError for what is no
    :class:`Scene`."""
    if not isinstance(scene, Scene):
        raise TypeError(f"a simulation is built from a scene file's path, a built-in scene's name "
                        f"or a parsed Scene (hybrid.app.scene.load_scene or parse_scene), not "
                        f"{type(scene).__name__}")
    source = str(scene.source_path)
    data = scene_data(scene)
    # read back as a file with these tables would be: mesh paths then lead where they were checked
    read = parse_scene(data, source, Path(source).parent)
    try:
        same = bool(parse_scene(scene.raw, source, Path(source).parent) == scene)
    except (SceneError, ValueError):        # (ValueError: numpy arrays put in a record)
        same = False
    return scene if same else replace(read, raw=data)


def _table(record):
    """A record's fields other than those at their defaults (a field given is judged against the
    body's model and shape: a rigid body may not name a deformable body's field)."""
    values = {f.name: _value(getattr(record, f.name)) for f in fields(record)}
    return {f.name: values[f.name] for f in fields(record)
            if values[f.name] is not None and values[f.name] != _value(_default(f))}


def _default(f):
    if f.default is not MISSING:
        return f.default
    return f.default_factory() if f.default_factory is not MISSING else MISSING


def _value(value):
    if is_dataclass(value):
        return _table(value)
    if isinstance(value, (tuple, list)):
        return [_value(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    return value
