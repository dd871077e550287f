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
def _side(i, r0, r1, r2, d0, d1, d2, inv_m, invI, scale):
    """Inverse effective mass d . M^-1 (impulse d at arm r) of body i, and its angular response."""
    if i < 0 or scale == 0.0:
        return 0.0, 0.0, 0.0, 0.0
    c0, c1, c2 = r1 * d2 - r2 * d1, r2 * d0 - r0 * d2, r0 * d1 - r1 * d0   # r x d
    I = invI[i]
    a0 = I[0, 0] * c0 + I[0, 1] * c1 + I[0, 2] * c2
    a1 = I[1, 0] * c0 + I[1, 1] * c1 + I[1, 2] * c2
    a2 = I[2, 0] * c0 + I[2, 1] * c1 + I[2, 2] * c2
    k = inv_m[i] + (a1 * r2 - a2 * r1) * d0 + (a2 * r0 - a0 * r2) * d1 + (a0 * r1 - a1 * r0) * d2
    return scale * k, scale * a0, scale * a1, scale * a2


@nb.njit(cache=True)
def _rel_velocity(a, b, ra, rb, v, w, k):
    x = y = z = 0.0
    if a >= 0:
        x += v[a, 0] + w[a, 1] * ra[k, 2] - w[a, 2] * ra[k, 1]
        y += v[a, 1] + w[a, 2] * ra[k, 0] - w[a, 0] * ra[k, 2]
        z += v[a, 2] + w[a, 0] * ra[k, 1] - w[a, 1] * ra[k, 0]
    if b >= 0:
        x -= v[b, 0] + w[b, 1] * rb[k, 2] - w[b, 2] * rb[k, 1]
        y -= v[b, 1] + w[b, 2] * rb[k, 0] - w[b, 0] * rb[k, 2]
        z -= v[b, 2] + w[b, 0] * rb[k, 1] - w[b, 1] * rb[k, 0]
    return x, y, z


@nb.njit(cache=True)
def _group_diag(i, d0, d1, d2, group_of, group_start, W, w_off):
    """d . W_ii d for particle i: its inverse effective mass along d (Delassus diagonal)."""
    g = group_of[i]
    k = group_start[g + 1] - group_start[g]
    li = i - group_start[g]
    base = w_off[g] + (li * k + li) * 9
    d = (d0, d1, d2)
    out = 0.0
    for a in range(3):
        for b in range(3):
            out += d[a] * W[base + 3 * a + b] * d[b]
    return out


@nb.njit(cache=True)
def _push_group(i, imp0, imp1, imp2, v, group_of, group_start, W, w_off):
    """Apply impulse (imp) to particle i: every particle l of its group moves by W[l, i] imp.

    Blocks are stored (k, k, 3, 3) row-major; W is symmetric, so W[l, i] imp = W[i, l]^T imp is
    read from block row i, contiguous in memory."""
    g = group_of[i]
    lo, hi = group_start[g], group_start[g + 1]
    k = hi - lo
    row = w_off[g] + (i - lo) * k * 9
    for l in range(k):
        b = row + 9 * l
        v[lo + l, 0] += W[b] * imp0 + W[b + 3] * imp1 + W[b + 6] * imp2
        v[lo + l, 1] += W[b + 1] * imp0 + W[b + 4] * imp1 + W[b + 7] * imp2
        v[lo + l, 2] += W[b + 2] * imp0 + W[b + 5] * imp1 + W[b + 8] * imp2


