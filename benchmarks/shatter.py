"""Shatter scene (steel ball at 20 m/s through a brittle plate): wall time split into stepping,
fracture checks and rebuilding/refactorising after splits, at two mesh resolutions.

Prints a table and writes outputs/bench_shatter.csv. Run:
    OPENBLAS_NUM_THREADS=1 python benchmarks/shatter.py [duration_s]
"""
import csv
import os
import sys
import time
import tomllib
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from hybrid.app.build import build  # noqa: E402
from hybrid.coupling.events import apply_fracture  # noqa: E402
from hybrid.app.scene import parse_scene  # noqa: E402
from hybrid.coupling.step import step  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "tests" / "test_fracture_structures.py"


def shatter_scene(resolution):
    """The shatter scene of tests/test_fracture_structures.py at plate ``resolution`` (m)."""
    namespace = {}
    exec(compile(SCENE.read_text().split("def build_scene")[0], str(SCENE), "exec"), namespace)
    text = namespace["SHATTER"].replace("resolution = 0.04", f"resolution = {resolution}")
    return parse_scene(tomllib.loads(text), "shatter", Path("."))


def measure(resolution, duration):
    model, state = build(shatter_scene(resolution))
    tets = model.fem[0].tet_count
    timings = {}
    stepping = 0.0
    events = []
    for _ in range(int(round(duration / model.dt))):
        t0 = time.perf_counter()
        state = step(model, state)
        stepping += time.perf_counter() - t0
        model, state, new = apply_fracture(model, state, timings)
        events += new
    return {"resolution_m": resolution, "plate_tets": tets, "steps": state.steps,
            "step_s": stepping, "fracture_check_s": timings["fracture_check"],
            "rebuild_s": timings["fracture_rebuild"], "crack_events": len(events),
            "split_events": sum(bool(e.new_bodies) for e in events),
            "fem_bodies": len(model.fem), "rigid_fragments": model.rigid.body_count - 3}


def main():
    duration = float(sys.argv[1]) if len(sys.argv) > 1 else 0.3
    rows = [measure(r, duration) for r in (0.04, 0.025)]
    keys = list(rows[0])
    print(" ".join(f"{k:>16}" for k in keys))
    for row in rows:
        print(" ".join(f"{v:>16.4g}" if isinstance(v, float) else f"{v:>16}" for v in row.values()))
    os.makedirs("outputs", exist_ok=True)
    with open("outputs/bench_shatter.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)


if __name__ == "__main__":
    main()
