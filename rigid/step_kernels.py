"""Compiled kernels behind the stages of the rigid step (rigid.step, rigid.resolve): each does a
stage's per-body or per-contact arithmetic in one pass, where numpy took a dozen small calls.

Each one computes what the numpy expression it replaces did, in the same order of operations
(tests/test_rigid_kernels.py compares them on random inputs): ``body_frames`` the rotation
matrices, world inverse inertia and angular velocity (rigid.model.world_inverse_inertia, w = I^-1 L);
``drift_bodies`` the positions, angular momenta and orientations after a step (rigid.step.drift);
``contact_targets`` the contact pass's target normal velocities; ``impact_kinematics`` the normal
velocity, normal acceleration, time of impact and approach speed of each contact
(rigid.resolve.time_of_impact); ``body_report`` a frame's rows of the bodies (the positions,
shape-frame orientations, velocities at the frame's time, angular velocities and kinetic energies
of rigid.model and rigid.quaternion.from_matrix).
"""
import math

import numba as nb
import numpy as np

from .integrate import _rotate_free


@nb.njit(cache=True)
def _rotation(q, b, R):
    """R[b] (3, 3) of unit quaternion q[b] (w, x, y, z), as rigid.quaternion.to_matrix."""
    w, x, y, z = q[b, 0], q[b, 1], q[b, 2], q[b, 3]
    R[b, 0, 0] = 1 - 2 * (y * y + z * z)
    R[b, 0, 1] = 2 * (x * y - w * z)
    R[b, 0, 2] = 2 * (x * z + w * y)
    R[b, 1, 0] = 2 * (x * y + w * z)
    R[b, 1, 1] = 1 - 2 * (x * x + z * z)
    R[b, 1, 2] = 2 * (y * z - w * x)
    R[b, 2, 0] = 2 * (x * z - w * y)
    R[b, 2, 1] = 2 * (y * z + w * x)
    R[b, 2, 2] = 1 - 2 * (x * x + y * y)


@nb.njit(cache=True)
def _sandwich(R, b, d, out):
    """out[b] = R[b] diag(d[b]) R[b]^T (a body-frame diagonal tensor in the world)."""
    for i in range(3):
        for k in range(3):
            acc = 0.0
            for j in range(3):
                acc += R[b, i, j] * d[b, j] * R[b, k, j]
            out[b, i, k] = acc


@nb.njit(cache=True)
def _times(M, b, x0, x1, x2):
    """M[b] (3, 3) times the vector (x0, x1, x2)."""
    return (0.0 + M[b, 0, 0] * x0 + M[b, 0, 1] * x1 + M[b, 0, 2] * x2,
            0.0 + M[b, 1, 0] * x0 + M[b, 1, 1] * x1 + M[b, 1, 2] * x2,
            0.0 + M[b, 2, 0] * x0 + M[b, 2, 1] * x1 + M[b, 2, 2] * x2)


@nb.njit(cache=True)
def body_frames(q, body_inv_inertia, L):
    """Rotation matrices R (b, 3, 3), world inverse inertia R diag(1/I0) R^T (b, 3, 3) 1/(kg m^2)
    and angular velocity w = I^-1 L (b, 3) rad/s of orientations q (b, 4), principal inverse
    inertia (b, 3) and world angular momentum L (b, 3)."""
    n = len(q)
    R = np.empty((n, 3, 3))
    inv_inertia = np.empty((n, 3, 3))
    w = np.empty((n, 3))
    for b in range(n):
        _rotation(q, b, R)
        _sandwich(R, b, body_inv_inertia, inv_inertia)
        w[b, 0], w[b, 1], w[b, 2] = _times(inv_inertia, b, L[b, 0], L[b, 1], L[b, 2])
    return R, inv_inertia, w


