"""Contact impulses: projected Gauss-Seidel over point contacts with Coulomb friction.

One routine serves every pass of the step (collision with restitution, resting contact, shock
propagation, penetration recovery): each contact asks that the relative normal velocity at the
contact be at least ``target``; the accumulated normal impulse stays >= 0 and the friction
impulse inside the Coulomb disk mu * lambda_n. "Solver bodies" are generic: a rigid body has an
inverse mass and a world inverse inertia; a particle (an FEM surface node) has a zero inverse
inertia. Index -1 is the static world.
"""
import math

import numba as nb
import numpy as np


@nb.njit(cache=True)
def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@nb.njit(cache=True)
def _velocity_at(i, r, v, w):
    if i < 0:
        return np.zeros(3)
    return v[i] + _cross(w[i], r)


@nb.njit(cache=True)
def arms(ia, ib, point, x):
    """Contact arms r = p - x for both sides (zero for the static side)."""
    c = len(ia)
    ra = np.zeros((c, 3))
    rb = np.zeros((c, 3))
    for k in range(c):
        ra[k] = point[k] - x[ia[k]]
        if ib[k] >= 0:
            rb[k] = point[k] - x[ib[k]]
    return ra, rb


@nb.njit(cache=True)
def normal_velocity(ia, ib, ra, rb, normal, v, w):
    c = len(ia)
    out = np.empty(c)
    for k in range(c):
        out[k] = np.dot(_velocity_at(ia[k], ra[k], v, w) - _velocity_at(ib[k], rb[k], v, w), normal[k])
    return out


@nb.njit(cache=True)
def contact_basis(normal):
    """(c, 3, 3) orthonormal contact bases: rows are the normal and two tangents (right-handed).
    A normal that is not a unit vector (zero, or not finite) has no basis: its rows are zero, so
    the contact has no response and the solver leaves it out (detection gives none such; a
    tangent built from a zero normal divided by its zero length)."""
    c = len(normal)
    out = np.zeros((c, 3, 3))
    for k in range(c):
        n0, n1, n2 = normal[k, 0], normal[k, 1], normal[k, 2]
        if not abs(n0 * n0 + n1 * n1 + n2 * n2 - 1.0) < 1e-6:
            continue
        if abs(n0) > 0.57735:
            t0, t1, t2 = n1, -n0, 0.0
        else:
            t0, t1, t2 = 0.0, n2, -n1
        tl = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        t0, t1, t2 = t0 / tl, t1 / tl, t2 / tl
        out[k, 0, 0], out[k, 0, 1], out[k, 0, 2] = n0, n1, n2
        out[k, 1, 0], out[k, 1, 1], out[k, 1, 2] = t0, t1, t2
        out[k, 2, 0], out[k, 2, 1], out[k, 2, 2] = n1 * t2 - n2 * t1, n2 * t0 - n0 * t2, n0 * t1 - n1 * t0
    return out


@nb.njit(cache=True)
def _block(i, l, W, w_ptr, w_col):
    """W[i, l] (3, 3), group frame: velocity of particle i per unit impulse on particle l (zero
    when the block was dropped as negligible)."""
    for p in range(w_ptr[i], w_ptr[i + 1]):
        if w_col[p] == l:
            return W[p]
    return np.zeros((3, 3))


@nb.njit(cache=True, inline="always")
def _push_group(i, J0, J1, J2, v, groups):
    """Impulse J (world) on particle i: every particle l of its group moves by W[l, i] R^T J
    (group-frame velocities, see pgs). W is symmetric, so W[l, i] = W[i, l]^T is read from row i."""
    group_of, group_R, w_ptr, w_col, W = groups[0], groups[1], groups[2], groups[3], groups[4]
    R = group_R[group_of[i]]
    j0 = R[0, 0] * J0 + R[1, 0] * J1 + R[2, 0] * J2
    j1 = R[0, 1] * J0 + R[1, 1] * J1 + R[2, 1] * J2
    j2 = R[0, 2] * J0 + R[1, 2] * J1 + R[2, 2] * J2
    for p in range(w_ptr[i], w_ptr[i + 1]):
        l = w_col[p]
        B = W[p]
        v[l, 0] += B[0, 0] * j0 + B[1, 0] * j1 + B[2, 0] * j2
        v[l, 1] += B[0, 1] * j0 + B[1, 1] * j1 + B[2, 1] * j2
        v[l, 2] += B[0, 2] * j0 + B[1, 2] * j1 + B[2, 2] * j2


