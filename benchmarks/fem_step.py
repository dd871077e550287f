"""FEM step cost: an elastic slab with a rigid box resting on it.

Scene (parsed with hybrid.app.scene.parse_scene, stepped by hybrid.Simulation):
a 1 m x 1 m x 0.2 m FEM slab (E = 1 MPa, nu = 0.3, 1000 kg/m^3, mass damping 1/s, P1 tets,
lumped mass, backward Euler) and a rigid 0.3 m cube (2000 kg/m^3) resting on its top face;
gravity -9.81 m/s^2, dt = 1 ms. Two ways to hold the slab up (``--supports``):
``ground``: it lies on a ground plane, so its whole bottom face (about 20 x 20 nodes at 10k tets)
is in contact together with the nodes under the box; ``anchored``: its bottom face is an anchor
region, so only the nodes under the box are in contact. The slab resolution is chosen so the mesh
has about the requested number of tets (box cells split into six tets each). For each size,
support and frame (floating, corotated), measured in the same run, side by side:

  step     the coupled step (contacts with the ground and the box, coupling rounds), after
           ``--warmup`` steps so the box has settled into contact and the slab's resting nodes
           on the ground are held (hybrid.coupling.resting; floating frame only, ``held_nodes`` in the CSV
           counts them); median of ``--steps`` steps
  elastic  the FEM step alone, ``fem.dynamics.step`` (no contacts), repeated from the settled,
           loaded state; median of ``--steps`` repetitions
  in-step  the same back-substitutions timed inside ``--steps`` more coupled steps (median): the
           floor as the step meets it, with the caches the rest of the step has used
  floor    one back-substitution of the slab's own prefactored system, no node held (the
           row's sparse backend, the scene's ``[simulation.solver] linear_solver``,
           ``--backends``: CHOLMOD, the project's default, and SuperLU),
           ``fem.dynamics.system_factorisation(model, dt).solve`` on a random right-hand side;
           median of 20 repetitions
  cold     the same back-substitution right after reading 32 MB (this machine's L3 cache) of other
           data, as a step's own work does before its solves: what the floor costs with the
           factor out of the cache; median of 20
  naive    per step: a scikit-fem basis on the current node positions, K (linear elasticity) and
           M (vector mass) assembled with ``skfem.asm``, and ``scipy.sparse.linalg.spsolve`` of
           ``(M + h^2 K) v+ = M v + h (f_gravity - K u)``; median of ``--naive-steps`` steps
           (frame-independent, measured once per size)

Goals reported against: floating step within 2x of the floor; coupled step at least 20x faster
than naive at 10k tets.

    OPENBLAS_NUM_THREADS=1 python benchmarks/fem_step.py [--sizes 1000 10000] [--big] [--steps 30]
        [--supports ground anchored] [--backends cholmod superlu]

Then, unless ``--no-plastic``, the plastic pass of benchmarks/plastic_step.py: its cost per step
at ~10k tets over the elastic step (goal: under 30% extra) and the reference updates
(refactorisations) of the dent scene.

Prints the tables and writes outputs/bench/fem_step.csv (and plastic_step's CSV). Default run:
~1k and ~10k tets, both backends, about 10 minutes on two shared cores. ``--big`` adds ~50k tets;
its first coupled step on the ground solves the response columns of 1,346 touched nodes (41 s with
CHOLMOD), so e.g. ``--sizes 50000 --steps 10 --warmup 5 --naive-steps 1 --backends cholmod``.
"""
import argparse
import csv
import math
import os
import time
import tomllib
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import scipy.sparse.linalg as spla
import skfem
from skfem.helpers import dot
from skfem.models.elasticity import lame_parameters, linear_elasticity

from fem import dynamics as fem_dyn
from fem import solver as fem_solver
from hybrid import Simulation
from hybrid.app.scene import parse_scene

from _common import write_csv

SLAB = (1.0, 1.0, 0.2)      # m
BOX = 0.3                    # m, edge of the rigid cube
YOUNG, POISSON, DENSITY = 1e6, 0.3, 1000.0
DT = 1e-3
FRAMES = ("floating", "corotated")
SUPPORTS = ("ground", "anchored")   # slab lying on a ground plane, or its bottom face held
BACKENDS = ("cholmod", "superlu")   # fem.solver backends (the floor is that of the row's backend)
CSV_PATH = Path("outputs/bench/fem_step.csv")


