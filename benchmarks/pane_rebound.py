"""Where the ball goes when it shatters a pane: sub-stepped, at a small step, on a finer mesh.

A glass pane (10 x 10 x 1 cm, E = 70 GPa, 5 MPa strength) held along two edges, struck at its
centre by a steel ball (1 cm radius) at 30 m/s in zero gravity (the scene of
tests/test_shattered_pane.py), run three ways one after the other:

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

SCENE = """
[simulation]
duration = {duration}
dt = {dt}
resolve_impacts = {resolve}
gravity = [0.0, 0.0, 0.0]
[[bodies]]
name = "pane"
model = "fem"
shape = {{ type = "box", size = [0.1, 0.1, 0.01], resolution = {resolution} }}
density = 2500.0
young = 70e9
poisson = 0.22
fracture_stress = 5e6
[[bodies.anchors]]
box = [[-0.06, -0.06, -0.01], [-0.0499, 0.06, 0.01]]
[[bodies.anchors]]
box = [[0.0499, -0.06, -0.01], [0.06, 0.06, 0.01]]
[[bodies]]
name = "ball"
shape = {{ type = "sphere", radius = 0.01 }}
density = 7800.0
position = [0.0, 0.0, 0.0151]
velocity = [0.0, 0.0, -30.0]
"""

WAYS = (("sub-stepped, dt 0.5 ms, 1 cm elements", 5e-4, "true", 0.01),
        ("dt 10 us throughout, 1 cm elements", 1e-5, "false", 0.01),
        ("sub-stepped, dt 0.5 ms, 5 mm elements", 5e-4, "true", 0.005))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=0.003, help="simulated time (s)")
    args = parser.parse_args()
    print(f"{'way':40s} {'ball vz m/s':>12s} {'pieces':>7s} {'wall s':>7s}")
    for name, dt, resolve, resolution in WAYS:
        text = SCENE.format(duration=args.duration, dt=dt, resolve=resolve, resolution=resolution)
        sim = Simulation(parse_scene(tomllib.loads(text), f"<{name}>", Path(".")))
        start = time.perf_counter()
        for _ in range(int(round(args.duration / dt))):
            sim.step()
        wall = time.perf_counter() - start
        pieces = sum(1 for n in sim.model.names if n == "pane" or n.startswith("pane."))
        print(f"{name:40s} {sim.body('ball').velocity[2]:12.2f} {pieces:7d} {wall:7.1f}", flush=True)


if __name__ == "__main__":
    main()