@nb.njit(cache=True, inline="always")
def _point_velocity(i, r, v, w, groups):
    """World velocity (x, y, z) of body i at arm r (particles: their group-frame velocity rotated
    out; places: the weighted sum of their corner particles')."""
    group_of, group_R, corner, corner_w = groups[0], groups[1], groups[5], groups[6]
    if i < 0:
        return 0.0, 0.0, 0.0
    if group_of[i] >= 0:
        R = group_R[group_of[i]]
        if corner[i, 0] >= 0:
            u0 = u1 = u2 = 0.0
            for c in range(3):
                q, f = corner[i, c], corner_w[i, c]
                u0 += f * v[q, 0]
                u1 += f * v[q, 1]
                u2 += f * v[q, 2]
        else:
            u0, u1, u2 = v[i, 0], v[i, 1], v[i, 2]
        return (R[0, 0] * u0 + R[0, 1] * u1 + R[0, 2] * u2,
                R[1, 0] * u0 + R[1, 1] * u1 + R[1, 2] * u2,
                R[2, 0] * u0 + R[2, 1] * u1 + R[2, 2] * u2)
    return (v[i, 0] + w[i, 1] * r[2] - w[i, 2] * r[1],
            v[i, 1] + w[i, 2] * r[0] - w[i, 0] * r[2],
            v[i, 2] + w[i, 0] * r[1] - w[i, 1] * r[0])


@nb.njit(cache=True, inline="always")
def _apply(i, r, j0, j1, j2, scale, inv_m, invI, v, w, groups):
    """Impulse scale * (j0, j1, j2) (world) on body i at arm r (a place: shared among its corners
    by their weights)."""
    group_of, corner, corner_w = groups[0], groups[5], groups[6]
    if i < 0 or scale == 0.0:
        return
    j0, j1, j2 = scale * j0, scale * j1, scale * j2
    if group_of[i] >= 0:
        if corner[i, 0] >= 0:
            for c in range(3):
                f = corner_w[i, c]
                if f != 0.0:
                    _push_group(corner[i, c], f * j0, f * j1, f * j2, v, groups)
        else:
            _push_group(i, j0, j1, j2, v, groups)
        return
    m = inv_m[i]
    v[i, 0] += m * j0
    v[i, 1] += m * j1
    v[i, 2] += m * j2
    c0, c1, c2 = r[1] * j2 - r[2] * j1, r[2] * j0 - r[0] * j2, r[0] * j1 - r[1] * j0   # r x J
    I = invI[i]
    w[i, 0] += I[0, 0] * c0 + I[0, 1] * c1 + I[0, 2] * c2
    w[i, 1] += I[1, 0] * c0 + I[1, 1] * c1 + I[1, 2] * c2
    w[i, 2] += I[2, 0] * c0 + I[2, 1] * c1 + I[2, 2] * c2


@nb.njit(cache=True, inline="always")
def _apply_pair(j, k, l0, l1, l2, basis, ia, ib, ra, rb, scale_a, scale_b, inv_m, invI, v, w, groups):
    """Impulse l0 n + l1 t1 + l2 t2 (contact j's basis) on side a of contact k, its opposite on b."""
    J0 = l0 * basis[j, 0, 0] + l1 * basis[j, 1, 0] + l2 * basis[j, 2, 0]
    J1 = l0 * basis[j, 0, 1] + l1 * basis[j, 1, 1] + l2 * basis[j, 2, 1]
    J2 = l0 * basis[j, 0, 2] + l1 * basis[j, 1, 2] + l2 * basis[j, 2, 2]
    _apply(ia[k], ra[k], J0, J1, J2, scale_a[k], inv_m, invI, v, w, groups)
    _apply(ib[k], rb[k], -J0, -J1, -J2, scale_b[k], inv_m, invI, v, w, groups)


