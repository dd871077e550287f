"""Shape matching: batched polar decomposition and the best-fit rigid frame of a point cloud.

Mueller, Heidelberger, Teschner, Gross 2005, "Meshless deformations based on shape matching":
the rotation that best maps rest offsets ``X - X_c`` onto current offsets ``x - c`` (mass-weighted
least squares) is the rotational part of ``A_pq = sum_i m_i (x_i - c)(X_i - X_c)^T`` (eq. 7).

:func:`rotation_of` (the per-step stiffness-warping rotations of every tet) runs a numba kernel:
a one-sided Jacobi SVD (Hestenes 1958) of each 3x3 matrix, vectorised over blocks of matrices.
It gives the same rotation as the batched LAPACK SVD of :func:`polar_decomposition` to ~1e-13,
about 50x faster for 10,000 matrices.

The kernel: plane rotations ``V`` of the columns of ``G = F V`` until they are mutually orthogonal
(cos^2 < ``_ORTHO_TOL2``), so ``G = U diag(s)`` with ``s`` the column norms (the singular values, to
the relative accuracy of the SVD; ``F^T F``, which squares the condition number, is never formed).
Columns sorted by norm: ``v1, v2`` the two largest, ``v3 = v1 x v2`` (``V`` proper);
``u1 = g1 / |g1|``, ``u2`` = ``g2`` orthogonalised against ``u1`` and normalised (for rank <= 1,
where any unit vector orthogonal to ``u1`` will do, ``v2`` or ``v3`` instead), ``u3 = u1 x u2``;
``R = U V^T``. With ``U`` and ``V`` both proper, ``F v3 = +-s3 u3`` with the sign of ``det F``: the
least significant singular pair is flipped exactly when ``F`` is inverted. ``F = 0`` gives
``U = V``, ``R = I``. Each matrix is first scaled by its largest entry (no overflow or underflow of
squares). NaN or inf in ``F[e]`` gives NaN in ``R[e]``.
"""
import math

import numba as nb
import numpy as np

_BLOCK = 128  # matrices per block: the Jacobi loops run (SIMD) over the matrices of a block
_ORTHO_TOL2 = 1e-30  # columns count as orthogonal when cos^2 of their angle is below this
_TINY = 1e-300
_FASTMATH = {"contract"}  # fused multiply-add only: no reassociation, NaN and inf kept


def polar_decomposition(F):
    """Polar decomposition ``F = R S`` of a batch of 3x3 matrices.

    F: ``(..., 3, 3)``. Returns ``R`` ``(..., 3, 3)``, a proper rotation (det +1), and ``S``
    ``(..., 3, 3)``, symmetric. ``S`` is positive semi-definite when ``det F >= 0``; for an
    inverted ``F`` the sign of the smallest singular direction is moved into ``S`` so that ``R``
    stays a rotation (as in stiffness warping of inverted tets). One batched SVD.
    """
    F = np.asarray(F, dtype=float)
    U, s, Vt = np.linalg.svd(F)
    # flip the least significant singular pair when U V^T would be a reflection
    d = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    d = np.where(d == 0, 1.0, d)
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    s = s.copy()
    s[..., 2] *= d
    R = U @ Vt
    S = np.einsum("...ki,...k,...kj->...ij", Vt, s, Vt)
    return R, S


