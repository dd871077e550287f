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
    if isinstance(name, str) and "\n" in name:
        shown = name.strip().splitlines()[0][:40] if name.strip() else ""
        raise KeyError(f"no built-in scene or scene file {shown!r}...: TOML text is not read "
                       f"as a scene; write it to a .toml file, or build Simulation("
                       f"hybrid.app.scene.parse_scene(tomllib.loads(text), name, folder))")
    if not isinstance(name, str) or "/" in name or "\\" in name or not _is_file(FOLDER / f"{name}.toml"):
        raise KeyError(f"no built-in scene {name!r}; built-in scenes: {', '.join(builtin_names())} "
                       f"(or give the path of a .toml file)")
    return FOLDER / f"{name}.toml"


def scene_path(path_or_name):
    """The scene file a user named: an existing file or anything that looks like one (a .toml
    file, a path with folders: the loader reports it if missing), else the built-in scene of that
    name (also when a folder has its name: ``hybrid run default --out default`` made one);
    KeyError naming the built-in scenes for a bare name that is neither."""
    if isinstance(path_or_name, str) and "\n" in path_or_name:
        return builtin_path(path_or_name)                   # TOML text: refused, saying so
    path = Path(path_or_name)
    if path.suffix == ".toml" or len(path.parts) > 1 or _is_file(path):
        return path
    if _exists(path):           # a folder of that name (a run's output, say) is no scene file
        try:
            return builtin_path(str(path_or_name))
        except KeyError:
            return path
    return builtin_path(str(path_or_name))


def _exists(path):
    try:
        return path.exists()
    except OSError:             # a name too long for a file
        return False


def _is_file(path):
    try:
        return path.is_file()
    except OSError:             # a name too long for a file
        return False


def builtin_summary(name):
    """The first line of built-in scene ``name``'s header comment (what the scene shows)."""
    for line in builtin_path(name).read_text(encoding="utf-8").splitlines():
        if not line.startswith("#"):
            break
        text = line.lstrip("#").strip()
        if text:
            return text
    return ""
