"""Scenes shipped with the package, run by name (``hybrid run dent``).

Each built-in scene is a TOML file in this folder whose header comment says what happens, what to
look at and which field to render; the first line of that comment is its summary.

    builtin_names()          # ['cantilever', 'default', 'dent', ...]
    builtin_path("dent")     # Path of dent.toml
    builtin_summary("dent")  # 'A steel ball dents an aluminium plate ...'
"""
from pathlib import Path

FOLDER = Path(__file__).resolve().parent


def builtin_names():
    """Names of the built-in scenes, sorted."""
    return sorted(path.stem for path in FOLDER.glob("*.toml"))


def builtin_path(name):
    """Path of the built-in scene ``name``; KeyError naming the built-in scenes if there is none."""
    path = FOLDER / f"{name}.toml"
    if not isinstance(name, str) or "/" in name or "\\" in name or not path.is_file():
        raise KeyError(f"no built-in scene {name!r}; built-in scenes: {', '.join(builtin_names())} "
                       f"(or give the path of a .toml file)")
    return path


def builtin_summary(name):
    """The first line of built-in scene ``name``'s header comment (what the scene shows)."""
    for line in builtin_path(name).read_text(encoding="utf-8").splitlines():
        if not line.startswith("#"):
            break
        text = line.lstrip("#").strip()
        if text:
            return text
    return ""