def slab_cells(target_tets):
    """Cells ``k`` along x and y (z gets ceil(0.2 k)) giving the tet count closest to the target."""
    def tets(k):
        return 6 * k * k * math.ceil(SLAB[2] * k - 1e-9)
    return min(range(2, 200), key=lambda k: abs(tets(k) - target_tets))


def scene_text(cells, frame, support="ground", backend="cholmod"):
    # a hair above 1/k so the scene mesher's ceil(size / resolution) gives exactly k cells
    resolution = SLAB[0] / cells * (1 + 1e-6)
    bottom = -SLAB[2] / 2
    held = (f"""[[bodies.anchors]]
box = [[-1.0, -1.0, {bottom - 1e-3}], [1.0, 1.0, {bottom + 1e-3}]]
""" if support == "anchored" else "")
    return f"""
[simulation]
dt = {DT}
[simulation.solver]
linear_solver = "{backend}"
{"[[planes]]" if support == "ground" else ""}
[[bodies]]
name = "slab"
model = "fem"
shape = {{ type = "box", size = {list(SLAB)}, resolution = {resolution!r} }}
position = [0.0, 0.0, {SLAB[2] / 2}]
young = {YOUNG}
poisson = {POISSON}
density = {DENSITY}
frame = "{frame}"
damping = {{ mass = 1.0 }}
{held}[[bodies]]
name = "box"
shape = {{ type = "box", size = [{BOX}, {BOX}, {BOX}] }}
position = [0.0, 0.0, {SLAB[2] + BOX / 2}]
density = 2000
"""


