"""Time integration of free rigid motion (no contacts here).

Translation is leapfrog (semi-implicit Euler on the mid-step velocity), exact for constant gravity.
Rotation is the torque-free flow split into exact rotations about the three principal axes
(symmetric Strang splitting, as in McLachlan 1993 / Touma-Wisdom): the world angular momentum is
kept exactly, and the rotational energy error stays bounded instead of drifting, unlike an
explicit update of w which gains energy.
"""
import numpy as np

from . import quaternion as quat

_AXES = np.eye(3)


def _rotate_about_body_axis(q, L, inv_inertia, axis, h):
    """Exact flow of H_i = Pi_i^2 / (2 I_i) for time h: rotate the body about its axis i."""
    R = quat.to_matrix(q)
    pi_i = np.einsum("bj,bj->b", R[:, :, axis], L)  # (R^T L)_i
    theta = h * pi_i * inv_inertia[:, axis]
    dq = quat.from_rotation_vector(theta[:, None] * _AXES[axis])
    return quat.multiply(q, dq)


def rotate_free(q, L, inv_inertia, h):
    """Advance orientations ``q`` (b,4) by ``h`` seconds of torque-free spin with world ``L`` (b,3)."""
    for axis, frac in ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5)):
        q = _rotate_about_body_axis(q, L, inv_inertia, axis, frac * h)
    return quat.normalize(q)


def rotate_by(q, rotation_vector):
    """Apply small world-frame rotations (b,3) rad to orientations (b,4)."""
    return quat.normalize(quat.multiply(quat.from_rotation_vector(rotation_vector), q))
