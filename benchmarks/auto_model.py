"""model = "auto" against all-FEM: wall time side by side in one run, and the error of auto.

Three scenes, each run twice in this process (every auto body as `model = "auto"`, then the same
scene with them `model = "fem"`), alternating so both see the same machine:

- pile: eight soft boxes (E = 0.2 MPa, 1.3k-2k tets each) in two layers, the upper dropped onto
  the lower off centre, left to settle (`--seconds`, default 5 s, dt = 2 ms); error: largest
  distance between a body's final centre in the two runs, over the body's size;
- plate: a plastic plate (E = 100 MPa, yield 0.2 MPa, 1.2k tets) anchored at two edges, struck by
  three steel balls at intervals (0.6 s, dt = 0.5 ms); error: the largest plastic strain and the
  dent depth under the first ball, relative;
- ringing (the worst case): an undamped Newmark block in zero gravity set vibrating, which never
  calms, so auto gains nothing and costs its checks (0.5 s, dt = 1 ms).

    OPENBLAS_NUM_THREADS=1 python benchmarks/auto_model.py [--seconds 5] [--repeat 1] [--scenes pile plate ringing]

Prints a table; writes outputs/bench/auto_model.csv.
"""
import argparse
import dataclasses
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from hybrid import Simulation
from hybrid.app.scene import parse_scene

from _common import write_csv

CSV_PATH = Path("outputs/bench/auto_model.csv")