@nb.njit(cache=True)
def _add_pair_block(i, l, D, scale, groups, out):
    """:func:`_add_block` for particles or places i and l of one group (a place's block is the
    weighted sum of its corners')."""
    corner, corner_w = groups[5], groups[6]
    ni = 3 if corner[i, 0] >= 0 else 1
    nl = 3 if corner[l, 0] >= 0 else 1
    for a in range(ni):
        p, fp = (corner[i, a], corner_w[i, a]) if ni == 3 else (i, 1.0)
        for b in range(nl):
            q, fq = (corner[l, b], corner_w[l, b]) if nl == 3 else (l, 1.0)
            if fp != 0.0 and fq != 0.0:
                _add_block(p, q, D, scale * fp * fq, groups, out)


@nb.njit(cache=True)
def _add_block(i, l, D, scale, groups, out):
    """Add scale * D R W[i, l] R^T D^T to out (3, 3): block W[i, l] (group frame) seen along the
    rows of D (world directions)."""
    group_of, group_R, w_ptr, w_col, W = groups[0], groups[1], groups[2], groups[3], groups[4]
    R = group_R[group_of[i]]
    Wb = _block(i, l, W, w_ptr, w_col)
    Db = np.zeros((3, 3))                               # directions in the group frame
    for e in range(3):
        for a in range(3):
            Db[e, a] = D[e, 0] * R[0, a] + D[e, 1] * R[1, a] + D[e, 2] * R[2, a]
    for e in range(3):
        for f in range(3):
            acc = 0.0
            for a in range(3):
                for b in range(3):
                    acc += Db[f, a] * Wb[a, b] * Db[e, b]
            out[f, e] += scale * acc


@nb.njit(cache=True)
def _response(i, r, D, scale, inv_m, invI, groups, out):
    """Add to out (3, 3) the velocity of body i at arm r along the rows of D per unit impulse along
    them, times scale."""
    if i < 0 or scale == 0.0:
        return
    if groups[0][i] >= 0:
        _add_pair_block(i, i, D, scale, groups, out)
        return
    I = invI[i]
    for e in range(3):
        d0, d1, d2 = D[e, 0], D[e, 1], D[e, 2]
        c0, c1, c2 = r[1] * d2 - r[2] * d1, r[2] * d0 - r[0] * d2, r[0] * d1 - r[1] * d0   # r x d
        a0 = I[0, 0] * c0 + I[0, 1] * c1 + I[0, 2] * c2
        a1 = I[1, 0] * c0 + I[1, 1] * c1 + I[1, 2] * c2
        a2 = I[2, 0] * c0 + I[2, 1] * c1 + I[2, 2] * c2
        m = inv_m[i]
        dv0, dv1, dv2 = m * d0 + a1 * r[2] - a2 * r[1], m * d1 + a2 * r[0] - a0 * r[2], m * d2 + a0 * r[1] - a1 * r[0]
        for f in range(3):
            out[f, e] += scale * (D[f, 0] * dv0 + D[f, 1] * dv1 + D[f, 2] * dv2)


@nb.njit(cache=True)
def _rotate_particles(v, group_of, group_R, to_group):
    """Particle velocities from world to their group frame (to_group) or back, in place."""
    for i in range(len(group_of)):
        g = group_of[i]
        if g >= 0:
            R = group_R[g]
            x0, x1, x2 = v[i, 0], v[i, 1], v[i, 2]
            for a in range(3):
                v[i, a] = (R[0, a] * x0 + R[1, a] * x1 + R[2, a] * x2 if to_group
                           else R[a, 0] * x0 + R[a, 1] * x1 + R[a, 2] * x2)


