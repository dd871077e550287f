"""Dense Cholesky factor and solve of a small symmetric positive semi-definite system whose
dependent columns are dropped (rigid.coarse's coarse systems)."""
import math

import numba as nb
import numpy as np


@nb.njit(cache=True)
def cholesky(A, drop):
    """Lower Cholesky factor of the symmetric positive semi-definite A (M, M); a column whose
    pivot is below ``drop`` of its diagonal (a mode the others already span) is dropped
    (zero column, its unknown held at 0)."""
    M = len(A)
    L = np.zeros((M, M))
    for c in range(M):
        d = A[c, c]
        for p in range(c):
            d -= L[c, p] * L[c, p]
        if not d > drop * A[c, c] or not d > 0.0:
            continue
        L[c, c] = math.sqrt(d)
        for r in range(c + 1, M):
            s = A[r, c]
            for p in range(c):
                s -= L[r, p] * L[c, p]
            L[r, c] = s / L[c, c]
    return L


@nb.njit(cache=True)
def solve_factored(L, b):
    """y with L L^T y = b over the kept columns (dropped ones 0)."""
    M = len(L)
    z = np.zeros(M)
    for r in range(M):
        if L[r, r] == 0.0:
            continue
        s = b[r]
        for p in range(r):
            s -= L[r, p] * z[p]
        z[r] = s / L[r, r]
    y = np.zeros(M)
    for r in range(M - 1, -1, -1):
        if L[r, r] == 0.0:
            continue
        s = z[r]
        for p in range(r + 1, M):
            s -= L[p, r] * y[p]
        y[r] = s / L[r, r]
    return y
