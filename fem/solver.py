"""Sparse SPD solves: a cached factorisation of the system matrix, and warm-started CG.

Two backends, measured in ``benchmarks/fem_solver.py``:
- ``"cholmod"``: supernodal Cholesky (SuiteSparse's CHOLMOD, through the self-contained
  ``cholespy`` wheel); on the 10k-tet slab it factors about 2x and solves about 3x faster than
  SuperLU, also for many right-hand sides at once (the contact response columns);
- ``"superlu"``: scipy's SuperLU (``splu``), which needs nothing beyond scipy; used when cholespy is
  not installed (:func:`available_linear_solver`), when the matrix is not positive definite for
  CHOLMOD, or when chosen.
A body's backend is a setting of its model (``fem.model.build_fem_model(..., linear_solver=...)``).
"""
import time
import warnings

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

try:
    from cholespy import CholeskySolverD, MatrixType
except ImportError:            # pure-scipy fallback
    CholeskySolverD = None

# the sparse solver backends a model may name (FemModel.linear_solver)
LINEAR_SOLVERS = ("cholmod", "superlu")
# SuperLU column ordering; MMD on A^T+A suits symmetric matrices (measured in benchmarks/fem_solver.py)
PERMC_SPEC = "MMD_AT_PLUS_A"
# one CHOLMOD back-substitution takes as long as a dense product reading about this many entries
# per nonzero of the matrix (measured 20-49 on P1 slabs and cubes of 1k-48k tets)
CHOLMOD_SOLVE_COST_PER_NNZ = 30


def available_linear_solver(name):
    """The backend to use for the chosen ``name`` (one of :data:`LINEAR_SOLVERS`): ``name`` itself,
    or ``"superlu"`` when ``name`` is ``"cholmod"`` and cholespy is not importable (with a
    warning, shown once per calling line). Raises ValueError for an unknown name."""
    if name not in LINEAR_SOLVERS:
        raise ValueError(f"unknown sparse solver backend {name!r}: 'cholmod' or 'superlu'")
    if name == "cholmod" and CholeskySolverD is None:
        warnings.warn("linear_solver 'cholmod' needs the cholespy package (pip install cholespy); "
                      "using 'superlu' (scipy's SuperLU) instead", RuntimeWarning, stacklevel=3)
        return "superlu"
    return name


class Factorisation:
    """Factorisation of a sparse SPD matrix, reused for every solve until the matrix changes.

    matrix: the CSC matrix factorised ``(m, m)``. solve(rhs) accepts ``(m,)`` or ``(m, k)``.
    backend: ``"cholmod"`` or ``"superlu"`` (:data:`LINEAR_SOLVERS`); CHOLMOD falls back to SuperLU
    for a matrix it finds not positive definite (``backend`` then reads ``"superlu"``); a ``(0, 0)``
    matrix (a body whose every node is anchored) reads ``"empty"`` and solves to empty arrays.
    solve_cost: the time of one back-substitution, in entries of a dense matrix-vector product
    (SuperLU: the nonzeros of L and U it reads); callers compare it with products they could use
    instead.
    """

    def __init__(self, matrix, backend):
        self.matrix = sp.csc_matrix(matrix)
        self.backend = backend
        if self.backend not in LINEAR_SOLVERS:
            raise ValueError(f"unknown sparse solver backend {self.backend!r}: 'cholmod' or 'superlu'")
        if self.matrix.shape[0] == 0:
            # nothing to solve (every node of the body anchored): CHOLMOD given an empty matrix
            # corrupted the heap and killed the process later
            self.backend, self.solve_cost = "empty", 0
            return
        if self.backend == "cholmod":
            if CholeskySolverD is None:
                raise ImportError("the 'cholmod' backend needs the cholespy package (pip install cholespy)")
            try:
                self._factor_cholmod()
                return
            except ValueError as error:     # not positive definite to CHOLMOD: pivoting LU instead
                warnings.warn(f"CHOLMOD: {error}; using SuperLU for this matrix", RuntimeWarning)
                self.backend = "superlu"
        # symmetric positive definite: no pivoting needed, keep the fill-reducing ordering
        self._lu = spla.splu(self.matrix, permc_spec=PERMC_SPEC, diag_pivot_thresh=0.0,
                             options={"SymmetricMode": True})
        self.solve_cost = int(self._lu.L.nnz + self._lu.U.nnz)

    def _factor_cholmod(self):
        A = self.matrix
        A.sort_indices()
        self._chol = CholeskySolverD(A.shape[0], A.indptr.astype(np.int32), A.indices.astype(np.int32),
                                     np.ascontiguousarray(A.data, dtype=float), MatrixType.CSC)
        self.solve_cost = int(CHOLMOD_SOLVE_COST_PER_NNZ * A.nnz)

    def solve(self, rhs):
        """The solution of ``matrix x = rhs`` for ``rhs`` ``(m,)`` or ``(m, k)`` (k right-hand sides)."""
        rhs = np.asarray(rhs, dtype=float)
        if self.backend == "empty":
            return rhs.copy()
        if self.backend == "superlu":
            return self._lu.solve(rhs)
        rhs = np.ascontiguousarray(rhs)
        out = np.empty_like(rhs)
        self._chol.solve(rhs, out)
        return out


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
        self.seconds = 0.0       # wall time of the last factorisation (s)
        self.matrix_dt = None
        self.matrix = None       # the whole system matrix for matrix_dt (anchored bodies use it)
        self._derived = {}       # parts of that matrix, see derived()

    def get(self, dt, build_matrix, backend):
        """Factorisation for ``dt``; ``build_matrix(dt)`` returns the sparse matrix to factorise with
        ``backend`` (the model's ``linear_solver``, the same for every call)."""
        if self.factorisation is None or self.dt != dt:
            start = time.perf_counter()
            self.factorisation = Factorisation(build_matrix(dt), backend)
            self.seconds = time.perf_counter() - start
            self.dt = dt
            self.factor_count += 1
        return self.factorisation

    def system(self, dt, build_matrix):
        """The system matrix for ``dt`` (``build_matrix(dt)``), built once per ``dt``."""
        if self.matrix is None or self.matrix_dt != dt:
            self.matrix, self.matrix_dt = build_matrix(dt), dt
            self._derived = {}
        return self.matrix

    def derived(self, key, build):
        """``build()``, a part of the current system matrix (e.g. its anchored columns), kept until
        the matrix changes."""
        if key not in self._derived:
            self._derived[key] = build()
        return self._derived[key]

    def invalidate(self):
        """Forget the factorisation (the matrix changed); the next use factorises again."""
        self.factorisation = None
        self.dt = None
        self.matrix = None
        self.matrix_dt = None
        self._derived = {}


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
