"""`resolve_impacts` against a run at the small step: same outcome, and what each costs.

Each scene runs three ways in this process, one after the other: at the scene's `dt` with
`resolve_impacts = true` (the impact steps taken in sub-steps, hybrid/coupling/substep.py), at
the shortest sub-step that run took, throughout (the small-step run it should match), and at the
scene's `dt` plainly (what the user had before). Scenes:

- dent: a 0.88 kg steel ball at 20 m/s onto a 2 cm aluminium plate (E = 70 GPa, yield 50 MPa) on
  two supports, 100 ms at dt = 1 ms (`--dent-duration`); outcome: the plastic work, yield stress times the volume
  integral of the equivalent plastic strain (perfect plasticity dissipates exactly that);
- pane: a glass pane (E = 70 GPa, 5 MPa strength) held on two edges, struck at its centre by a
  steel ball (1 cm radius) at 10 m/s, 4 ms at dt = 0.5 ms (docs/scenes.md); outcome: the number of pieces.

The issue's goals (23): outcome within 20% (plastic work) and 50% (pieces) of the small-step
run's, at a fraction of its cost (wall time ratio printed against 0.5).

    OPENBLAS_NUM_THREADS=1 python benchmarks/substep_cost.py [--scenes dent pane] [--dent-duration 0.1]

The sub-stepped run pays the sub-step's factorisation and contact response on top of the scene
step's, which the small-step run does not; it gains on every step after the impact, so its cost
ratio falls with the length of the run (the dent's plate rings on after the ball has left).

Prints a table and GOAL lines; writes outputs/bench/substep_cost.csv.
"""
import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

import tomllib

from hybrid import Simulation
from hybrid.app.scene import parse_scene

from _common import write_csv

CSV_PATH = Path("outputs/bench/substep_cost.csv")

DENT = """
[simulation]
duration = {duration}
dt = {dt}
resolve_impacts = {resolve}
[[bodies]]
name = "support_left"
shape = {{ type = "box", size = [0.02, 0.3, 0.03] }}
position = [-0.12, 0.0, 0.0]
fixed = true
[[bodies]]
name = "support_right"
shape = {{ type = "box", size = [0.02, 0.3, 0.03] }}
position = [0.12, 0.0, 0.0]
fixed = true
[[bodies]]
name = "plate"
model = "fem"
shape = {{ type = "box", size = [0.3, 0.3, 0.02] }}
position = [0.0, 0.0, 0.025]
density = 2700.0
young = 70e9
poisson = 0.33
yield_stress = 50e6
[[bodies]]
name = "ball"
shape = {{ type = "sphere", radius = 0.03 }}
density = 7800.0
position = [0.0, 0.0, 0.0651]
velocity = [0.0, 0.0, -20.0]
"""

PANE = """
[simulation]
duration = {duration}
dt = {dt}
resolve_impacts = {resolve}
gravity = [0.0, 0.0, 0.0]
[[bodies]]
name = "pane"
model = "fem"
shape = {{ type = "box", size = [0.2, 0.2, 0.01], resolution = 0.01 }}
density = 2500.0
young = 70e9
poisson = 0.22
fracture_stress = 5e6
[[bodies.anchors]]
box = [[-0.11, -0.11, -0.01], [-0.0999, 0.11, 0.01]]
[[bodies.anchors]]
box = [[0.0999, -0.11, -0.01], [0.11, 0.11, 0.01]]
[[bodies]]
name = "ball"
shape = {{ type = "sphere", radius = 0.01 }}
density = 7800.0
position = [0.0, 0.0, 0.0155]
velocity = [0.0, 0.0, -10.0]
"""


def plastic_work(sim):
    """Yield stress times the volume integral of the equivalent plastic strain (J, each element's
    quadrature points averaged), over the FEM bodies: what perfect von Mises plasticity has
    dissipated."""
    total = 0.0
    for m, s in zip(sim.model.fem, sim.state.fem):
        if m.yield_stress is not None and s.tet_peeq is not None:
            peeq = np.asarray(s.tet_peeq).reshape(m.tet_count, -1).mean(axis=1)
            total += m.yield_stress * float(m.elements.tet_volume @ peeq)
    return total


def pieces(sim):
    """Bodies made of the pane: the pane and its fragments."""
    return sum(1 for n in sim.model.names if n == "pane" or n.startswith("pane."))


def run(template, duration, dt, resolve):
    """The scene over ``duration`` s at ``dt`` (with ``resolve_impacts``): (wall s, the finished
    simulation)."""
    text = template.format(duration=duration, dt=dt, resolve=str(resolve).lower())
    sim = Simulation(parse_scene(tomllib.loads(text), "<substep_cost>", Path(".")))
    steps = int(round(sim.scene.simulation.duration / sim.dt))
    start = time.perf_counter()
    for _ in range(steps):
        sim.step()
    return time.perf_counter() - start, sim


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["dent", "pane"], help="which scenes to run")
    parser.add_argument("--dent-duration", type=float, default=0.1, help="simulated time of the dent (s)")
    args = parser.parse_args()
    scenes = {"dent": (DENT, args.dent_duration, 1e-3, plastic_work, "plastic work (J)", 0.2),
              "pane": (PANE, 0.004, 5e-4, pieces, "pieces", 0.5)}
    rows = []
    for name in args.scenes:
        template, duration, dt, outcome, what, tolerance = scenes[name]
        wall_sub, sub = run(template, duration, dt, True)
        small = sub.impacts.substepped["smallest_dt"] or dt
        wall_small, fine = run(template, duration, small, False)
        wall_plain, plain = run(template, duration, dt, False)
        o_sub, o_small, o_plain = outcome(sub), outcome(fine), outcome(plain)
        row = {"scene": name, "duration_s": duration, "dt": dt, "small_dt": small,
               "substepped_steps": sub.impacts.substepped["steps"],
               "substeps": sub.impacts.substepped["substeps"],
               "wall_resolve_s": round(wall_sub, 2), "wall_small_dt_s": round(wall_small, 2),
               "wall_plain_s": round(wall_plain, 2), "cost_ratio": round(wall_sub / wall_small, 3),
               "outcome": what, "with_resolve": round(o_sub, 4), "at_small_dt": round(o_small, 4),
               "plain": round(o_plain, 4)}
        rows.append(row)
        print(", ".join(f"{k} {v}" for k, v in row.items()), flush=True)
        off = abs(o_sub - o_small) / max(abs(o_small), 1e-300)
        print(f"GOAL substep_{name}_outcome_vs_small_dt: measured={off:.3f} target={tolerance} "
              f"{'met' if off <= tolerance else 'not met'}")
        print(f"GOAL substep_{name}_cost_vs_small_dt: measured={wall_sub / wall_small:.3f} target=0.5 "
              f"{'met' if wall_sub / wall_small <= 0.5 else 'not met'}")
    write_csv(CSV_PATH, rows)


if __name__ == "__main__":
    main()
