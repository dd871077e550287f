"""model = "auto" against all-FEM: wall time side by side in one run, and the error of auto.

Three scenes, each run twice in this process (every auto body as `model = "auto"`, then the same
scene with them `model = "fem"`), alternating so both see the same machine:

- pile: eight soft boxes (E = 0.2 MPa, 1.3k-2k tets each) in two layers, the upper four dropped
  30 cm onto the lower four, a little off centre, left to settle (`--seconds`, default 5 s,
  dt = 2 ms); run as auto with the default thresholds and again with `elastify_strain` 1e-2
  (`--pile-elastify`); error: largest distance between a body's final centre in the auto and
  all-FEM runs, over the body's size;
- plate: a plastic plate (E = 100 MPa, yield 0.2 MPa, 1.2k tets) anchored at two edges, struck by
  three steel balls at intervals (0.6 s, dt = 0.5 ms); error: the largest plastic strain and the
  dent depth under the first ball, relative;
- ringing (the worst case): an undamped Newmark block in zero gravity set vibrating, which never
  calms, so auto gains nothing and costs its checks (0.5 s, dt = 1 ms).

    OPENBLAS_NUM_THREADS=1 python benchmarks/auto_model.py [--seconds 5] [--repeat 1] [--scenes pile plate ringing] [--timeline]

Prints a table and GOAL lines (issue 21: the pile 5x faster within 1% of size, the worst case's
overhead under 10%); writes outputs/bench/auto_model.csv.
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
TIMELINE = 0.25      # s of simulated time per entry of --timeline


def pile_scene(seconds, elastify=None):
    """Eight soft boxes in two layers: four 20 cm boxes dropped 2 cm onto the ground side by side,
    four 15 cm boxes dropped 30 cm onto them, each a little off centre (so they land tilted and
    rock), left to settle. ``elastify``: the auto bodies' ``elastify_strain`` (None: default)."""
    text = f"""
[simulation]
duration = {seconds}
dt = 0.002
[[planes]]
"""
    table = "" if elastify is None else f"auto = {{ elastify_strain = {elastify} }}"
    rng = np.random.default_rng(3)
    for i in range(8):
        lower = i < 4
        size, resolution = (0.2, 0.03) if lower else (0.15, 0.025)
        x, y = -0.11 + 0.22 * (i % 2), -0.11 + 0.22 * ((i // 2) % 2)
        z = 0.12 if lower else 0.42
        text += f"""
[[bodies]]
name = "box{i}"
model = "auto"
young = 2e5
density = 1000
friction = 0.6
shape = {{ type = "box", size = [{size}, {size}, {size}], resolution = {resolution} }}
position = [{x + 0.01 * rng.standard_normal():.4f}, {y + 0.01 * rng.standard_normal():.4f}, {z:.4f}]
damping = {{ stiffness = 0.005 }}
{table}
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


def run(texts):
    """Run each of ``texts`` (variant name -> scene text) with its auto bodies as auto, then the
    first with them all-FEM; wall times (s) and the finished simulations, by variant ("fem" for
    the all-FEM run)."""
    sims, walls = {}, {}
    runs = [(name, text, "auto") for name, text in texts.items()] + [("fem", next(iter(texts.values())), "fem")]
    for name, text, model in runs:
        sim = simulation(text, model)
        sim.scene_text = text
        steps = int(round(sim.scene.simulation.duration / sim.dt))
        every = max(1, int(round(TIMELINE / sim.dt)))
        sim.timeline = []           # wall time (s) of each TIMELINE s of simulated time
        start = last = time.perf_counter()
        for k in range(steps):
            sim.step()
            if (k + 1) % every == 0 or k + 1 == steps:
                now = time.perf_counter()
                sim.timeline.append(now - last)
                last = now
        walls[name], sims[name] = time.perf_counter() - start, sim
    return walls, sims


def fem_fraction(sim):
    """Fraction of the steps × auto bodies stepped as FEM."""
    total = sim.stepped_time * len([b for b in sim.scene.bodies if b.model == "auto"])
    return sum(sim.fem_time.get(b.name, 0.0) for b in sim.scene.bodies if b.model == "auto") / total


def position_errors(auto, fem, sizes):
    """Per body |final centre auto - all-FEM| over the body's size."""
    return {n: float(np.linalg.norm(auto.body(n).position - fem.body(n).position) / s)
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
    parser.add_argument("--pile-elastify", type=float, nargs="*", default=[1e-2],
                        help="the pile run again with its boxes' elastify_strain at these values")
    parser.add_argument("--timeline", action="store_true",
                        help=f"also print each run's wall time per {TIMELINE} s of simulated time")
    args = parser.parse_args()
    rows = []
    pile = {"auto": pile_scene(args.seconds)}
    pile.update({f"auto, elastify_strain {e:g}": pile_scene(args.seconds, e) for e in args.pile_elastify})
    scenes = (("pile", pile), ("plate", {"auto": plate_scene()}), ("ringing", {"auto": ringing_scene()}))
    for name, texts in [(n, t) for n, t in scenes if n in args.scenes]:
        results = [run(texts) for _ in range(args.repeat)]
        fem = float(np.median([w["fem"] for w, _ in results]))
        sims = results[-1][1]
        if args.timeline:
            for variant in [*texts, "fem"]:
                print(f"timeline {name} ({variant}), wall s per {TIMELINE} s simulated: "
                      + " ".join(f"{w:.2f}" for w in sims[variant].timeline))
        for variant in texts:
            auto = float(np.median([w[variant] for w, _ in results]))
            sim = sims[variant]
            row = {"scene": name, "auto": variant, "wall_fem_s": round(fem, 2),
                   "wall_auto_s": round(auto, 2), "speedup": round(fem / auto, 2),
                   "fem_fraction": round(fem_fraction(sim), 3),
                   "switches": sum(1 for e in sim.events if hasattr(e, "event"))}
            if name == "pile":
                errors = position_errors(sim, sims["fem"], {b.name: b.shape.size[0] for b in sim.scene.bodies})
                row["error"] = (f"positions: largest {max(errors.values()):.2%} of size, median "
                                f"{np.median(list(errors.values())):.2%}")
                met = "met" if fem / auto >= 5.0 and max(errors.values()) <= 0.01 else "not met"
                print(f"GOAL auto_pile_speedup ({variant}): measured={fem / auto:.2f} target=5.0 {met}")
            elif name == "plate":
                (s_auto, d_auto), (s_fem, d_fem) = dent(sim), dent(sims["fem"])
                row["error"] = (f"plastic strain {abs(s_auto - s_fem) / s_fem:.2%}, dent depth "
                                f"{abs(d_auto - d_fem) / d_fem:.2%} ({d_fem * 1e3:.2f} mm)")
            else:
                row["error"] = f"position {position_errors(sim, sims['fem'], {'block': 0.3})['block']:.2%} of size"
                overhead = auto / fem - 1.0
                print(f"GOAL auto_worst_case_overhead: measured={overhead:.2f} target=0.10 "
                      f"{'met' if overhead < 0.10 else 'not met'}")
            rows.append(row)
            print(", ".join(f"{k} {v}" for k, v in row.items()), flush=True)
    write_csv(CSV_PATH, rows)


if __name__ == "__main__":
    main()