@nb.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _jacobi_pair(G, V, p, q, n):
    """One-sided Jacobi rotation of columns ``p < q`` of the block ``G`` ``(3, 3, B)`` (row, column,
    matrix), for its first ``n`` matrices: the plane rotation that makes the two columns orthogonal,
    applied to the columns of ``G`` and of the accumulated right factor ``V``."""
    for i in range(n):
        a = G[0, p, i] * G[0, p, i] + G[1, p, i] * G[1, p, i] + G[2, p, i] * G[2, p, i]
        b = G[0, q, i] * G[0, q, i] + G[1, q, i] * G[1, q, i] + G[2, q, i] * G[2, q, i]
        g = G[0, p, i] * G[0, q, i] + G[1, p, i] * G[1, q, i] + G[2, p, i] * G[2, q, i]
        # symmetric Schur rotation of the 2x2 Gram matrix [[a, g], [g, b]] (the smaller angle):
        # tan = 2 g sign(d) / D with D = |d| + sqrt(d^2 + 4 g^2), cos = D / sqrt(D^2 + 4 g^2)
        d = b - a
        D = max(abs(d) + math.sqrt(d * d + 4.0 * g * g), 1e-150)  # g = d = 0 gives the identity
        r = 1.0 / math.sqrt(D * D + 4.0 * g * g)
        c = D * r
        s = math.copysign(2.0, d) * g * r
        for k in range(3):
            x = G[k, p, i]
            y = G[k, q, i]
            G[k, p, i] = c * x - s * y
            G[k, q, i] = s * x + c * y
            x = V[k, p, i]
            y = V[k, q, i]
            V[k, p, i] = c * x - s * y
            V[k, q, i] = s * x + c * y


@nb.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _not_orthogonal(G, n):
    """Number of column pairs of the first ``n`` matrices of ``G`` ``(3, 3, B)`` that are not yet
    orthogonal (``cos^2 > _ORTHO_TOL2``); zero columns count as orthogonal to anything."""
    count = 0
    for i in range(n):
        a0 = G[0, 0, i] * G[0, 0, i] + G[1, 0, i] * G[1, 0, i] + G[2, 0, i] * G[2, 0, i]
        a1 = G[0, 1, i] * G[0, 1, i] + G[1, 1, i] * G[1, 1, i] + G[2, 1, i] * G[2, 1, i]
        a2 = G[0, 2, i] * G[0, 2, i] + G[1, 2, i] * G[1, 2, i] + G[2, 2, i] * G[2, 2, i]
        g01 = G[0, 0, i] * G[0, 1, i] + G[1, 0, i] * G[1, 1, i] + G[2, 0, i] * G[2, 1, i]
        g02 = G[0, 0, i] * G[0, 2, i] + G[1, 0, i] * G[1, 2, i] + G[2, 0, i] * G[2, 2, i]
        g12 = G[0, 1, i] * G[0, 2, i] + G[1, 1, i] * G[1, 2, i] + G[2, 1, i] * G[2, 2, i]
        count += ((g01 * g01 > _ORTHO_TOL2 * a0 * a1) + (g02 * g02 > _ORTHO_TOL2 * a0 * a2)
                  + (g12 * g12 > _ORTHO_TOL2 * a1 * a2))
    return count


@nb.njit(cache=True, error_model="numpy", inline="always")
def _first_two(x0, x1, x2, one_over_zero, two_first, two_second):
    """``(x[j0], x[j1])`` where ``j0, j1`` index the largest and second largest of three keys,
    given the comparisons ``k1 > k0``, ``k2 > max(k0, k1)`` and ``k2 > min(k0, k1)`` (no branches)."""
    big01 = x1 if one_over_zero else x0
    small01 = x0 if one_over_zero else x1
    first = x2 if two_first else big01
    second = big01 if two_first else (x2 if two_second else small01)
    return first, second


@nb.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _load_block(F, b0, n, G, V, scale):
    """Matrices ``b0 .. b0 + n - 1`` of ``F`` into the block ``G`` ``(3, 3, B)`` (row, column,
    matrix), each scaled by its largest entry (no overflow or underflow of squares); ``V = I``."""
    for i in range(n):
        for k in range(3):
            for j in range(3):
                G[k, j, i] = F[b0 + i, k, j]
    for i in range(n):
        scale[i] = 1.0 / max(abs(G[0, 0, i]), abs(G[0, 1, i]), abs(G[0, 2, i]),
                             abs(G[1, 0, i]), abs(G[1, 1, i]), abs(G[1, 2, i]),
                             abs(G[2, 0, i]), abs(G[2, 1, i]), abs(G[2, 2, i]), _TINY)
    for k in range(3):
        for j in range(3):
            for i in range(n):
                G[k, j, i] *= scale[i]
                V[k, j, i] = 1.0 if k == j else 0.0


