"""Sparse solver timings for the FEM system matrix M + h^2 K at ~10k tets.

Prints a table (backend, what, seconds) and writes outputs/bench_fem_solver.csv. Run:
    OPENBLAS_NUM_THREADS=1 python benchmarks/fem_solver.py
"""
import csv
import os
import time

import numpy as np
import scipy.sparse.linalg as spla

from fem import solver
from fem.dynamics import predict, step, system_matrix, warped_stiffness
from fem.mesh import box_tet_mesh
from fem.model import build_fem_model, rest_state
from fem.rotations import tet_rotations


COLUMNS = 300


def timed(fn, repeat=1):
    t0 = time.perf_counter()
    for _ in range(repeat):
        out = fn()
    return (time.perf_counter() - t0) / repeat, out


def main():
    rows = []
    points, tets = box_tet_mesh((1.0, 0.5, 0.5), (20, 9, 9))
    dt = 0.01
    t_build, model = timed(lambda: build_fem_model(points, tets, density=1000.0, young=1e6,
                                                   poisson=0.3, frame="corotated"))
    rows.append(("build_fem_model P1", f"{len(tets)} tets", t_build))
    A = system_matrix(model, dt).tocsc()
    rhs = np.random.default_rng(0).standard_normal(A.shape[0])
    for spec in ["MMD_AT_PLUS_A", "COLAMD"]:
        t_f, lu = timed(lambda: spla.splu(A, permc_spec=spec, diag_pivot_thresh=0.0,
                                          options={"SymmetricMode": True}))
        t_s, _ = timed(lambda: lu.solve(rhs), 20)
        rows += [(f"splu {spec}", "factor", t_f), (f"splu {spec}", "solve", t_s)]
    # the project's backends (fem.solver.Factorisation): factor, one solve, and the per-column cost
    # of COLUMNS right-hand sides at once (the contact response columns of fem/contact_response.py)
    many = np.zeros((A.shape[0], COLUMNS))
    many[3 * np.arange(COLUMNS), np.arange(COLUMNS)] = 1.0
    for backend in ["superlu", "cholmod"]:
        if backend == "cholmod" and solver.CholeskySolverD is None:
            rows.append(("cholmod", "cholespy not installed", float("nan")))
            continue
        t_f, fact = timed(lambda: solver.Factorisation(A, backend=backend))
        t_s, _ = timed(lambda: fact.solve(rhs), 20)
        t_m, _ = timed(lambda: fact.solve(many), 2)
        rows += [(backend, "factor", t_f), (backend, "solve", t_s),
                 (backend, f"solve {COLUMNS} columns, per column", t_m / COLUMNS)]
    # corotated step: warped assembly, then LU refactor vs CG preconditioned by the rest factorisation
    state = rest_state(model, v=np.cross([0.0, 0.0, 5.0], points))
    for _ in range(3):
        state = step(model, state, dt)
    t_R, tet_R = timed(lambda: tet_rotations(model, state.x), 5)
    t_K, K = timed(lambda: warped_stiffness(model, tet_R), 5)
    rows += [("corotated", "tet rotations (batched SVD)", t_R), ("corotated", "warped assembly", t_K)]
    for method in ["lu", "cg"]:
        # the same body with this corotated_solver setting, its rest system factorised before timing
        variant = build_fem_model(points, tets, density=1000.0, young=1e6, poisson=0.3,
                                  frame="corotated", corotated_solver=method, dt=dt)
        t_p, s = timed(lambda: predict(variant, state, dt), 3)
        rows.append((f"corotated predict {method}", f"iterations {s.iterations[0]}", t_p))
    floating = build_fem_model(points, tets, density=1000.0, young=1e6, poisson=0.3, dt=dt)
    fstate = rest_state(floating, v=state.v)
    t_p, _ = timed(lambda: predict(floating, fstate, dt), 5)
    rows.append(("floating predict", "prefactored", t_p))
    for row in rows:
        print(f"{row[0]:32s} {row[1]:28s} {row[2]:9.4f} s")
    os.makedirs("outputs", exist_ok=True)
    with open("outputs/bench_fem_solver.csv", "w", newline="") as f:
        csv.writer(f).writerows([("backend", "what", "seconds")] + rows)


if __name__ == "__main__":
    main()