@nb.njit(cache=True)
def _responses(idx, basis, ia, ib, ra, rb, scale_a, scale_b, inv_m, invI, groups):
    """(m, 3, 3) response of each active contact's relative velocity, in its basis, per unit
    impulse along its basis (the Delassus block of the contact, both sides' scales applied)."""
    group_of = groups[0]
    K = np.zeros((len(idx), 3, 3))
    for j in range(len(idx)):
        k = idx[j]
        a, b = ia[k], ib[k]
        D = basis[j]
        _response(a, ra[k], D, scale_a[k], inv_m, invI, groups, K[j])
        _response(b, rb[k], D, scale_b[k], inv_m, invI, groups, K[j])
        if a >= 0 and b >= 0 and group_of[a] >= 0 and group_of[a] == group_of[b]:
            # both sides in one deformable body: an impulse on one side moves the other too
            _add_pair_block(a, b, D, -scale_b[k], groups, K[j])
            _add_pair_block(b, a, D, -scale_a[k], groups, K[j])
    return K


@nb.njit(cache=True, inline="always")
def _relative_velocity(j, k, basis, ia, ib, ra, rb, v, w, groups, u):
    """u (3,) = velocity of side a minus side b at contact k, in contact j's basis."""
    x0, x1, x2 = _point_velocity(ia[k], ra[k], v, w, groups)
    y0, y1, y2 = _point_velocity(ib[k], rb[k], v, w, groups)
    x0, x1, x2 = x0 - y0, x1 - y1, x2 - y2
    for d in range(3):
        u[d] = basis[j, d, 0] * x0 + basis[j, d, 1] * x1 + basis[j, d, 2] * x2


@nb.njit(cache=True, inline="always")
def _solve_normal(K, j, target, lam, k, u, delta):
    """Normal row of contact k (response K[j]): reach the target normal velocity, accumulated
    impulse lam[k, 0] >= 0; u follows."""
    new = max(lam[k, 0] + (target - u[0]) / K[j, 0, 0], 0.0)
    delta[0] = new - lam[k, 0]
    lam[k, 0] = new
    for e in range(3):
        u[e] += K[j, e, 0] * delta[0]


@nb.njit(cache=True, inline="always")
def _solve_friction(K, j, mu, lam, k, u, delta):
    """Friction rows: both tangents at once, each stopped through the larger of the two
    tangential responses (never past the answer on either), and the pair projected radially into
    the Coulomb disk mu * lam[k, 0], so a sliding contact's friction opposes its sliding velocity.

    Clamped one tangent after the other, a sliding node whose lateral vibration asked more than
    the disk held got friction at 45 degrees to its motion, or along it (a Newmark block slid at
    0.90 mu g); through the full 2x2 response, a sliding box's corners (whose response turns with
    their lever arms) pulled askew and it slid 2% too far down a slope."""
    limit = mu * lam[k, 0]
    ktt = max(K[j, 1, 1], K[j, 2, 2])
    f1 = lam[k, 1] - u[1] / ktt if ktt > 0.0 else lam[k, 1]
    f2 = lam[k, 2] - u[2] / ktt if ktt > 0.0 else lam[k, 2]
    norm = math.sqrt(f1 * f1 + f2 * f2)
    if norm > limit:
        scale = limit / norm if norm > 0.0 else 0.0
        f1, f2 = f1 * scale, f2 * scale
    step1, step2 = f1 - lam[k, 1], f2 - lam[k, 2]
    lam[k, 1], lam[k, 2] = f1, f2
    delta[1] += step1
    delta[2] += step2
    for e in range(3):
        u[e] += K[j, e, 1] * step1 + K[j, e, 2] * step2


@nb.njit(cache=True)
def _sweeps(idx, K, basis, ia, ib, ra, rb, target, mu, scale_a, scale_b, lam, inv_m, invI, v, w,
            iterations, groups):
    """Gauss-Seidel sweeps over the active contacts (see pgs), until no impulse changes by more
    than 1e-7 of the largest."""
    u = np.zeros(3)
    delta = np.zeros(3)
    for sweep in range(iterations):
        largest_change = 0.0
        largest = 0.0
        for j in range(len(idx)):
            if not K[j, 0, 0] > 0.0:    # no effective mass (both sides immovable): no row
                continue
            k = idx[j]
            _relative_velocity(j, k, basis, ia, ib, ra, rb, v, w, groups, u)
            delta[:] = 0.0
            _solve_normal(K, j, target[k], lam, k, u, delta)
            if mu[k] > 0.0:
                _solve_friction(K, j, mu[k], lam, k, u, delta)
            largest = max(largest, lam[k, 0])
            change = max(abs(delta[0]), abs(delta[1]), abs(delta[2]))
            if change == 0.0:
                continue
            largest_change = max(largest_change, change)
            _apply_pair(j, k, delta[0], delta[1], delta[2], basis, ia, ib, ra, rb, scale_a, scale_b,
                        inv_m, invI, v, w, groups)
        if sweep > 0 and largest_change <= 1e-7 * largest:
            break


