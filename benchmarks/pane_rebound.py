"""Where the ball goes when it shatters a pane: sub-stepped, at a small step, on a finer mesh.

A glass pane (10 x 10 x 1 cm, E = 70 GPa, 5 MPa strength) held along two edges, struck at its
centre by a steel ball (1 cm radius) at 30 m/s in zero gravity (the scene of
tests/test_shattered_pane.py, tests/scenes/pane_struck.toml), run three ways one after the other:

- `dt` = 0.5 ms with `resolve_impacts` (the impact steps taken in sub-steps), 1 cm elements;
- `dt` = 10 us throughout, no sub-steps (the small-step run the first should match);
- `dt` = 0.5 ms with `resolve_impacts` on a mesh of 5 mm elements.

Prints, for each, the ball's velocity along the blow after `--duration` (default 3 ms; negative:
it went on through the pane, positive: it came back), the number of pieces and the wall time.

    OPENBLAS_NUM_THREADS=1 python benchmarks/pane_rebound.py [--duration 0.003]
"""
import argparse
import os
import time
import tomllib
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from hybrid import Simulation
from hybrid.app.scene import parse_scene

# the scene of tests/test_shattered_pane.py, its step, sub-stepping, mesh and duration set per way
SCENE = Path(__file__).resolve().parents[1] / "tests" / "scenes" / "pane_struck.toml"


def scene_text(dt, resolve, resolution, duration):
    """The pane scene with ``dt`` (s), ``resolve_impacts`` ("true"/"false"), the pane's
    ``resolution`` (m) and ``duration`` (s)."""
    text = SCENE.read_text()
    for old, new in (("dt = 5e-4", f"dt = {dt}"), ("resolve_impacts = true", f"resolve_impacts = {resolve}"),
                     ("resolution = 0.01", f"resolution = {resolution}"),
                     ("duration = 0.003", f"duration = {duration}")):
        assert old in text, old
        text = text.replace(old, new)
    return text

WAYS = (("sub-stepped, dt 0.5 ms, 1 cm elements", 5e-4, "true", 0.01),
        ("dt 10 us throughout, 1 cm elements", 1e-5, "false", 0.01),
        ("sub-stepped, dt 0.5 ms, 5 mm elements", 5e-4, "true", 0.005))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=0.003, help="simulated time (s)")
    args = parser.parse_args()
    print(f"{'way':40s} {'ball vz m/s':>12s} {'pieces':>7s} {'wall s':>7s}")
    for name, dt, resolve, resolution in WAYS:
        text = scene_text(dt, resolve, resolution, args.duration)
        sim = Simulation(parse_scene(tomllib.loads(text), f"<{name}>", Path(".")))
        start = time.perf_counter()
        for _ in range(int(round(args.duration / dt))):
            sim.step()
        wall = time.perf_counter() - start
        pieces = sum(1 for n in sim.model.names if n == "pane" or n.startswith("pane."))
        print(f"{name:40s} {sim.body('ball').velocity[2]:12.2f} {pieces:7d} {wall:7.1f}", flush=True)


if __name__ == "__main__":
    main()
