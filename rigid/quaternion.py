"""Unit quaternions ``(w, x, y, z)``, vectorised over a leading axis."""
import numpy as np


def multiply(a, b):
    """Hamilton product ``a * b`` for arrays of shape ``(..., 4)``."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bw - ax * bx - ay * by - az * bz
    out[..., 1] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 2] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 3] = aw * bz + ax * by - ay * bx + az * bw
    return out


def to_matrix(q):
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)``."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def from_matrix(R):
    """Unit quaternions ``(..., 4)`` (w >= 0) of rotation matrices ``(..., 3, 3)``.

    Shepperd's method: the symmetric matrix ``K`` below has ``K = 4 q q^T`` for the rotation's
    quaternion ``q`` (w, x, y, z), so any row of it is ``q`` times 4 times one component; the row
    of the largest diagonal entry (4w^2, 4x^2, 4y^2 or 4z^2) divides by the largest component.
    """
    R = np.asarray(R, dtype=float)
    m = R.reshape(-1, 3, 3)
    t = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    K = np.empty((len(m), 4, 4))
    K[:, 0, 0] = 1.0 + t
    K[:, 1, 1] = 1.0 + 2.0 * m[:, 0, 0] - t
    K[:, 2, 2] = 1.0 + 2.0 * m[:, 1, 1] - t
    K[:, 3, 3] = 1.0 + 2.0 * m[:, 2, 2] - t
    K[:, 0, 1] = K[:, 1, 0] = m[:, 2, 1] - m[:, 1, 2]
    K[:, 0, 2] = K[:, 2, 0] = m[:, 0, 2] - m[:, 2, 0]
    K[:, 0, 3] = K[:, 3, 0] = m[:, 1, 0] - m[:, 0, 1]
    K[:, 1, 2] = K[:, 2, 1] = m[:, 0, 1] + m[:, 1, 0]
    K[:, 1, 3] = K[:, 3, 1] = m[:, 0, 2] + m[:, 2, 0]
    K[:, 2, 3] = K[:, 3, 2] = m[:, 1, 2] + m[:, 2, 1]
    rows = np.arange(len(m))
    q = K[rows, np.argmax(K[:, [0, 1, 2, 3], [0, 1, 2, 3]], axis=1)]
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return normalize(q).reshape(R.shape[:-2] + (4,))


def from_rotation_vector(phi):
    """Quaternions ``(..., 4)`` of rotation vectors ``(..., 3)`` (axis times angle, rad)."""
    phi = np.asarray(phi, dtype=float)
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a, with its series near zero
    k = np.where(angle > 1e-8, np.sin(half) / np.where(angle > 1e-8, angle, 1.0), 0.5 - angle**2 / 48.0)
    return np.concatenate([np.cos(half), k * phi], axis=-1)


def normalize(q):
    """Unit quaternions ``(..., 4)`` of ``q`` (each divided by its norm)."""
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def rotate(q, v):
    """Rotate vectors ``(..., 3)`` by quaternions ``(..., 4)``."""
    return np.einsum("...ij,...j->...i", to_matrix(q), v)
