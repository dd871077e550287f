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

  first    the first step (s, CPU time; wall time in the CSV): the slab's first contact with the
           ground (its whole bottom face) or the anchors, and the box; it solves the contact
           response of every touched node (fem.contact_response); ``response_mb`` is the memory
           the response keeps after it
  coupled  the coupled step, ``hybrid.coupling.step.advance`` (contacts with the ground and the
           box, coupling rounds, events), after ``--warmup`` steps so the box has settled into
           contact and the slab's resting nodes on the ground are held (hybrid.coupling.resting;
           floating frame only, ``held_nodes`` in the CSV counts them); median of ``--steps``
           steps, each timed right after a ``cold`` back-substitution (below), side by side, in
           CPU time of the process (``time.process_time``: on a machine running more processes
           than cores, wall time counts the waits for a core; both are in the CSV)
  step     the same through ``hybrid.Simulation.step``, which adds its per-step watch (stress
           peaks, impact resolution); median of ``--steps`` steps, CPU time
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
           factor out of the cache; median of ``--steps``, each taken just before a timed
           coupled step
  naive    per step: a scikit-fem basis on the current node positions, K (linear elasticity) and
           M (vector mass) assembled with ``skfem.asm``, and ``scipy.sparse.linalg.spsolve`` of
           ``(M + h^2 K) v+ = M v + h (f_gravity - K u)``; median of ``--naive-steps`` steps
           (frame-independent, measured once per size)

Goals (issue 24), printed as ``GOAL <name>: measured=<ratio> target=<ratio> met|not met``: the
coupled step with the floating frame, ground and anchored, within 2x of the cold floor at ~10k
tets and 1.5x at ~50k (CHOLMOD); the corotated frame within 3x at ~10k (the worse of ground and
anchored); the first contact at ~50k tets under 5 s (the median first step of the CHOLMOD ground
runs). Also reported: coupled step at least 20x faster than naive at 10k tets.

    OPENBLAS_NUM_THREADS=1 python benchmarks/fem_step.py [--sizes 1000 10000] [--big] [--steps 30]
        [--supports ground anchored] [--backends cholmod superlu]

With ``--stages``, each stage of the floating CHOLMOD rows' coupled step is timed too (wall time,
medians of ``--steps`` more steps, each right after reading 32 MB of other memory): the
back-substitution, predict, detection, the contact problem, contact resolution, the impulse
response, finish, the resting watch, and the finiteness check and the events (these two after
``hybrid.coupling.step.coupled_step``, which holds the others).

Then, unless ``--no-plastic``, the plastic pass of benchmarks/plastic_step.py: its cost per step
at ~10k tets over the elastic step (goal: under 30% extra) and the reference updates
(refactorisations) of the dent scene.

