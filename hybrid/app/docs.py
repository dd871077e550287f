"""Regenerate the scene-file reference in docs/scene_reference.md and in README.md.

    python -m hybrid.app.docs          # rewrite both from the schema in hybrid/app/scene.py
    python -m hybrid.app.docs --check  # exit 1 if either is out of date
"""
import sys
from pathlib import Path

from .scene import reference_markdown

START, END = "<!-- scene-reference:start -->", "<!-- scene-reference:end -->"
ROOT = Path(__file__).resolve().parents[2]


def readme_with_reference(readme_text):
    """README text with the generated reference between the markers (headings demoted one level)."""
    body = reference_markdown().replace("\n## ", "\n### ").replace("\n# ", "\n### ")
    body = "\n".join(line for line in body.splitlines() if not line.startswith("# Scene file reference"))
    head, rest = readme_text.split(START, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{START}\n{body.strip()}\n{END}{tail}"


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    readme, reference = ROOT / "README.md", ROOT / "docs" / "scene_reference.md"
    want_readme = readme_with_reference(readme.read_text())
    want_reference = reference_markdown()
    if "--check" in argv:
        stale = [p.name for p, want in ((readme, want_readme), (reference, want_reference))
                 if p.read_text() != want]
        if stale:
            print(f"out of date: {', '.join(stale)}; run python -m hybrid.app.docs", file=sys.stderr)
            return 1
        return 0
    readme.write_text(want_readme)
    reference.write_text(want_reference)
    return 0


if __name__ == "__main__":
    sys.exit(main())
