"""The documentation stays true: the scene reference is the one the schema generates, README.md
stays a short user's page, and its links into docs/ lead somewhere."""
import re
from pathlib import Path

from hybrid.app.docs import main

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def test_scene_reference_matches_the_scene_schema():
    assert main(["--check"]) == 0, "run: python -m hybrid.app.docs"


def test_readme_stays_under_12_kb():
    size = len(README.read_bytes())
    assert size < 12 * 1024, f"README.md is {size} bytes; move depth into docs/"


def test_every_docs_link_in_the_readme_points_to_an_existing_file():
    targets = re.findall(r"\]\((docs/[^)#\s]+)", README.read_text())
    assert targets, "README.md links no page of docs/"
    missing = sorted({t for t in targets if not (ROOT / t).is_file()})
    assert not missing, f"README.md links missing files: {missing}"
