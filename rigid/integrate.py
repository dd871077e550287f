"""Time integration of free rigid motion (no contacts here).

Translation is leapfrog (semi-implicit Euler on the mid-step velocity), exact for constant gravity.
Rotation is the torque-free flow split into exact rotations about the three principal axes
(symmetric Strang splitting, as in McLachlan 1993 / Touma-Wisdom): the world angular momentum is
kept exactly, and the rotational energy error stays bounded instead of drifting, unlike an
explicit update of w which gains energy.
"""
import math

import numba as nb
import numpy as np

from . import quaternion as quat

# Strang splitting of the three principal-axis flows: (axis, fraction of the step)
_SPLIT = ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5))


@nb.njit(cache=True)
def _rotate_free(q, L, inv_inertia, h):
    out = np.empty_like(q)
    for i in range(len(q)):
        w, x, y, z = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        for axis, frac in _SPLIT:
            # exact flow of H_axis = Pi_axis^2 / (2 I_axis): rotate the body about that axis by
            # theta = h Pi_axis / I_axis, with Pi = R^T L (column ``axis`` of R(q) dotted with L)
            if axis == 0:
                c0, c1, c2 = 1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)
            elif axis == 1:
                c0, c1, c2 = 2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)
            else:
                c0, c1, c2 = 2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)
            theta = frac * h * (c0 * L[i, 0] + c1 * L[i, 1] + c2 * L[i, 2]) * inv_inertia[i, axis]
            cw, sn = math.cos(0.5 * theta), math.sin(0.5 * theta)
            # q * (cos, sin e_axis)
            if axis == 0:
                w, x, y, z = w * cw - x * sn, x * cw + w * sn, y * cw + z * sn, z * cw - y * sn
            elif axis == 1:
                w, x, y, z = w * cw - y * sn, x * cw - z * sn, y * cw + w * sn, z * cw + x * sn
            else:
                w, x, y, z = w * cw - z * sn, x * cw + y * sn, y * cw - x * sn, z * cw + w * sn
        n = math.sqrt(w * w + x * x + y * y + z * z)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = w / n, x / n, y / n, z / n
    return out


def rotate_free(q, L, inv_inertia, h):
    """Advance orientations ``q`` (b,4) by ``h`` seconds of torque-free spin with world ``L`` (b,3)."""
    return _rotate_free(np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(L, dtype=float),
                        np.ascontiguousarray(inv_inertia, dtype=float), float(h))


def rotate_by(q, rotation_vector):
    """Apply small world-frame rotations (b,3) rad to orientations (b,4)."""
    return quat.normalize(quat.multiply(quat.from_rotation_vector(rotation_vector), q))
