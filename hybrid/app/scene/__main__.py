"""``python -m hybrid.app.scene`` prints the scene file reference (Markdown) to stdout."""
import sys

from .reference import reference_markdown

sys.stdout.write(reference_markdown())
