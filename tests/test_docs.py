"""The scene reference in README.md and docs/ is the one the schema generates (docs never drift)."""
from hybrid.app.docs import main


def test_readme_and_reference_match_the_scene_schema():
    assert main(["--check"]) == 0, "run: python -m hybrid.app.docs"