@nb.njit(cache=True)
def pgs(ia, ib, ra, rb, normal, target, mu, scale_a, scale_b, active, lam, inv_m, invI, v, w,
        iterations, group_of, group_start, W, w_off):
    """Projected Gauss-Seidel. Updates v, w (solver bodies) and lam (c, 3) in place.

    lam[:, 0] accumulates the normal impulse (N s), lam[:, 1:] the friction impulse in the
    contact's tangent basis (warm start: the velocities already include what lam holds).
    scale_a/scale_b (c,) multiply each side's response: 0 makes that side immovable for this call
    (shock propagation). Only contacts with active[k] take part. Solver bodies with
    group_of[i] >= 0 are particles (FEM surface nodes) whose group (one deformable body) answers an
    impulse on any of them through its Delassus block: the particles of group g are the solver
    bodies group_start[g]..group_start[g+1]-1 and their blocks W[w_off[g]:] are (k, k, 3, 3)
    row-major (block [l, i]: velocity of particle l per unit impulse on particle i; symmetric).
    Sweeps stop early once no impulse changes by more than 1e-7 of the largest. Returns the world
    impulse on side a of each contact, (c, 3) N s (NaN rows for inactive contacts).
    """
    idx = np.nonzero(active)[0]
    m = len(idx)
    # per active contact and direction (normal, t1, t2): direction, 1/k, angular responses
    dirs = np.zeros((m, 3, 3))
    invk = np.zeros((m, 3))
    resp = np.zeros((m, 3, 2, 3))   # [contact, direction, side, xyz] = scale invI (r x d)
    for j in range(m):
        k = idx[j]
        n0, n1, n2 = normal[k, 0], normal[k, 1], normal[k, 2]
        if abs(n0) > 0.57735:
            t0, t1, t2 = n1, -n0, 0.0
        else:
            t0, t1, t2 = 0.0, n2, -n1
        tl = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        t0, t1, t2 = t0 / tl, t1 / tl, t2 / tl
        s0, s1, s2 = n1 * t2 - n2 * t1, n2 * t0 - n0 * t2, n0 * t1 - n1 * t0
        dirs[j, 0, 0], dirs[j, 0, 1], dirs[j, 0, 2] = n0, n1, n2
        dirs[j, 1, 0], dirs[j, 1, 1], dirs[j, 1, 2] = t0, t1, t2
        dirs[j, 2, 0], dirs[j, 2, 1], dirs[j, 2, 2] = s0, s1, s2
        a, b = ia[k], ib[k]
        for d in range(3):
            e0, e1, e2 = dirs[j, d, 0], dirs[j, d, 1], dirs[j, d, 2]
            if a >= 0 and group_of[a] >= 0:
                ka = scale_a[k] * _group_diag(a, e0, e1, e2, group_of, group_start, W, w_off)
            else:
                ka, x0, x1, x2 = _side(a, ra[k, 0], ra[k, 1], ra[k, 2], e0, e1, e2, inv_m, invI, scale_a[k])
                resp[j, d, 0, 0], resp[j, d, 0, 1], resp[j, d, 0, 2] = x0, x1, x2
            if b >= 0 and group_of[b] >= 0:
                kb = scale_b[k] * _group_diag(b, e0, e1, e2, group_of, group_start, W, w_off)
            else:
                kb, y0, y1, y2 = _side(b, rb[k, 0], rb[k, 1], rb[k, 2], e0, e1, e2, inv_m, invI, scale_b[k])
                resp[j, d, 1, 0], resp[j, d, 1, 1], resp[j, d, 1, 2] = y0, y1, y2
            invk[j, d] = 1.0 / (ka + kb) if ka + kb > 0.0 else 0.0
    for sweep in range(iterations):
        largest_change = 0.0
        largest = 0.0
        for j in range(m):
            if invk[j, 0] == 0.0:
                continue
            k = idx[j]
            a, b = ia[k], ib[k]
            for d in range(3):
                x, y, z = _rel_velocity(a, b, ra, rb, v, w, k)
                vd = x * dirs[j, d, 0] + y * dirs[j, d, 1] + z * dirs[j, d, 2]
                if d == 0:
                    # normal: reach the target normal velocity, accumulated impulse >= 0
                    new = max(lam[k, 0] + (target[k] - vd) * invk[j, 0], 0.0)
                    delta = new - lam[k, 0]
                    lam[k, 0] = new
                else:
                    # friction: stop sliding, inside the Coulomb disk mu * lambda_n
                    if mu[k] <= 0.0 or invk[j, d] == 0.0:
                        break
                    f = lam[k, d] - vd * invk[j, d]
                    other = lam[k, 3 - d]
                    limit = mu[k] * lam[k, 0]
                    norm = math.sqrt(f * f + other * other)
                    if norm > limit:
                        f = f * limit / norm if norm > 0 else 0.0
                    delta = f - lam[k, d]
                    lam[k, d] = f
                if delta == 0.0:
                    continue
                largest_change = max(largest_change, abs(delta))
                _apply_both(j, k, d, delta, a, b, ra, rb, dirs, resp, scale_a, scale_b, inv_m, v, w,
                            group_of, group_start, W, w_off)
            largest = max(largest, lam[k, 0])
            if mu[k] > 0.0:
                # the disk clamp may have left the first tangent outside after the second moved
                l1, l2 = lam[k, 1], lam[k, 2]
                limit = mu[k] * lam[k, 0]
                norm = math.sqrt(l1 * l1 + l2 * l2)
                if norm > limit * (1 + 1e-12) and norm > 0:
                    s = limit / norm
                    for d in (1, 2):
                        delta = lam[k, d] * s - lam[k, d]
                        lam[k, d] += delta
                        _apply_both(j, k, d, delta, a, b, ra, rb, dirs, resp, scale_a, scale_b,
                                    inv_m, v, w, group_of, group_start, W, w_off)
        if sweep > 0 and largest_change <= 1e-7 * largest:
            break
    out = np.full((len(ia), 3), np.nan)
    for j in range(m):
        k = idx[j]
        for c in range(3):
            out[k, c] = lam[k, 0] * dirs[j, 0, c] + lam[k, 1] * dirs[j, 1, c] + lam[k, 2] * dirs[j, 2, c]
    return out


