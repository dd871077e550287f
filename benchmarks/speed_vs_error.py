"""Speed against accuracy: the steel cantilever run dynamically to rest, per element order and frame.

Beam 1 m x 0.1 m x 0.1 m along x, steel (E = 2e11 Pa, nu = 0.3, 7800 kg/m^3), clamped at x = 0
by an anchor (all nodes of that face held still), 1 kN downward load on the x = 1 face (a load
region, spread by lumped mass). Meshes: ``fem.mesh.box_tet_mesh`` with (c, c/10, c/10) cells, six
tets per cell; order 2 adds midside nodes (``fem.mesh.quadratic_tets``).

Dynamics: backward Euler, dt = 1 ms, stiffness-proportional damping beta = 2e-4 s, the load applied
suddenly at t = 0 and ``--seconds`` (default 0.2 s, 200 steps) simulated from rest. The first
bending period is 12 ms, so 0.2 s is ~16 periods; backward Euler at this dt alone damps that mode by
~11 % a step, so the beam is at rest long before the end. ``settled`` in the table is the final tip
deflection over the static solve on the same mesh (``fem.static.static_displacement``): 1 means the
dynamic run reached the discrete static answer, so the error is discretisation error.

Error: mean vertical displacement of the x = 1 nodes against Timoshenko beam theory
PL^3/(3EI) + PL/(kappa G A), kappa = 5/6 (2.016e-4 m).
Speed: wall time per simulated second = median wall time of one step (over all the run's steps
after the first ``WARMUP``) / dt. Model build (assembly, factorisation) is reported separately.

    OPENBLAS_NUM_THREADS=1 python benchmarks/speed_vs_error.py [--big] [--seconds 0.2]

Prints the table, writes outputs/bench/speed_vs_error.csv and a log-log plot of error against
wall time per simulated second (one line per order and frame) to outputs/bench/speed_vs_error.png.
Default: P1 at 10, 20, 40, 80 cells along the beam and P2 at 5, 10, 20, 40 (up to ~31k tets or
~20k DOFs; about 3 minutes on two shared cores); ``--big`` adds P1 at 120 and P2 at 60 cells
(~61k DOFs; the corotated runs take several minutes each).
"""
import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from fem.dynamics import step
from fem.mesh import box_tet_mesh, quadratic_tets, select_nodes_in_box
from fem.model import build_fem_model, rest_state
from fem.static import static_displacement

from _common import write_csv

LENGTH, SIDE = 1.0, 0.1
E, NU, RHO, LOAD = 2e11, 0.3, 7800.0, 1000.0
AREA, INERTIA = SIDE**2, SIDE**4 / 12
SHEAR_MODULUS = E / (2 * (1 + NU))
TIP_THEORY = LOAD * LENGTH**3 / (3 * E * INERTIA) + LOAD * LENGTH / (5 / 6 * SHEAR_MODULUS * AREA)
DT = 1e-3
DAMPING_STIFFNESS = 2e-4    # s
WARMUP = 3                  # steps left out of the per-step median (first-call overheads)
FRAMES = ("floating", "corotated")
CELLS = {1: [10, 20, 40, 80], 2: [5, 10, 20, 40]}
CELLS_BIG = {1: [120], 2: [60]}
CSV_PATH = Path("outputs/bench/speed_vs_error.csv")
PNG_PATH = Path("outputs/bench/speed_vs_error.png")