@nb.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _orthogonalise(G, V, n):
    """Cyclic Jacobi sweeps over the three column pairs of the block until its columns are
    mutually orthogonal; typically 3-4 (quadratic convergence), at most 30."""
    for sweep in range(30):
        if _not_orthogonal(G, n) == 0:
            break
        _jacobi_pair(G, V, 0, 1, n)
        _jacobi_pair(G, V, 0, 2, n)
        _jacobi_pair(G, V, 1, 2, n)


@nb.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _store_rotation(u1, u2, u3, v1, v2, v3, Rb, i):
    """``Rb[:, :, i] = U V^T`` with ``U = [u1 u2 u3]``, ``V = [v1 v2 v3]`` (columns, (x, y, z) each)."""
    u1x, u1y, u1z = u1
    u2x, u2y, u2z = u2
    u3x, u3y, u3z = u3
    v1x, v1y, v1z = v1
    v2x, v2y, v2z = v2
    v3x, v3y, v3z = v3
    Rb[0, 0, i] = u1x * v1x + u2x * v2x + u3x * v3x
    Rb[0, 1, i] = u1x * v1y + u2x * v2y + u3x * v3y
    Rb[0, 2, i] = u1x * v1z + u2x * v2z + u3x * v3z
    Rb[1, 0, i] = u1y * v1x + u2y * v2x + u3y * v3x
    Rb[1, 1, i] = u1y * v1y + u2y * v2y + u3y * v3y
    Rb[1, 2, i] = u1y * v1z + u2y * v2z + u3y * v3z
    Rb[2, 0, i] = u1z * v1x + u2z * v2x + u3z * v3x
    Rb[2, 1, i] = u1z * v1y + u2z * v2y + u3z * v3y
    Rb[2, 2, i] = u1z * v1z + u2z * v2z + u3z * v3z