Prints the tables and writes outputs/bench/fem_step.csv (and plastic_step's CSV). Default run:
~1k and ~10k tets, both backends, about 10 minutes on two shared cores. ``--big`` adds ~50k tets;
its first coupled step on the ground solves the response columns of 1,346 touched nodes (22 s CPU with
CHOLMOD), so e.g. ``--sizes 50000 --steps 15 --warmup 100 --naive-steps 1 --backends cholmod
--frames floating --no-plastic`` (20 warm-up steps are not enough there: the bottom face is not held yet).
"""
import argparse
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
from hybrid.coupling.step import advance

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


def measure(cells, frame, support, backend, steps, warmup, stages=False):
    scene = parse_scene(tomllib.loads(scene_text(cells, frame, support, backend)), "fem_step", Path("."))
    sim = Simulation(scene)
    model = sim.model
    if model.fem[0].linear_solver != backend:
        raise RuntimeError(f"the slab was built with linear_solver {model.fem[0].linear_solver!r}, "
                           f"not the scene's {backend!r}")
    fem_model = model.fem[0]
    fem_dyn.system_factorisation(fem_model, DT)      # built with the scene: not the first contact's
    t0, c0 = time.perf_counter(), time.process_time()
    sim.step()
    first, first_wall = time.process_time() - c0, time.perf_counter() - t0
    response = response_mb(fem_model)
    for _ in range(warmup - 1):
        sim.step()
    floor = floor_ms(fem_model)
    coupled, cold, coupled_wall, cold_wall = coupled_and_cold_ms(sim, fem_model, steps)
    times = []
    for _ in range(steps):
        t0 = time.process_time()
        sim.step()
        times.append(time.process_time() - t0)
    state = sim.state
    step_ms = 1e3 * float(np.median(times))
    q1, q3 = 1e3 * np.percentile(coupled, [25, 75])
    record = state.resting[0] if state.resting is not None else None
    held = len(record.nodes) if record is not None and record.held else 0
    # elastic-only FEM step from the settled, loaded state (same input every repetition)
    settled = state.fem[0]
    elastic, _ = median_ms(lambda: fem_dyn.step(fem_model, settled, DT, model.gravity), steps)
    floor = min(floor, floor_ms(fem_model))     # before and after the step timings
    in_step = in_step_solve_ms(sim, steps)
    stage_times = stage_us(sim, steps) if stages else None
    state = sim.state
    sanity = dict(box_z=float(state.rigid.position[0, 2]), slab_min_z=float(settled.x[:, 2].min()))
    return model, state, dict(first_s=first, first_wall_s=first_wall, response_mb=response, coupled_ms=float(np.median(coupled)),
                              coupled_q1=q1, coupled_q3=q3, step_ms=step_ms, elastic_ms=elastic,
                              coupled_wall_ms=float(np.median(coupled_wall)),
                              cold_wall_ms=float(np.median(cold_wall)),
                              floor_ms=floor, cold_floor_ms=float(np.median(cold)),
                              solve_in_step_ms=in_step, held_nodes=held, stages=stage_times, **sanity)


def coupled_and_cold_ms(sim, fem_model, steps):
    """``steps`` coupled steps (``hybrid.coupling.step.advance``), each timed right after one cold
    back-substitution of the rest system (timed too), side by side so that the load of a shared
    machine falls on both alike: (step times, cold times, step wall times, cold wall times) in ms.
    The first two are the process's CPU time (``time.process_time``; BLAS runs on one thread):
    on an idle machine the same as wall time, on one running more processes than it has cores
    it leaves out the time the process waited for a core (in scheduler slices of a few ms)."""
    factorisation = fem_dyn.system_factorisation(fem_model, DT)
    rhs = np.random.default_rng(0).standard_normal(factorisation.matrix.shape[0])
    other = np.ones(COLD_BYTES // 8)
    model, state = sim.model, sim.state
    coupled, cold, coupled_wall, cold_wall = [], [], [], []
    for _ in range(steps):
        other.sum()
        w0, c0 = time.perf_counter(), time.process_time()
        factorisation.solve(rhs)
        w1, c1 = time.perf_counter(), time.process_time()
        model, state, _ = advance(model, state)
        w2, c2 = time.perf_counter(), time.process_time()
        cold.append(1e3 * (c1 - c0))
        coupled.append(1e3 * (c2 - c1))
        cold_wall.append(1e3 * (w1 - w0))
        coupled_wall.append(1e3 * (w2 - w1))
    sim.model, sim.state = model, state
    return coupled, cold, coupled_wall, cold_wall


def response_mb(fem_model):
    """Memory (MB) the slab's contact response keeps (fem.contact_response.ResponseCache)."""
    cache = fem_model.cache.response
    if cache is None:
        return 0.0
    return cache.nbytes / 2 ** 20


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


# the stages of the coupled step timed by --stages: (label, owner, attribute), each wrapped where
# hybrid.coupling.step (or the stage that calls it) looks it up
def _stage_names():
    from hybrid.coupling import solve as coupling_solve
    from hybrid.coupling import step as coupling_step
    from rigid import step as rigid_step
    from hybrid.app.peaks import Peaks
    from hybrid.app.resolution import ImpactWatch
    return (("back-substitution", fem_solver.Factorisation, "solve"),
            ("predict (with it)", coupling_step.fem_dyn, "predict"),
            ("surface nodes", coupling_step.SurfaceNodes, "of"),
            ("detection", coupling_step, "detect_all"),
            ("contact problem", coupling_step, "build_problem"),
            ("contact resolution", rigid_step, "resolve_contacts"),
            ("impulse response", coupling_solve, "apply_contact_impulses"),
            ("finish", coupling_step, "integrate"),
            ("held impulses", coupling_step.held, "hold_impulses"),
            ("resting watch", coupling_step.held, "watch"),
            ("finiteness check", coupling_step, "check_finite"),
            ("events", coupling_step, "between_steps"),
            ("coupled_step", coupling_step, "coupled_step"),
            # what Simulation.step adds to the coupled step: the run's watches
            ("run's peaks (Simulation.step)", Peaks, "update"),
            ("run's impact check (Simulation.step)", ImpactWatch, "check"))


def stage_us(sim, steps):
    """Median time (us, wall) of each stage of the coupled step (:func:`_stage_names`) over
    ``steps`` more steps, each taken right after reading COLD_BYTES of other memory (the caches
    cleared, as a step's own work leaves them for the next)."""
    names, spent, kept = _stage_names(), {}, []
    current = {}

    def timed(label, fn):
        def wrapper(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                current[label] = current.get(label, 0.0) + time.perf_counter() - t0
        return wrapper

    for label, owner, attribute in names:
        kept.append((owner, attribute, getattr(owner, attribute)))
        setattr(owner, attribute, timed(label, getattr(owner, attribute)))
    other = np.ones(COLD_BYTES // 8)
    try:
        for _ in range(steps):
            other.sum()
            current.clear()
            sim.step()
            for label, value in current.items():
                spent.setdefault(label, []).append(1e6 * value)
    finally:
        for owner, attribute, fn in kept:
            setattr(owner, attribute, fn)
    return {label: float(np.median(spent.get(label, [0.0]))) for label, _, _ in names}


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
    parser.add_argument("--frames", nargs="+", default=list(FRAMES), choices=FRAMES,
                        help="frames to run (default: both; the corotated goal is at ~10k tets)")
    parser.add_argument("--stages", action="store_true",
                        help="also time each stage of the coupled step (floating frame, CHOLMOD) over --steps more steps")
    parser.add_argument("--no-plastic", action="store_true",
                        help="skip the plastic-pass cost and dent reference updates (plastic_step.py)")
    args = parser.parse_args()
    sizes = args.sizes + ([50000] if args.big and 50000 not in args.sizes else [])

    rows, naive = [], {}
    for target in sizes:
        cells = slab_cells(target)
        for support in args.supports:
            for backend in args.backends:
                for frame in args.frames:
                    rows.append(measure_row(cells, frame, support, backend, naive, args))
                    print(f"  {rows[-1]['tets']} tets {support} {backend} {frame}: coupled step "
                          f"{rows[-1]['coupled_ms']:.2f} ms, cold floor {rows[-1]['cold_floor_ms']:.2f} ms, "
                          f"first step {rows[-1]['first_s']:.2f} s (box z {rows[-1]['box_z']:.4f} m, slab min z "
                          f"{rows[-1]['slab_min_z']:.2e} m, {rows[-1]['held_nodes']} nodes held)",
                          flush=True)
    report(rows, args)
    if not args.no_plastic:
        print("\nplastic pass (benchmarks/plastic_step.py): goal under 30% extra over the elastic step")
        import plastic_step
        plastic_step.main()


def measure_row(cells, frame, support, backend, naive_by_size, args):
    model, state, r = measure(cells, frame, support, backend, args.steps, args.warmup,
                              args.stages and frame == "floating" and backend == "cholmod")
    m = model.fem[0]
    s = state.fem[0]
    if (cells, support) not in naive_by_size:     # the naive step does not depend on the backend
        naive_by_size[cells, support] = median_ms(
            lambda: naive_step(m.rest_points, m.tets, s.x, s.v, model.gravity), args.naive_steps)[0]
    naive = naive_by_size[cells, support]
    row = dict(tets=m.tet_count, nodes=m.node_count, dofs=3 * m.node_count, support=support,
               backend=backend, frame=frame, **r, naive_ms=naive)
    row["coupled_over_cold_floor"] = row["coupled_ms"] / row["cold_floor_ms"]
    row["wall_coupled_over_cold_floor"] = row["coupled_wall_ms"] / row["cold_wall_ms"]
    row["coupled_over_floor"] = row["coupled_ms"] / row["floor_ms"]
    row["step_over_floor"] = row["step_ms"] / row["floor_ms"]
    row["step_over_cold_floor"] = row["step_ms"] / row["cold_floor_ms"]
    row["elastic_over_floor"] = row["elastic_ms"] / row["floor_ms"]
    row["naive_over_coupled"] = naive / row["coupled_ms"]
    row["naive_over_elastic"] = naive / row["elastic_ms"]
    return row


def size_label(tets):
    """The goal's name for a slab of ``tets`` tets: ``10k``, ``50k`` (the nearest of the sizes the
    goals name), else the count itself."""
    for label, target in (("10k", 10000), ("50k", 50000)):
        if abs(tets - target) <= 0.2 * target:
            return label
    return str(tets)


def goal_line(name, measured, target, smaller=True):
    """A goal as scripts read it: ``GOAL <name>: measured=<value> target=<value> met|not met``."""
    met = measured <= target if smaller else measured >= target
    return f"GOAL {name}: measured={measured:.2f} target={target:.1f} {'met' if met else 'not met'}"


def goals(rows):
    """The GOAL lines of issue 24 for the sizes measured (CHOLMOD rows)."""
    lines = []
    chol = [r for r in rows if r["backend"] == "cholmod"]
    for label, target in (("10k", 2.0), ("50k", 1.5)):
        for support in SUPPORTS:
            found = [r for r in chol if size_label(r["tets"]) == label and r["support"] == support
                     and r["frame"] == "floating"]
            if found:
                lines.append(goal_line(f"coupled_step_{label}_{support}_vs_cold_floor",
                                       found[0]["coupled_over_cold_floor"], target))
    corotated = [r for r in chol if size_label(r["tets"]) == "10k" and r["frame"] == "corotated"]
    if corotated:
        worst = max(r["coupled_over_cold_floor"] for r in corotated)
        lines.append(goal_line("corotated_step_10k_vs_cold_floor", worst, 3.0))
    first = [r["first_s"] for r in chol if size_label(r["tets"]) == "50k" and r["support"] == "ground"]
    if first:
        lines.append(goal_line("first_contact_50k_seconds", float(np.median(first)), 5.0))
    return lines


def report(rows, args):
    header = (f"{'tets':>6} {'dofs':>6} {'support':>8} {'backend':>8} {'frame':>9} {'first s':>7} {'resp MB':>7} "
              f"{'coupled':>8} {'step ms':>8} {'elastic':>8} {'floor ms':>8} {'cold':>6} {'in-step':>7} "
              f"{'naive ms':>9} {'coupled/cold':>12} {'(wall)':>6} {'coupled/floor':>13} {'naive/coupled':>13}")
    print(f"\nmedians; coupled step (advance) and cold floor side by side (CPU time) over {args.steps} steps after "
          f"{args.warmup} warm-up, Simulation.step over {args.steps} more, floor over 20 solves, naive "
          f"over {args.naive_steps} steps; dt = {DT} s; times in ms unless marked")
    print(header)
    for r in rows:
        print(f"{r['tets']:>6} {r['dofs']:>6} {r['support']:>8} {r['backend']:>8} {r['frame']:>9} "
              f"{r['first_s']:>7.2f} {r['response_mb']:>7.1f} {r['coupled_ms']:>8.2f} {r['step_ms']:>8.2f} "
              f"{r['elastic_ms']:>8.2f} {r['floor_ms']:>8.2f} {r['cold_floor_ms']:>6.2f} "
              f"{r['solve_in_step_ms']:>7.2f} {r['naive_ms']:>9.1f} {r['coupled_over_cold_floor']:>12.2f} "
              f"{r['wall_coupled_over_cold_floor']:>6.2f} "
              f"{r['coupled_over_floor']:>13.2f} {r['naive_over_coupled']:>13.1f}")

    print("\nother goals")
    for r in rows:
        if 5000 <= r["tets"] <= 20000:
            print(f"  {r['tets']} tets {r['support']} {r['backend']} {r['frame']} >= 20x faster than naive: coupled "
                  f"{r['naive_over_coupled']:.1f}x ({'met' if r['naive_over_coupled'] >= 20 else 'NOT met'}), "
                  f"elastic-only {r['naive_over_elastic']:.1f}x "
                  f"({'met' if r['naive_over_elastic'] >= 20 else 'NOT met'})")
    staged = [r for r in rows if r["stages"] is not None]
    if staged:
        print("\nstages of the coupled step (us, medians, wall; each step after reading "
              f"{COLD_BYTES // 2 ** 20} MB of other memory; predict includes the back-substitution)")
        width = max(len(label) for label in staged[0]["stages"])
        print(f"{'stage':>{width}} " + " ".join(f"{str(r['tets']) + ' ' + r['support']:>16}" for r in staged))
        for label in staged[0]["stages"]:
            print(f"{label:>{width}} " + " ".join(f"{r['stages'][label]:>16.0f}" for r in staged))
    print()
    for line in goals(rows):
        print(line)
    write_csv(CSV_PATH, [{k: v for k, v in r.items() if k != "stages"} for r in rows])
    print(f"wrote {CSV_PATH}")


if __name__ == "__main__":
    main()