@nb.njit(cache=True)
def drift_bodies(position, q, L, fixed, body_inertia, body_inv_inertia, h, velocity, angular,
                 shift, shift_rotation, pseudo_velocity, pseudo_angular, momentum_fix):
    """Positions (b, 3), angular momenta (b, 3) and orientations (b, 4) after a step of h s with
    the contact resolution's results (rigid.resolve.Resolution fields, (b, 3) each).

    L takes what the contacts did to the angular velocity, I (w - w0), plus the momentum
    correction of impacts moved back in time (free bodies only); orientations are the torque-free
    flow of the new L (rigid.integrate) followed by the small rotation the impacts and
    penetration recovery ask for."""
    n = len(q)
    R = np.empty((n, 3, 3))
    inertia = np.empty((n, 3, 3))
    inv_inertia = np.empty((n, 3, 3))
    new_position = np.empty((n, 3))
    new_L = np.empty((n, 3))
    for b in range(n):
        _rotation(q, b, R)
        _sandwich(R, b, body_inertia, inertia)
        _sandwich(R, b, body_inv_inertia, inv_inertia)
        # the angular velocity the step started with, w0 = I^-1 L
        w0 = _times(inv_inertia, b, L[b, 0], L[b, 1], L[b, 2])
        # I (w - w0): the contacts' change of angular velocity as angular momentum
        dL = _times(inertia, b, angular[b, 0] - w0[0], angular[b, 1] - w0[1], angular[b, 2] - w0[2])
        for i in range(3):
            change = 0.0
            if not fixed[b]:
                change = dL[i] + momentum_fix[b, i]
            new_L[b, i] = L[b, i] + change
            new_position[b, i] = (position[b, i] + h * velocity[b, i] + shift[b, i]
                                  + h * pseudo_velocity[b, i])
    spun = _rotate_free(q, new_L, body_inv_inertia, h)
    new_q = np.empty((n, 4))
    for b in range(n):
        # q <- normalize(from_rotation_vector(phi) * q), phi the small world rotation
        p0 = shift_rotation[b, 0] + h * pseudo_angular[b, 0]
        p1 = shift_rotation[b, 1] + h * pseudo_angular[b, 1]
        p2 = shift_rotation[b, 2] + h * pseudo_angular[b, 2]
        angle = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        half = 0.5 * angle
        k = math.sin(half) / angle if angle > 1e-8 else 0.5 - angle ** 2 / 48.0
        aw, ax, ay, az = math.cos(half), k * p0, k * p1, k * p2
        bw, bx, by, bz = spun[b, 0], spun[b, 1], spun[b, 2], spun[b, 3]
        cw = aw * bw - ax * bx - ay * by - az * bz
        cx = aw * bx + ax * bw + ay * bz - az * by
        cy = aw * by - ax * bz + ay * bw + az * bx
        cz = aw * bz + ax * by - ay * bx + az * bw
        size = math.sqrt(cw * cw + cx * cx + cy * cy + cz * cz)
        new_q[b, 0], new_q[b, 1], new_q[b, 2], new_q[b, 3] = cw / size, cx / size, cy / size, cz / size
    return new_position, new_L, new_q


@nb.njit(cache=True)
def contact_targets(ia, ib, ra, rb, normal, gap, shift, shift_rotation, h):
    """(c,) the normal velocity m/s each contact may reach at most: closing its gap exactly by
    the end of the step, counting the shifts (and small rotations) the collision pass gave both
    sides, -(max(gap, 0) + n . (moved_a - moved_b)) / h."""
    c = len(ia)
    out = np.empty(c)
    for k in range(c):
        a, b = ia[k], ib[k]
        m0 = shift[a, 0] + (shift_rotation[a, 1] * ra[k, 2] - shift_rotation[a, 2] * ra[k, 1])
        m1 = shift[a, 1] + (shift_rotation[a, 2] * ra[k, 0] - shift_rotation[a, 0] * ra[k, 2])
        m2 = shift[a, 2] + (shift_rotation[a, 0] * ra[k, 1] - shift_rotation[a, 1] * ra[k, 0])
        if b >= 0:
            m0 -= shift[b, 0] + (shift_rotation[b, 1] * rb[k, 2] - shift_rotation[b, 2] * rb[k, 1])
            m1 -= shift[b, 1] + (shift_rotation[b, 2] * rb[k, 0] - shift_rotation[b, 0] * rb[k, 2])
            m2 -= shift[b, 2] + (shift_rotation[b, 0] * rb[k, 1] - shift_rotation[b, 1] * rb[k, 0])
        shift_n = m0 * normal[k, 0] + m1 * normal[k, 1] + m2 * normal[k, 2]
        out[k] = -(max(gap[k], 0.0) + shift_n) / h
    return out


