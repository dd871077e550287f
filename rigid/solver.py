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
def _tangents(n):
    if abs(n[0]) > 0.57735:
        t = np.array([n[1], -n[0], 0.0])
    else:
        t = np.array([0.0, n[2], -n[1]])
    t /= math.sqrt(t[0] ** 2 + t[1] ** 2 + t[2] ** 2)
    return t, _cross(n, t)


@nb.njit(cache=True)
def _inv_eff_mass(i, r, d, inv_m, invI, scale):
    """d . (M^-1 applied to a unit impulse along d at arm r) for body i (0 if static)."""
    if i < 0 or scale == 0.0:
        return 0.0
    rd = _cross(r, d)
    return scale * (inv_m[i] + np.dot(_cross(invI[i] @ rd, r), d))


@nb.njit(cache=True)
def _velocity_at(i, r, v, w):
    if i < 0:
        return np.zeros(3)
    return v[i] + _cross(w[i], r)


@nb.njit(cache=True)
def _apply(i, r, impulse, inv_m, invI, v, w, scale):
    if i < 0 or scale == 0.0:
        return
    v[i] += scale * inv_m[i] * impulse
    w[i] += scale * (invI[i] @ _cross(r, impulse))


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
def pgs(ia, ib, ra, rb, normal, target, mu, scale_a, scale_b, active, lam, inv_m, invI, v, w,
        iterations):
    """Projected Gauss-Seidel. Updates v, w (solver bodies) and lam (c, 3) in place.

    lam[:, 0] accumulates the normal impulse (N s), lam[:, 1:] the friction impulse in the
    contact's tangent basis. scale_a/scale_b (c,) multiply each side's inverse mass: 0 makes that
    side immovable for this call (shock propagation). Only contacts with active[k] take part.
    """
    c = len(ia)
    kn = np.zeros(c)
    kt = np.zeros((c, 2))
    tan = np.zeros((c, 2, 3))
    for k in range(c):
        if not active[k]:
            continue
        n = normal[k]
        t1, t2 = _tangents(n)
        tan[k, 0] = t1
        tan[k, 1] = t2
        a, b = ia[k], ib[k]
        kn[k] = (_inv_eff_mass(a, ra[k], n, inv_m, invI, scale_a[k])
                 + _inv_eff_mass(b, rb[k], n, inv_m, invI, scale_b[k]))
        kt[k, 0] = (_inv_eff_mass(a, ra[k], t1, inv_m, invI, scale_a[k])
                    + _inv_eff_mass(b, rb[k], t1, inv_m, invI, scale_b[k]))
        kt[k, 1] = (_inv_eff_mass(a, ra[k], t2, inv_m, invI, scale_a[k])
                    + _inv_eff_mass(b, rb[k], t2, inv_m, invI, scale_b[k]))
    for _ in range(iterations):
        for k in range(c):
            if not active[k] or kn[k] <= 0.0:
                continue
            a, b = ia[k], ib[k]
            n = normal[k]
            vrel = _velocity_at(a, ra[k], v, w) - _velocity_at(b, rb[k], v, w)
            # normal: reach the target normal velocity, accumulated impulse >= 0
            d = (target[k] - np.dot(vrel, n)) / kn[k]
            new = max(lam[k, 0] + d, 0.0)
            d = new - lam[k, 0]
            lam[k, 0] = new
            if d != 0.0:
                _apply(a, ra[k], d * n, inv_m, invI, v, w, scale_a[k])
                _apply(b, rb[k], -d * n, inv_m, invI, v, w, scale_b[k])
            # friction: stop tangential sliding, inside the Coulomb disk
            if mu[k] <= 0.0:
                continue
            vrel = _velocity_at(a, ra[k], v, w) - _velocity_at(b, rb[k], v, w)
            f1 = lam[k, 1] - np.dot(vrel, tan[k, 0]) / kt[k, 0]
            f2 = lam[k, 2] - np.dot(vrel, tan[k, 1]) / kt[k, 1]
            limit = mu[k] * lam[k, 0]
            norm = math.sqrt(f1 * f1 + f2 * f2)
            if norm > limit:
                f1 *= limit / norm
                f2 *= limit / norm
            d1, d2 = f1 - lam[k, 1], f2 - lam[k, 2]
            lam[k, 1], lam[k, 2] = f1, f2
            imp = d1 * tan[k, 0] + d2 * tan[k, 1]
            _apply(a, ra[k], imp, inv_m, invI, v, w, scale_a[k])
            _apply(b, rb[k], -imp, inv_m, invI, v, w, scale_b[k])
    # world impulse on side a of each contact
    out = np.zeros((c, 3))
    for k in range(c):
        out[k] = lam[k, 0] * normal[k] + lam[k, 1] * tan[k, 0] + lam[k, 2] * tan[k, 1]
    return out


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