@nb.njit(cache=True)
def _apply_both(j, k, d, delta, a, b, ra, rb, dirs, resp, scale_a, scale_b, inv_m, v, w,
                group_of, group_start, W, w_off):
    """Apply +delta along contact direction d to side a and -delta to side b."""
    d0, d1, d2 = dirs[j, d, 0], dirs[j, d, 1], dirs[j, d, 2]
    if a >= 0 and scale_a[k] != 0.0:
        sa = scale_a[k] * delta
        if group_of[a] >= 0:
            _push_group(a, sa * d0, sa * d1, sa * d2, v, group_of, group_start, W, w_off)
        else:
            m = inv_m[a] * sa
            v[a, 0] += m * d0
            v[a, 1] += m * d1
            v[a, 2] += m * d2
            w[a, 0] += delta * resp[j, d, 0, 0]
            w[a, 1] += delta * resp[j, d, 0, 1]
            w[a, 2] += delta * resp[j, d, 0, 2]
    if b >= 0 and scale_b[k] != 0.0:
        sb = scale_b[k] * delta
        if group_of[b] >= 0:
            _push_group(b, -sb * d0, -sb * d1, -sb * d2, v, group_of, group_start, W, w_off)
        else:
            m = inv_m[b] * sb
            v[b, 0] -= m * d0
            v[b, 1] -= m * d1
            v[b, 2] -= m * d2
            w[b, 0] -= delta * resp[j, d, 1, 0]
            w[b, 1] -= delta * resp[j, d, 1, 1]
            w[b, 2] -= delta * resp[j, d, 1, 2]


@nb.njit(cache=True)
def stack_levels(ia, ib, normal, up, body_count, is_static):
    """Height of each body in the contact graph (Guendelman 2003 shock propagation).

    Static bodies are level 0; a body resting (normal within ~70 degrees of up) on a body of level
    k has level <= k + 1. Bodies touching nothing below them get a level above every other.
    """
    big = body_count + 1
    level = np.full(body_count, big, dtype=np.int64)
    for i in range(body_count):
        if is_static[i]:
            level[i] = 0
    changed = True
    sweeps = 0
    while changed and sweeps < body_count + 1:
        changed = False
        sweeps += 1
        for k in range(len(ia)):
            s = np.dot(normal[k], up)
            if s > 0.34:
                upper, lower = ia[k], ib[k]
            elif s < -0.34:
                upper, lower = ib[k], ia[k]
            else:
                continue
            lower_level = 0 if lower < 0 else level[lower]
            if upper >= 0 and lower_level + 1 < level[upper]:
                level[upper] = lower_level + 1
                changed = True
    top = 0
    for i in range(body_count):
        if level[i] < big and level[i] > top:
            top = level[i]
    for i in range(body_count):
        if level[i] == big:
            level[i] = top + 1
    return level


def shock_scales(body_a, body_b, level):
    """Per contact: which level it belongs to and the inverse-mass scales that freeze its lower side."""
    la = np.where(body_a >= 0, level[np.maximum(body_a, 0)], 0)
    lb = np.where(body_b >= 0, level[np.maximum(body_b, 0)], 0)
    contact_level = np.maximum(la, lb)
    scale_a = np.where(la < lb, 0.0, 1.0)
    scale_b = np.where(lb < la, 0.0, 1.0)
    return contact_level, scale_a, scale_b
