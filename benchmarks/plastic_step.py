"""Cost of the von Mises plasticity pass per FEM step at ~10k tets, and reference-update counts.

Prints a table and writes outputs/bench_plastic_step.csv. Run:
    OPENBLAS_NUM_THREADS=1 python benchmarks/plastic_step.py
1. The same floating (and corotated) body stepped elastically and with a yield stress, loaded so
   that it is yielding (so the return map, the force update and the plastic RHS all run).
2. The dent scene of tests/test_plasticity_structures.py: reference updates (each one
   refactorisation of the plate only) for several ``plastic_update_strain``.
"""
import csv
import os
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

from fem import dynamics
from fem.mesh import box_tet_mesh
from fem.model import build_fem_model, rest_state
from fem.reference import apply_reference_updates


def step_time(model, state, dt, steps):
    state = dynamics.step(model, state, dt)   # factorise outside the timing
    t0 = time.perf_counter()
    for _ in range(steps):
        state = dynamics.step(model, state, dt)
    return (time.perf_counter() - t0) / steps, state


def step_cost(rows, frame, steps):
    points, tets = box_tet_mesh((1.0, 0.5, 0.5), (20, 9, 9))
    dt = 1e-4
    kw = dict(density=2700.0, young=70e9, poisson=0.3, frame=frame)
    # a twisting, stretching initial velocity: large enough to yield everywhere at Y = 1 MPa
    v = np.cross([0.0, 0.0, 5.0], points) + points * [3.0, 0.0, 0.0]
    elastic = build_fem_model(points, tets, **kw)
    plastic = build_fem_model(points, tets, yield_stress=1e6, **kw)
    t_el, _ = step_time(elastic, rest_state(elastic, v=v), dt, steps)
    t_pl, s = step_time(plastic, rest_state(plastic, v=v), dt, steps)
    yielded = float(s.tet_yielded.mean())
    rows.append((f"{frame} step", f"{len(tets)} tets", f"{t_el * 1e3:.2f}", f"{t_pl * 1e3:.2f}",
                 f"{100 * (t_pl / t_el - 1):.1f}%", f"yielded {100 * yielded:.0f}% of tets"))


def dent_updates(rows, strains):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from conftest import Sim
    from test_plasticity_structures import DENT_YIELD, plate_scene
    for strain in strains:
        sim = Sim(plate_scene(f"yield_stress = {DENT_YIELD}\nplastic_update_strain = {strain}"))
        count = [0]

        def events(s):
            s.model.fem, s.state.fem, done = apply_reference_updates(s.model.fem, s.state.fem, s.model.dt)
            count[0] += len(done)

        t0 = time.perf_counter()
        sim.advance(0.01, each=events)
        wall = time.perf_counter() - t0
        st = sim.state.fem[0]
        rows.append(("dent 0.01 s", f"update strain {strain}", f"{wall:.2f} s wall", f"{count[0]} updates",
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
