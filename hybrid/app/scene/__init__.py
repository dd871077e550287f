"""Scene files: a declarative schema, a loader that reports every problem, and the reference docs.

A scene is a TOML file (SI units throughout) with a ``[simulation]`` table, ``[[planes]]`` and
``[[bodies]]``. The schema (:mod:`.schema`) is data: one Section per table, one Field per key (type,
default, allowed values, unit, doc). The loader (:mod:`.parse`, :mod:`.tables`), the error messages
(:mod:`.describe`), the record docstrings (:mod:`.records`) and ``docs/scene_reference.md``
(:mod:`.reference`; ``python -m hybrid.app.scene > docs/scene_reference.md``) are all derived from
it, so they cannot drift apart. Nothing from a scene file is ever evaluated.

    scene = load_scene("scenes/drop.toml")     # raises SceneError listing every problem
"""
from .parse import SceneError, load_scene, parse_scene
from .records import (Anchor, Body, Damping, Load, Plane, Scene, Shape, Simulation, Solver,
                      Unbreakable)
from .reference import reference_markdown
from .schema import SCHEMA, Field, Section
from .validate import validate_command

__all__ = ["Anchor", "Body", "Damping", "Field", "Load", "Plane", "SCHEMA", "Scene", "SceneError",
           "Section", "Shape", "Simulation", "Solver", "Unbreakable", "load_scene", "parse_scene",
           "reference_markdown", "validate_command"]