def median_ms(fn, repeat):
    """Median wall time of ``fn()`` over ``repeat`` calls (ms), and the last result."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times)), out


def floor_ms(model, repeat=20):
    """One back-substitution of the prefactored rest system on a random right-hand side (ms)."""
    factorisation = fem_dyn.system_factorisation(model, DT)
    rhs = np.random.default_rng(0).standard_normal(factorisation.matrix.shape[0])
    return median_ms(lambda: factorisation.solve(rhs), repeat)[0]


# bytes read before each cold back-substitution: the L3 cache of this project's machine
COLD_BYTES = 32 * 2 ** 20


def cold_floor_ms(model, repeat=20):
    """One back-substitution of the prefactored rest system (ms), each right after reading
    COLD_BYTES of other memory, so the factor is no longer in the cache."""
    factorisation = fem_dyn.system_factorisation(model, DT)
    rhs = np.random.default_rng(0).standard_normal(factorisation.matrix.shape[0])
    other = np.ones(COLD_BYTES // 8)
    times = []
    for _ in range(repeat):
        other.sum()
        t0 = time.perf_counter()
        factorisation.solve(rhs)
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def naive_step(points_rest, tets, x, v, gravity):
    """The naive step: reassemble K and M with scikit-fem on the current mesh, spsolve M + h^2 K."""
    mesh = skfem.MeshTet(np.ascontiguousarray(x.T), np.ascontiguousarray(tets.T))
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP1()))
    lam, mu = lame_parameters(YOUNG, POISSON)

    @skfem.BilinearForm
    def mass(u, w, _):
        return DENSITY * dot(u, w)

    K = skfem.asm(linear_elasticity(lam, mu), basis)
    M = skfem.asm(mass, basis)
    dofs = basis.nodal_dofs            # (3, n): scikit-fem DOF of each node's component
    u = np.zeros(basis.N)
    vel = np.zeros(basis.N)
    g = np.zeros(basis.N)
    u[dofs] = (x - points_rest).T
    vel[dofs] = v.T
    g[dofs] = np.asarray(gravity, float)[:, None]
    rhs = M @ vel + DT * (M @ g - K @ u)
    v_new = spla.spsolve((M + DT * DT * K).tocsc(), rhs)
    return v_new[dofs].T


def measure(cells, frame, support, backend, steps, warmup):
    scene = parse_scene(tomllib.loads(scene_text(cells, frame, support, backend)), "fem_step", Path("."))
    sim = Simulation(scene)
    model = sim.model
    if model.fem[0].linear_solver != backend:
        raise RuntimeError(f"the slab was built with linear_solver {model.fem[0].linear_solver!r}, "
                           f"not the scene's {backend!r}")
    for _ in range(warmup):
        sim.step()
    fem_model = model.fem[0]
    floor = floor_ms(fem_model)
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        sim.step()
        times.append(time.perf_counter() - t0)
    state = sim.state
    step_ms = 1e3 * float(np.median(times))
    q1, q3 = 1e3 * np.percentile(times, [25, 75])
    record = state.resting[0] if state.resting is not None else None
    held = len(record.nodes) if record is not None and record.held else 0
    # elastic-only FEM step from the settled, loaded state (same input every repetition)
    settled = state.fem[0]
    elastic, _ = median_ms(lambda: fem_dyn.step(fem_model, settled, DT, model.gravity), steps)
    floor = min(floor, floor_ms(fem_model))     # before and after the step timings
    cold = cold_floor_ms(fem_model)
    in_step = in_step_solve_ms(sim, steps)
    state = sim.state
    sanity = dict(box_z=float(state.rigid.position[0, 2]), slab_min_z=float(settled.x[:, 2].min()))
    return model, state, dict(step_ms=step_ms, step_q1=q1, step_q3=q3, elastic_ms=elastic,
                              floor_ms=floor, cold_floor_ms=cold, solve_in_step_ms=in_step,
                              held_nodes=held, **sanity)


def in_step_solve_ms(sim, steps):
    """Median time of the single back-substitutions (one right-hand side) made inside ``steps``
    more coupled steps (ms): the floor's solve as the step sees it, after the rest of the step has
    used the caches. Timed in separate steps, so the step timings carry no timer."""
    times, solve = [], fem_solver.Factorisation.solve

    def timed(self, rhs):
        t0 = time.perf_counter()
        out = solve(self, rhs)
        if np.ndim(rhs) == 1:
            times.append(time.perf_counter() - t0)
        return out

    fem_solver.Factorisation.solve = timed
    try:
        for _ in range(steps):
            sim.step()
    finally:
        fem_solver.Factorisation.solve = solve
    return 1e3 * float(np.median(times)) if times else float("nan")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000],
                        help="target tet counts (default 1000 10000)")
    parser.add_argument("--big", action="store_true", help="add ~50k tets")
    parser.add_argument("--steps", type=int, default=30, help="timed steps per configuration")
    parser.add_argument("--warmup", type=int, default=100,
                        help="steps before timing (the box settles, the slab's resting nodes are held)")
    parser.add_argument("--naive-steps", type=int, default=3, help="timed naive steps per size")
    parser.add_argument("--supports", nargs="+", default=list(SUPPORTS), choices=SUPPORTS,
                        help="how the slab is held up (default: both)")
    parser.add_argument("--backends", nargs="+", default=[b for b in BACKENDS if b != "cholmod"
                                                           or fem_solver.CholeskySolverD is not None],
                        choices=BACKENDS, help="sparse solver backends to run (default: both; the "
                        "project uses cholmod when cholespy is installed)")
    parser.add_argument("--no-plastic", action="store_true",
                        help="skip the plastic-pass cost and dent reference updates (plastic_step.py)")
    args = parser.parse_args()
    sizes = args.sizes + ([50000] if args.big and 50000 not in args.sizes else [])

    rows, naive = [], {}
    for target in sizes:
        cells = slab_cells(target)
        for support in args.supports:
            for backend in args.backends:
                for frame in FRAMES:
                    rows.append(measure_row(cells, frame, support, backend, naive, args))
                    print(f"  {rows[-1]['tets']} tets {support} {backend} {frame}: step "
                          f"{rows[-1]['step_ms']:.1f} ms (box z {rows[-1]['box_z']:.4f} m, slab min z "
                          f"{rows[-1]['slab_min_z']:.2e} m, {rows[-1]['held_nodes']} nodes held)",
                          flush=True)
    report(rows, args)
    if not args.no_plastic:
        print("\nplastic pass (benchmarks/plastic_step.py): goal under 30% extra over the elastic step")
        import plastic_step
        plastic_step.main()


def measure_row(cells, frame, support, backend, naive_by_size, args):
    model, state, r = measure(cells, frame, support, backend, args.steps, args.warmup)
    m = model.fem[0]
    s = state.fem[0]
    if (cells, support) not in naive_by_size:     # the naive step does not depend on the backend
        naive_by_size[cells, support] = median_ms(
            lambda: naive_step(m.rest_points, m.tets, s.x, s.v, model.gravity), args.naive_steps)[0]
    naive = naive_by_size[cells, support]
    row = dict(tets=m.tet_count, nodes=m.node_count, dofs=3 * m.node_count, support=support,
               backend=backend, frame=frame, **r, naive_ms=naive)
    row["step_over_floor"] = row["step_ms"] / row["floor_ms"]
    row["step_over_solve_in_step"] = row["step_ms"] / row["solve_in_step_ms"]
    row["step_over_cold_floor"] = row["step_ms"] / row["cold_floor_ms"]
    row["elastic_over_floor"] = row["elastic_ms"] / row["floor_ms"]
    row["naive_over_step"] = naive / row["step_ms"]
    row["naive_over_elastic"] = naive / row["elastic_ms"]
    return row


def report(rows, args):
    header = (f"{'tets':>6} {'dofs':>6} {'support':>8} {'backend':>8} {'frame':>9} {'step ms':>8} {'elastic ms':>10} {'floor ms':>8} {'cold':>5} {'in-step':>7} "
              f"{'naive ms':>9} {'step/floor':>10} {'elastic/floor':>13} {'naive/step':>10} "
              f"{'naive/elastic':>13}")
    print(f"\nmedians; coupled step over {args.steps} steps after {args.warmup} warm-up, floor over 20 "
          f"solves, naive over {args.naive_steps} steps; dt = {DT} s")
    print(header)
    for r in rows:
        print(f"{r['tets']:>6} {r['dofs']:>6} {r['support']:>8} {r['backend']:>8} {r['frame']:>9} {r['step_ms']:>8.2f} {r['elastic_ms']:>10.2f} "
              f"{r['floor_ms']:>8.2f} {r['cold_floor_ms']:>5.2f} {r['solve_in_step_ms']:>7.2f} {r['naive_ms']:>9.1f} {r['step_over_floor']:>10.1f} "
              f"{r['elastic_over_floor']:>13.2f} {r['naive_over_step']:>10.1f} {r['naive_over_elastic']:>13.1f}")

    print("\ngoals")
    for r in rows:
        if r["frame"] == "floating":
            print(f"  {r['tets']} tets {r['support']} {r['backend']} floating within 2x of floor: coupled {r['step_over_floor']:.1f}x "
                  f"({'met' if r['step_over_floor'] <= 2 else 'NOT met'}), elastic-only "
                  f"{r['elastic_over_floor']:.2f}x ({'met' if r['elastic_over_floor'] <= 2 else 'NOT met'}); "
                  f"the same solve inside the step takes {r['solve_in_step_ms']:.2f} ms, "
                  f"{r['solve_in_step_ms'] / r['floor_ms']:.1f}x the floor, and {r['cold_floor_ms']:.2f} ms "
                  f"({r['cold_floor_ms'] / r['floor_ms']:.1f}x) with the factor out of the cache; "
                  f"the coupled step is {r['step_over_cold_floor']:.1f}x that")
    for r in rows:
        if 5000 <= r["tets"] <= 20000:
            print(f"  {r['tets']} tets {r['support']} {r['backend']} {r['frame']} >= 20x faster than naive: coupled "
                  f"{r['naive_over_step']:.1f}x ({'met' if r['naive_over_step'] >= 20 else 'NOT met'}), "
                  f"elastic-only {r['naive_over_elastic']:.1f}x "
                  f"({'met' if r['naive_over_elastic'] >= 20 else 'NOT met'})")

    write_csv(CSV_PATH, rows)
    print(f"wrote {CSV_PATH}")


if __name__ == "__main__":
    main()
