"""Sparse SPD solves: a cached factorisation of the system matrix, and warm-started CG.

The backend is scipy's SuperLU (``splu``), which needs nothing beyond scipy. Measurements behind the
choice of ordering and backend are in ``benchmarks/fem_solver.py``.
"""
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

# SuperLU column ordering; MMD on A^T+A suits symmetric matrices (measured in benchmarks/fem_solver.py)
PERMC_SPEC = "MMD_AT_PLUS_A"


class Factorisation:
    """LU factorisation of a sparse SPD matrix, reused for every solve until the matrix changes.

    matrix: the CSC matrix factorised ``(m, m)``. solve(rhs) accepts ``(m,)`` or ``(m, k)``.
    solve_cost: entries of the factors one back-substitution reads (nnz of L and U).
    """

    def __init__(self, matrix):
        self.matrix = sp.csc_matrix(matrix)
        # symmetric positive definite: no pivoting needed, keep the fill-reducing ordering
        self._lu = spla.splu(self.matrix, permc_spec=PERMC_SPEC, diag_pivot_thresh=0.0,
                             options={"SymmetricMode": True})
        self.solve_cost = int(self._lu.L.nnz + self._lu.U.nnz)

    def solve(self, rhs):
        return self._lu.solve(np.asarray(rhs, dtype=float))


class FactorCache:
    """Holds the factorisation of the system matrix for one time step size.

    A model owns one cache; it refactorises only when asked for a different ``dt`` (or after
    :meth:`invalidate`, called by events that change the matrix). ``factor_count`` counts
    factorisations so tests can check that a floating-frame body factorises once.
    """

    def __init__(self):
        self.dt = None
        self.factorisation = None
        self.factor_count = 0
        self.matrix_dt = None
        self.matrix = None       # the whole system matrix for matrix_dt (anchored bodies use it)

    def get(self, dt, build_matrix):
        """Factorisation for ``dt``; ``build_matrix(dt)`` returns the sparse matrix to factorise."""
        if self.factorisation is None or self.dt != dt:
            self.factorisation = Factorisation(build_matrix(dt))
            self.dt = dt
            self.factor_count += 1
        return self.factorisation

    def system(self, dt, build_matrix):
        """The system matrix for ``dt`` (``build_matrix(dt)``), built once per ``dt``."""
        if self.matrix is None or self.matrix_dt != dt:
            self.matrix, self.matrix_dt = build_matrix(dt), dt
        return self.matrix

    def invalidate(self):
        self.factorisation = None
        self.dt = None
        self.matrix = None
        self.matrix_dt = None


def cg_solve(matrix, rhs, x0, preconditioner, rtol=1e-10, maxiter=500):
    """Conjugate gradients on an SPD matrix from a warm start; returns ``(x, iterations)``.

    preconditioner: callable ``r -> z`` approximating ``matrix^-1 r``.
    """
    count = [0]

    def callback(_):
        count[0] += 1

    M = spla.LinearOperator(matrix.shape, matvec=preconditioner, dtype=float)
    x, info = spla.cg(matrix, rhs, x0=x0, rtol=rtol, atol=0.0, maxiter=maxiter, M=M, callback=callback)
    if info > 0:
        raise RuntimeError(f"CG did not converge in {maxiter} iterations")
    return x, count[0]
