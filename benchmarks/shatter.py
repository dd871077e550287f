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

from hybrid import Simulation  # noqa: E402
from hybrid.app.scene import parse_scene  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "tests" / "scenes" / "shatter.toml"


def shatter_scene(resolution):
    """The shatter scene of tests/scenes/shatter.toml at plate ``resolution`` (m)."""
    text = SCENE.read_text().replace("resolution = 0.04", f"resolution = {resolution}")
    return parse_scene(tomllib.loads(text), "shatter", Path("."))


def measure(resolution, duration):
    sim = Simulation(shatter_scene(resolution))
    tets = sim.model.fem[0].tet_count
    t0 = time.perf_counter()
    for _ in range(int(round(duration / sim.dt))):
        sim.step()
    wall = time.perf_counter() - t0
    check, rebuild = sim.timings["fracture_check"], sim.timings["fracture_rebuild"]
    cracks = [e for e in sim.events if hasattr(e, "new_bodies")]
    return {"resolution_m": resolution, "plate_tets": tets, "steps": sim.steps,
            "step_s": wall - check - rebuild, "fracture_check_s": check,
            "rebuild_s": rebuild, "crack_events": len(cracks),
            "split_events": sum(bool(e.new_bodies) for e in cracks),
            "fem_bodies": len(sim.model.fem), "rigid_fragments": sim.model.rigid.body_count - 3}


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
