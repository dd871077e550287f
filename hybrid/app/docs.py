"""Regenerate the scene-file reference, docs/scene_reference.md, from the scene schema.

    python -m hybrid.app.docs          # rewrite it from the schema in hybrid/app/scene/
    python -m hybrid.app.docs --check  # exit 1 if it is out of date

README.md links the reference instead of embedding it, so this file is the only generated one.
"""
import sys
from pathlib import Path

from .scene import reference_markdown

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "docs" / "scene_reference.md"


def main(argv=None):
    """Rewrite docs/scene_reference.md, or with ``--check`` report whether it is in sync.
    Returns the exit code: 0, or 1 when ``--check`` finds it out of date."""
    argv = sys.argv[1:] if argv is None else argv
    want = reference_markdown()
    if "--check" in argv:
        if not REFERENCE.exists() or REFERENCE.read_text() != want:
            print(f"out of date: {REFERENCE.name}; run python -m hybrid.app.docs", file=sys.stderr)
            return 1
        return 0
    REFERENCE.write_text(want)
    return 0


if __name__ == "__main__":
    sys.exit(main())