@nb.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _rotations(F, R):
    """Proper rotation ``R[e]`` (det +1) of the polar decomposition of each ``F[e]``, ``F`` and
    ``R`` ``(m, 3, 3)`` C-contiguous (the algorithm: the module's docstring). The per-matrix loop
    stays whole on purpose: split into inlined functions, LLVM vectorises and contracts it
    differently, and the rotations change in their last bit or take 35% longer."""
    m = F.shape[0]
    B = _BLOCK
    G = np.empty((3, 3, B))
    V = np.empty((3, 3, B))
    Rb = np.empty((3, 3, B))
    scale = np.empty(B)
    for b0 in range(0, m, B):
        n = min(B, m - b0)
        _load_block(F, b0, n, G, V, scale)
        _orthogonalise(G, V, n)
        for i in range(n):
            n0 = G[0, 0, i] * G[0, 0, i] + G[1, 0, i] * G[1, 0, i] + G[2, 0, i] * G[2, 0, i]
            n1 = G[0, 1, i] * G[0, 1, i] + G[1, 1, i] * G[1, 1, i] + G[2, 1, i] * G[2, 1, i]
            n2 = G[0, 2, i] * G[0, 2, i] + G[1, 2, i] * G[1, 2, i] + G[2, 2, i] * G[2, 2, i]
            o1 = n1 > n0
            t1 = n2 > max(n0, n1)
            t2 = n2 > min(n0, n1)
            s1sq, _ = _first_two(n0, n1, n2, o1, t1, t2)
            v1x, v2x = _first_two(V[0, 0, i], V[0, 1, i], V[0, 2, i], o1, t1, t2)
            v1y, v2y = _first_two(V[1, 0, i], V[1, 1, i], V[1, 2, i], o1, t1, t2)
            v1z, v2z = _first_two(V[2, 0, i], V[2, 1, i], V[2, 2, i], o1, t1, t2)
            v3x, v3y, v3z = v1y * v2z - v1z * v2y, v1z * v2x - v1x * v2z, v1x * v2y - v1y * v2x
            g1x, wx = _first_two(G[0, 0, i], G[0, 1, i], G[0, 2, i], o1, t1, t2)
            g1y, wy = _first_two(G[1, 0, i], G[1, 1, i], G[1, 2, i], o1, t1, t2)
            g1z, wz = _first_two(G[2, 0, i], G[2, 1, i], G[2, 2, i], o1, t1, t2)
            if s1sq > 0.0:
                h = 1.0 / math.sqrt(s1sq)
                u1x, u1y, u1z = g1x * h, g1y * h, g1z * h
            else:  # F = 0: U = V, R = I
                u1x, u1y, u1z = v1x, v1y, v1z
            if wx * wx + wy * wy + wz * wz <= _TINY:
                # rank <= 1: u2 is any unit vector orthogonal to u1; take v2 (or, if v2 is nearly
                # along u1, v3) orthogonalised against u1, so that R = I where F = v1 v1^T
                h = u1x * v2x + u1y * v2y + u1z * v2z
                wx, wy, wz = v2x, v2y, v2z
                if h * h > 0.5:
                    h = u1x * v3x + u1y * v3y + u1z * v3z
                    wx, wy, wz = v3x, v3y, v3z
            else:
                h = u1x * wx + u1y * wy + u1z * wz
            wx -= h * u1x
            wy -= h * u1y
            wz -= h * u1z
            h = 1.0 / math.sqrt(wx * wx + wy * wy + wz * wz)
            u2x, u2y, u2z = wx * h, wy * h, wz * h
            u3x, u3y, u3z = u1y * u2z - u1z * u2y, u1z * u2x - u1x * u2z, u1x * u2y - u1y * u2x
            _store_rotation((u1x, u1y, u1z), (u2x, u2y, u2z), (u3x, u3y, u3z), (v1x, v1y, v1z),
                            (v2x, v2y, v2z), (v3x, v3y, v3z), Rb, i)
        for i in range(n):
            for k in range(3):
                for j in range(3):
                    R[b0 + i, k, j] = Rb[k, j, i]


def rotation_of(F):
    """Rotational part ``R`` ``(..., 3, 3)`` of ``F`` ``(..., 3, 3)``: the proper rotation of the
    polar decomposition, same convention as :func:`polar_decomposition` (for an inverted ``F`` the
    least significant singular pair is flipped). Any leading shape, including a single ``(3, 3)``.
    Numba kernel (one-sided Jacobi SVD), no LAPACK; about 1 ms per 10,000 matrices."""
    F = np.asarray(F, dtype=float)
    if F.shape[-2:] != (3, 3):
        raise ValueError(f"rotation_of expects (..., 3, 3) matrices, got shape {F.shape}")
    flat = np.ascontiguousarray(F.reshape(-1, 3, 3))
    R = np.empty_like(flat)
    _rotations(flat, R)
    return R.reshape(F.shape)


def best_fit_frame(rest_offsets, points, weights):
    """Best-fit rigid frame of a deformed point cloud (Mueller 2005, eq. 5-7).

    rest_offsets: ``(n, 3)`` rest positions relative to their weighted centre ``X - X_c`` (m).
    points: ``(n, 3)`` current positions ``x`` (m). weights: ``(n,)`` masses (kg), positive.
    Returns ``(R, c)``: rotation ``(3, 3)`` and current weighted centre ``c`` ``(3,)`` (m), such that
    ``x ~= R (X - X_c) + c`` in the weighted least-squares sense.
    """
    w = np.asarray(weights, dtype=float)
    x = np.asarray(points, dtype=float)
    c = w @ x / w.sum()
    A_pq = np.einsum("i,ij,ik->jk", w, x - c, rest_offsets)
    return rotation_of(A_pq), c
