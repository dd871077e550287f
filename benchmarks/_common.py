"""Shared by the benchmark scripts: writing their result tables."""
import csv
from pathlib import Path


def write_csv(path, rows):
    """Write a list of dicts (same keys) as CSV, creating the folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