@nb.njit(cache=True)
def time_of_impact_one(gap, vn, an, h):
    """First time in [0, inf) at which gap + vn t + an t^2 / 2 reaches 0 (inf if never), in the
    conjugate form 2 gap / (sqrt(vn^2 - 2 an gap) - vn), stable for an -> 0."""
    if gap <= 0:
        return 0.0
    disc = vn * vn - 2.0 * an * gap
    den = math.sqrt(max(disc, 0.0)) - vn
    if disc >= 0 and den > 0:
        return 2.0 * gap / den
    return math.inf


@nb.njit(cache=True)
def impact_kinematics(ia, ib, ra, rb, normal, gap, velocity, angular, accel, h):
    """Per contact (c,) each: relative normal velocity at the start of the step vn (m/s, rigid
    bodies v + w x r), relative normal acceleration an (m/s^2), time of impact tau (s, inf if
    the gap does not close) and approach speed at that time -(vn + an min(tau, h))."""
    c = len(ia)
    tau = np.empty(c)
    approach = np.empty(c)
    for k in range(c):
        a, b = ia[k], ib[k]
        x0 = velocity[a, 0] + (angular[a, 1] * ra[k, 2] - angular[a, 2] * ra[k, 1])
        x1 = velocity[a, 1] + (angular[a, 2] * ra[k, 0] - angular[a, 0] * ra[k, 2])
        x2 = velocity[a, 2] + (angular[a, 0] * ra[k, 1] - angular[a, 1] * ra[k, 0])
        g0, g1, g2 = accel[a, 0], accel[a, 1], accel[a, 2]
        y0 = y1 = y2 = e0 = e1 = e2 = 0.0
        if b >= 0:
            y0 = velocity[b, 0] + (angular[b, 1] * rb[k, 2] - angular[b, 2] * rb[k, 1])
            y1 = velocity[b, 1] + (angular[b, 2] * rb[k, 0] - angular[b, 0] * rb[k, 2])
            y2 = velocity[b, 2] + (angular[b, 0] * rb[k, 1] - angular[b, 1] * rb[k, 0])
            e0, e1, e2 = accel[b, 0], accel[b, 1], accel[b, 2]
        vn = (x0 - y0) * normal[k, 0] + (x1 - y1) * normal[k, 1] + (x2 - y2) * normal[k, 2]
        an = (g0 - e0) * normal[k, 0] + (g1 - e1) * normal[k, 1] + (g2 - e2) * normal[k, 2]
        tau[k] = time_of_impact_one(gap[k], vn, an, h)
        approach[k] = -(vn + an * min(tau[k], h))
    return tau, approach


@nb.njit(cache=True)
def body_speeds(velocity, angular, radius):
    """(b,) how fast each body's surface can move, |v| + |w| r (m/s), r its bounding radius."""
    out = np.empty(len(radius))
    for b in range(len(radius)):
        v0, v1, v2 = velocity[b, 0], velocity[b, 1], velocity[b, 2]
        w0, w1, w2 = angular[b, 0], angular[b, 1], angular[b, 2]
        out[b] = (math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
                  + math.sqrt(w0 * w0 + w1 * w1 + w2 * w2) * radius[b])
    return out


