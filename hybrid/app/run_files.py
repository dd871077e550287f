"""The files of a run folder (their names, the CSV tables' columns) and how to read a run back
(:func:`read_run`, used by rendering, studies and tests); :mod:`hybrid.app.output` writes them."""
from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any, Mapping

BODY_COLUMNS = (
    "time", "body", "x", "y", "z", "qw", "qx", "qy", "qz",
    "vx", "vy", "vz", "wx", "wy", "wz", "kinetic_energy", "model",
)
REGION_COLUMNS = ("time", "body", "region", "fx", "fy", "fz", "ux", "uy", "uz")

FRAME_PATTERN = re.compile(r"^frame_\d{5,}\.vtu$")
BODIES_CSV = "bodies.csv"
REGIONS_CSV = "regions.csv"
SUMMARY_JSON = "summary.json"


def find_pvd(run_dir: Path | str, summary: Mapping[str, Any] | None = None) -> Path:
    """The run's ``.pvd`` index (the scene's own if several are present, else the newest)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError("it is a file" if run_dir.exists() else "there is no such folder")
    candidates = sorted(run_dir.glob("*.pvd"))
    if not candidates:
        raise FileNotFoundError(f"no .pvd index in {run_dir} (is it a run directory?)")
    if len(candidates) == 1:
        return candidates[0]
    scene = (summary or {}).get("scene")
    name = scene.get("name") if isinstance(scene, Mapping) else None
    for c in candidates:
        if name and c.stem == name:
            return c
    return max(candidates, key=lambda c: c.stat().st_mtime)      # the latest run's


def read_summary(run_dir: Path | str) -> dict | None:
    """``summary.json`` of a run, or None when the run did not finish."""
    path = Path(run_dir) / SUMMARY_JSON
    if not path.exists():
        return None
    return json.loads(path.read_text(encoding="utf-8"))


def read_run(run_dir: Path | str) -> tuple[list[float], list[Path], dict | None]:
    """Read a run directory: (frame times in s, frame file paths, summary dict or None)."""
    run_dir = Path(run_dir)
    summary = read_summary(run_dir)
    pvd = find_pvd(run_dir, summary)
    root = ET.parse(pvd).getroot()
    times, paths = [], []
    for dataset in root.iter("DataSet"):
        times.append(float(dataset.get("timestep", "0")))
        paths.append(pvd.parent / dataset.get("file"))
    return times, paths, summary