def cantilever(order, cells, frame):
    """Model (factorised for DT) and the tip node indices of the beam with ``cells`` along x."""
    across = max(1, cells // 10)
    points, tets = box_tet_mesh((LENGTH, SIDE, SIDE), (cells, across, across))
    points = points + [0.5 * LENGTH, 0.0, 0.0]
    if order == 2:
        points, tets = quadratic_tets(points, tets)
    clamp = select_nodes_in_box(points, [-1, -1, -1], [0, 1, 1])
    tip = select_nodes_in_box(points, [LENGTH, -1, -1], [2, 1, 1])
    model = build_fem_model(points, tets, order=order, density=RHO, young=E, poisson=NU,
                            damping_stiffness=DAMPING_STIFFNESS, frame=frame,
                            anchors=[(clamp, [0, 0, 0])], loads=[(tip, [0, 0, -LOAD])], dt=DT)
    return model, tip


def run(order, cells, frame, seconds):
    t0 = time.perf_counter()
    model, tip = cantilever(order, cells, frame)
    build_s = time.perf_counter() - t0
    state = rest_state(model)
    times = []
    for _ in range(int(round(seconds / DT))):
        t0 = time.perf_counter()
        state = step(model, state, DT)
        times.append(time.perf_counter() - t0)
    tip_deflection = -(state.x - model.rest_points)[tip, 2].mean()
    static_tip = -static_displacement(model)[tip, 2].mean()
    step_s = float(np.median(times[WARMUP:]))
    return dict(order=order, frame=frame, cells=cells, tets=model.tet_count, nodes=model.node_count,
                dofs=3 * model.node_count, tip_m=tip_deflection, theory_m=TIP_THEORY,
                error=abs(tip_deflection / TIP_THEORY - 1), settled=tip_deflection / static_tip,
                step_ms=1e3 * step_s, wall_per_sim_s=step_s / DT,
                run_wall_per_sim_s=sum(times) / seconds, build_s=build_s)


def plot(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    for order, color in ((1, "C0"), (2, "C3")):
        for frame, style in zip(FRAMES, ("-o", "--s")):
            sel = [r for r in rows if r["order"] == order and r["frame"] == frame]
            if not sel:
                continue
            ax.loglog([r["wall_per_sim_s"] for r in sel], [r["error"] for r in sel], style,
                      color=color, label=f"P{order} {frame}")
            for r in sel:
                ax.annotate(f"{r['tets']}", (r["wall_per_sim_s"], r["error"]), fontsize=7,
                            textcoords="offset points", xytext=(4, 3))
    ax.set_xlabel("wall time per simulated second (s), dt = 1 ms")
    ax.set_ylabel("|tip deflection / beam theory - 1|")
    ax.set_title("Steel cantilever, 1 kN tip load (labels: tets)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--big", action="store_true", help="add P1 at 120 and P2 at 60 cells")
    parser.add_argument("--seconds", type=float, default=0.2, help="simulated time per run (s)")
    args = parser.parse_args()
    rows = []
    for order in (1, 2):
        cells_list = CELLS[order] + (CELLS_BIG[order] if args.big else [])
        for cells in cells_list:
            for frame in FRAMES:
                r = run(order, cells, frame, args.seconds)
                rows.append(r)
                print(f"  P{order} {cells} cells {frame}: error {r['error']:.3g}, "
                      f"{r['wall_per_sim_s']:.2f} s/sim-s", flush=True)

    print(f"\ntheory tip deflection {TIP_THEORY:.5e} m; dt = {DT} s, {args.seconds} s simulated per run, "
          f"beta = {DAMPING_STIFFNESS} s; wall per sim-s = median step time / dt")
    print(f"{'order':>5} {'frame':>9} {'cells':>5} {'tets':>6} {'dofs':>6} {'tip m':>11} {'error':>9} "
          f"{'settled':>8} {'step ms':>8} {'wall/sim-s':>10} {'build s':>8}")
    for r in rows:
        print(f"{r['order']:>5} {r['frame']:>9} {r['cells']:>5} {r['tets']:>6} {r['dofs']:>6} "
              f"{r['tip_m']:>11.5e} {r['error']:>9.2e} {r['settled']:>8.4f} {r['step_ms']:>8.2f} "
              f"{r['wall_per_sim_s']:>10.3f} {r['build_s']:>8.2f}")
    write_csv(CSV_PATH, rows)
    plot(rows, PNG_PATH)
    print(f"wrote {CSV_PATH} and {PNG_PATH}")


if __name__ == "__main__":
    main()