@nb.njit(cache=True)
def body_report(position, q, velocity, L, contact_dv, fixed, mass, body_inv_inertia,
                shape_rotation, gravity, last_dt, force_like):
    """Each body's row of a frame's report, (b, 14): centre of mass (3), orientation of its own
    (shape) frame (4, w >= 0: rigid.quaternion.from_matrix of R S^T), velocity at the state's
    time (3: rigid.model.reported_velocity, ``force_like`` its FORCE_LIKE), angular velocity
    I^-1 L (3) and kinetic energy (J, 0 for a fixed body: rigid.model.kinetic_energy), in one
    pass."""
    n = len(q)
    out = np.empty((n, 14))
    R = np.empty((n, 3, 3))
    inv_inertia = np.empty((n, 3, 3))
    g0, g1, g2 = gravity[0], gravity[1], gravity[2]
    g_norm = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    step = g_norm * last_dt
    report = last_dt != 0.0 and step != 0.0
    up0, up1, up2 = 0.0, 0.0, 0.0
    if report:
        up0, up1, up2 = -g0 / g_norm, -g1 / g_norm, -g2 / g_norm
    K, m_scratch = np.empty((4, 4)), np.empty((3, 3))
    for b in range(n):
        v0, v1, v2 = velocity[b, 0], velocity[b, 1], velocity[b, 2]
        if report and not fixed[b]:
            c0, c1, c2 = contact_dv[b, 0], contact_dv[b, 1], contact_dv[b, 2]
            if math.sqrt(c0 * c0 + c1 * c1 + c2 * c2) > force_like * step:
                support = min(max(c0 * up0 + c1 * up1 + c2 * up2, 0.0), step)
                c0, c1, c2 = support * up0, support * up1, support * up2
            v0 += 0.5 * (g0 * last_dt + c0)
            v1 += 0.5 * (g1 * last_dt + c1)
            v2 += 0.5 * (g2 * last_dt + c2)
        _rotation(q, b, R)
        _sandwich(R, b, body_inv_inertia, inv_inertia)
        w0, w1, w2 = _times(inv_inertia, b, L[b, 0], L[b, 1], L[b, 2])
        m = 0.0 if fixed[b] else mass[b]
        ke = 0.5 * m * (v0 * v0 + v1 * v1 + v2 * v2) \
            + 0.5 * (w0 * L[b, 0] + w1 * L[b, 1] + w2 * L[b, 2])
        _shape_quaternion(R, b, shape_rotation, K, m_scratch, out[b, 3:7])
        out[b, 0], out[b, 1], out[b, 2] = position[b, 0], position[b, 1], position[b, 2]
        out[b, 7], out[b, 8], out[b, 9] = v0, v1, v2
        out[b, 10], out[b, 11], out[b, 12] = w0, w1, w2
        out[b, 13] = ke
    return out


@nb.njit(cache=True)
def _shape_quaternion(R, b, S, K, m, q):
    """q (4,) = the unit quaternion (w >= 0) of m = R[b] S[b]^T, by Shepperd's method as
    rigid.quaternion.from_matrix: the row of K = 4 q q^T of its largest diagonal entry (K and m
    scratch)."""
    for i in range(3):
        for k in range(3):
            m[i, k] = R[b, i, 0] * S[b, k, 0] + R[b, i, 1] * S[b, k, 1] + R[b, i, 2] * S[b, k, 2]
    t = m[0, 0] + m[1, 1] + m[2, 2]
    K[0, 0] = 1.0 + t
    K[1, 1] = 1.0 + 2.0 * m[0, 0] - t
    K[2, 2] = 1.0 + 2.0 * m[1, 1] - t
    K[3, 3] = 1.0 + 2.0 * m[2, 2] - t
    K[0, 1] = K[1, 0] = m[2, 1] - m[1, 2]
    K[0, 2] = K[2, 0] = m[0, 2] - m[2, 0]
    K[0, 3] = K[3, 0] = m[1, 0] - m[0, 1]
    K[1, 2] = K[2, 1] = m[0, 1] + m[1, 0]
    K[1, 3] = K[3, 1] = m[0, 2] + m[2, 0]
    K[2, 3] = K[3, 2] = m[1, 2] + m[2, 1]
    row = 0
    for i in range(1, 4):
        if K[i, i] > K[row, row]:
            row = i
    sign = -1.0 if K[row, 0] < 0 else 1.0
    norm = math.sqrt(K[row, 0] ** 2 + K[row, 1] ** 2 + K[row, 2] ** 2 + K[row, 3] ** 2)
    for i in range(4):
        q[i] = sign * K[row, i] / norm
