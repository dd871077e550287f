"""Cost of the von Mises plasticity pass per FEM step at ~10k tets, and reference-update counts.

Prints a table and writes outputs/bench_plastic_step.csv. Run:
    OPENBLAS_NUM_THREADS=1 python benchmarks/plastic_step.py
1. The same floating (and corotated) body stepped elastically and with a yield stress under a
   ramped end torque, so that a growing part of it is yielding during the timed steps (the return
   map, the force update and the plastic RHS all run). The two bodies are stepped in lockstep (one
   step of each in turn, alternating which goes first), so that the shared machine's changing load
   hits both alike; medians over the timed steps of a few repeats.
2. The dent scene of tests/test_plasticity_structures.py: reference updates (each one
   refactorisation of the plate only) for several ``plastic_update_strain``.
"""
import csv
import os
import sys
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np

from fem import dynamics
from fem.mesh import box_tet_mesh
from fem.model import build_fem_model, rest_state
from hybrid import Simulation
from hybrid.app.scene import parse_scene
from hybrid.coupling.events import ReferenceUpdate


def end_torsion(model, torque):
    """Node forces ``(n, 3)`` (N) twisting the end faces x = +-L/2 by -+``torque`` (N m) about x,
    tangential and proportional to node mass (zero net force and torque on the body)."""
    x = model.rest_points
    end = np.isclose(np.abs(x[:, 0]), np.abs(x[:, 0]).max())
    tangential = np.cross([1.0, 0.0, 0.0], x) * (np.sign(x[:, 0]) * end * model.node_mass)[:, None]
    return tangential * torque / np.cross(x, tangential)[x[:, 0] > 0, 0].sum()


def step_times(models, dt, steps, torque):
    """Wall times (s) of the ``steps`` timed steps of each model, ``(len(models), steps)``, and the
    fraction of yielded tets after each, same shape. The models (same mesh) are stepped in lockstep,
    the first to go alternating. The end torque ramps from 0 to ``torque`` over the untimed first
    ``steps`` steps and on to 2 ``torque`` over the timed ones, so the plastic zone keeps
    spreading."""
    pattern = end_torsion(models[0], 1.0)
    states = [rest_state(model) for model in models]
    times, yielded = np.zeros((len(models), steps)), np.zeros((len(models), steps))
    for k in range(2 * steps):
        for i in (range(len(models)) if k % 2 else reversed(range(len(models)))):
            loaded = replace(models[i], node_load=pattern * torque * (k + 1) / steps)
            t0 = time.perf_counter()
            states[i] = dynamics.step(loaded, states[i], dt)
            if k >= steps:
                times[i, k - steps] = time.perf_counter() - t0
                yielded[i, k - steps] = 0.0 if states[i].tet_yielded is None else states[i].tet_yielded.mean()
    return times, yielded


def step_cost(rows, frame, steps):
    points, tets = box_tet_mesh((1.0, 0.5, 0.5), (20, 9, 9))
    dt = 1e-4
    kw = dict(density=2700.0, young=70e9, poisson=0.3, frame=frame)
    # square bar 0.5 m: first yield of the section near 15 kN m at Y = 1 MPa, fully plastic near 24;
    # the ramp to 30 kN m yields a growing fraction (about 0 to 80 %) of the tets
    elastic = build_fem_model(points, tets, **kw)
    plastic = build_fem_model(points, tets, yield_stress=1e6, **kw)
    # repeats in lockstep, medians: the machine is shared
    runs = [step_times([elastic, plastic], dt, steps, 15e3) for _ in range(3)]
    t_el, t_pl = np.median(np.concatenate([times for times, _ in runs], axis=1), axis=1)
    yielded = [fraction[1].mean() for _, fraction in runs]
    rows.append((f"{frame} step", f"{len(tets)} tets", f"{t_el * 1e3:.2f}", f"{t_pl * 1e3:.2f}",
                 f"{100 * (t_pl / t_el - 1):.1f}%", f"yielded {100 * np.mean(yielded):.0f}% of tets"))


def dent_updates(rows, strains):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from test_plasticity_structures import DENT_YIELD, plate_scene
    for strain in strains:
        scene = plate_scene(f"yield_stress = {DENT_YIELD}\nplastic_update_strain = {strain}")
        sim = Simulation(parse_scene(tomllib.loads(scene), "dent", Path(".")))
        t0 = time.perf_counter()
        for _ in range(int(round(0.01 / sim.dt))):
            sim.step()
        wall = time.perf_counter() - t0
        count = sum(isinstance(e, ReferenceUpdate) for e in sim.events)
        st = sim.state.fem[0]
        rows.append(("dent 0.01 s", f"update strain {strain}", f"{wall:.2f} s wall", f"{count} updates",
                     f"peeq max {st.tet_peeq.max():.4f}", f"{sim.model.fem[0].tet_count} tets, 100 steps"))


def main():
    rows = [("what", "size", "elastic ms/step", "plastic ms/step", "extra", "note")]
    steps = int(os.environ.get("BENCH_STEPS", "20"))
    step_cost(rows, "floating", steps)
    step_cost(rows, "corotated", max(5, steps // 4))
    dent_updates(rows, [0.02, 0.01, 0.004, 0.002])
    for row in rows:
        print(" | ".join(f"{c:>18}" for c in row))
    out = Path("outputs")
    out.mkdir(exist_ok=True)
    with open(out / "bench_plastic_step.csv", "w", newline="") as stream:
        csv.writer(stream).writerows(rows)


if __name__ == "__main__":
    main()