@nb.njit(cache=True)
def pgs(ia, ib, ra, rb, normal, target, mu, scale_a, scale_b, active, lam, inv_m, invI, v, w,
        iterations, group_of, group_R, w_ptr, w_col, W, corner, corner_w, apply_lam):
    """Projected Gauss-Seidel. Updates v, w (solver bodies) and lam (c, 3) in place.

    lam[:, 0] accumulates the normal impulse (N s), lam[:, 1:] the friction impulse in the
    contact's tangent basis (:func:`contact_basis`). Warm start: with ``apply_lam`` the impulses lam
    holds are applied to the bodies first; without it the velocities already include them.
    scale_a/scale_b (c,) multiply each side's response: 0 makes that side immovable for this call
    (shock propagation). Only contacts with active[k] take part. Solver bodies with
    group_of[i] >= 0 are particles (FEM surface nodes) of group group_of[i] (one deformable body),
    which answer impulses through the group's Delassus matrix, block-sparse by rows: for particle
    i, W[p] (3, 3) for p in w_ptr[i]..w_ptr[i+1]-1 is block [i, w_col[p]], the velocity of
    particle i per unit impulse on particle w_col[p] (symmetric; the diagonal block comes first;
    w_ptr has n + 1 entries, empty rows for rigid bodies). Blocks are in the group's frame, whose
    rotation to world is group_R[g] (world blocks are R W R^T; during the sweeps particle velocities
    are kept in their group frame, which spares rotating W). A place (a point of a deformable
    body's surface between its nodes) is a solver body with corner[i, 0] >= 0: its velocity is the
    sum of its corner particles' corner[i] (3,) with weights corner_w[i] (3,), an impulse on it
    acts on them in those proportions, and it has no block row of its own (corner[i, 0] = -1 for
    every other body).
    Each contact is solved as a block: normal, then the two tangents, each with the exact 3x3
    response of the contact, and the sum is applied to the bodies once.
    Sweeps stop early once no impulse changes by more than 1e-7 of the largest. Returns the world
    impulse on side a of each contact, (c, 3) N s (NaN rows for inactive contacts).
    """
    groups = (group_of, group_R, w_ptr, w_col, W, corner, corner_w)
    idx = np.nonzero(active)[0]
    basis = contact_basis(normal[idx])
    K = _responses(idx, basis, ia, ib, ra, rb, scale_a, scale_b, inv_m, invI, groups)
    # particle velocities stay in their group's frame during the sweeps
    _rotate_particles(v, group_of, group_R, True)
    if apply_lam:       # warm start: the impulses lam holds act first
        for j in range(len(idx)):
            k = idx[j]
            if not K[j, 0, 0] > 0.0:    # a guess on a contact nothing can move: it takes none
                lam[k] = 0.0
            else:
                _apply_pair(j, k, lam[k, 0], lam[k, 1], lam[k, 2], basis, ia, ib, ra, rb, scale_a,
                            scale_b, inv_m, invI, v, w, groups)
    _sweeps(idx, K, basis, ia, ib, ra, rb, target, mu, scale_a, scale_b, lam, inv_m, invI, v, w,
            iterations, groups)
    _rotate_particles(v, group_of, group_R, False)
    out = np.full((len(ia), 3), np.nan)
    for j in range(len(idx)):
        k = idx[j]
        out[k] = lam[k, 0] * basis[j, 0] + lam[k, 1] * basis[j, 1] + lam[k, 2] * basis[j, 2]
    return out