def pile_scene(seconds):
    """Eight soft boxes in two layers: the lower four dropped onto the ground, the upper four onto
    them, each off centre, so they land on each other and settle into a pile."""
    text = f"""
[simulation]
duration = {seconds}
dt = 0.002
[[planes]]
"""
    rng = np.random.default_rng(3)
    for i in range(8):
        size, resolution = (0.15, 0.025) if i % 2 else (0.2, 0.03)
        x, y = -0.12 + 0.24 * (i % 2), -0.12 + 0.24 * ((i // 2) % 2)
        z = 0.12 + 0.3 * (i // 4)
        shift = 0.05 * (i // 4)            # the upper layer lands across two lower boxes
        text += f"""
[[bodies]]
name = "box{i}"
model = "auto"
young = 2e5
density = 1000
friction = 0.6
shape = {{ type = "box", size = [{size}, {size}, {size}], resolution = {resolution} }}
position = [{x + shift + 0.01 * rng.standard_normal():.4f}, {y + shift + 0.01 * rng.standard_normal():.4f}, {z:.4f}]
damping = {{ stiffness = 0.005 }}
"""
    return text


def plate_scene():
    """A plastic plate anchored at two edges, three steel balls arriving at intervals."""
    text = """
[simulation]
duration = 0.6
dt = 0.0005
[[bodies]]
name = "plate"
model = "auto"
young = 1e8
density = 2700
yield_stress = 2e5
shape = { type = "box", size = [0.3, 0.2, 0.02], resolution = 0.02 }
damping = { stiffness = 0.0005 }
[[bodies.anchors]]
box = [[-0.16, -0.11, -0.02], [-0.14, 0.11, 0.02]]
[[bodies.anchors]]
box = [[0.14, -0.11, -0.02], [0.16, 0.11, 0.02]]
"""
    for i, (x, height) in enumerate(((-0.08, 0.09), (0.0, 0.6), (0.08, 1.3))):
        text += f"""
[[bodies]]
name = "ball{i}"
shape = {{ type = "sphere", radius = 0.02 }}
density = 7800
position = [{x}, 0.0, {height}]
velocity = [0, 0, -4.0]
"""
    return text


def ringing_scene():
    """An undamped Newmark block vibrating in zero gravity: never calm."""
    return """
[simulation]
duration = 0.5
dt = 0.001
gravity = [0, 0, 0]
[[bodies]]
name = "block"
model = "auto"
young = 1e6
density = 1000
integrator = "newmark"
shape = { type = "box", size = [0.3, 0.1, 0.1], resolution = 0.025 }
angular_velocity = [0, 0, 3.0]
[[bodies]]
name = "hammer"
shape = { type = "sphere", radius = 0.03 }
density = 7800
position = [0.0, -0.2, 0.0]
velocity = [0, 4.0, 0]
"""


def simulation(text, model):
    """The scene with every auto body as ``model``."""
    scene = parse_scene(__import__("tomllib").loads(text), f"<{model}>", Path("."))
    bodies = tuple(dataclasses.replace(b, model=model) if b.model == "auto" else b
                   for b in scene.bodies)
    return Simulation(dataclasses.replace(scene, bodies=bodies))


def run(text):
    """Run the scene auto and all-FEM; wall times (s) and the two finished simulations."""
    sims, walls = {}, {}
    for model in ("auto", "fem"):
        sim = simulation(text, model)
        sim.scene_text = text
        steps = int(round(sim.scene.simulation.duration / sim.dt))
        start = time.perf_counter()
        for _ in range(steps):
            sim.step()
        walls[model], sims[model] = time.perf_counter() - start, sim
    return walls, sims


def fem_fraction(sim):
    """Fraction of the steps × auto bodies stepped as FEM."""
    total = sim.stepped_time * len([b for b in sim.scene.bodies if b.model == "auto"])
    return sum(sim.fem_time.get(b.name, 0.0) for b in sim.scene.bodies if b.model == "auto") / total


def position_errors(sims, sizes):
    """Per body |final centre auto - all-FEM| over the body's size."""
    return {n: float(np.linalg.norm(sims["auto"].body(n).position - sims["fem"].body(n).position) / s)
            for n, s in sizes.items()}


def dent(sim):
    """(largest plastic strain, deepest sag of the plate's top face (m), from its shape when the
    run began: a reference update bakes the dent into the current rest shape)."""
    plate = sim.body("plate")
    rest = simulation(sim.scene_text, "fem").body("plate").points
    top = rest[:, 2] > rest[:, 2].max() - 1e-9
    return plate.plastic_strain.max(), float((rest[top, 2] - plate.points[top, 2]).max())


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="simulated time of the pile")
    parser.add_argument("--repeat", type=int, default=1, help="runs of each scene (medians)")
    parser.add_argument("--scenes", nargs="+", default=["pile", "plate", "ringing"],
                        help="which scenes to run")
    args = parser.parse_args()
    rows = []
    scenes = (("pile", pile_scene(args.seconds)), ("plate", plate_scene()), ("ringing", ringing_scene()))
    for name, text in [(n, t) for n, t in scenes if n in args.scenes]:
        results = [run(text) for _ in range(args.repeat)]
        auto = float(np.median([w["auto"] for w, _ in results]))
        fem = float(np.median([w["fem"] for w, _ in results]))
        sims = results[-1][1]
        row = {"scene": name, "wall_fem_s": round(fem, 2), "wall_auto_s": round(auto, 2),
               "speedup": round(fem / auto, 2), "fem_fraction": round(fem_fraction(sims["auto"]), 3),
               "switches": sum(1 for e in sims["auto"].events if hasattr(e, "event"))}
        if name == "pile":
            errors = position_errors(sims, {b.name: b.shape.size[0] for b in sims["auto"].scene.bodies})
            row["error"] = (f"positions: largest {max(errors.values()):.2%} of size, median "
                            f"{np.median(list(errors.values())):.2%}")
        elif name == "plate":
            (s_auto, d_auto), (s_fem, d_fem) = dent(sims["auto"]), dent(sims["fem"])
            row["error"] = (f"plastic strain {abs(s_auto - s_fem) / s_fem:.2%}, dent depth "
                            f"{abs(d_auto - d_fem) / d_fem:.2%} ({d_fem * 1e3:.2f} mm)")
        else:
            row["error"] = f"position {position_errors(sims, {'block': 0.3})['block']:.2%} of size"
        rows.append(row)
        print(", ".join(f"{k} {v}" for k, v in row.items()), flush=True)
    write_csv(CSV_PATH, rows)


if __name__ == "__main__":
    main()
