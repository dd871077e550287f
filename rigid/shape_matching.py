"""Shape matching: batched polar decomposition and the best-fit rigid frame of a point cloud.

Mueller, Heidelberger, Teschner, Gross 2005, "Meshless deformations based on shape matching":
the rotation that best maps rest offsets ``X - X_c`` onto current offsets ``x - c`` (mass-weighted
least squares) is the rotational part of ``A_pq = sum_i m_i (x_i - c)(X_i - X_c)^T`` (eq. 7).
"""
import numpy as np


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


def rotation_of(F):
    """Rotational part ``R`` ``(..., 3, 3)`` of ``F`` ``(..., 3, 3)`` (see :func:`polar_decomposition`)."""
    return polar_decomposition(F)[0]


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
