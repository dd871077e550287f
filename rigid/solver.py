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

from .coarse import _cross3, _push, _rigid_velocity, coarse_space, coarse_step, entities
from .coarse import COARSE_EVERY
from .particle_kernels import (_add_pair_block, _apply_particle, _particle_velocity,
                               _rotate_particles, with_place_rows)


@nb.njit(cache=True)
def arms(ia, ib, point, x):
    """Contact arms r = p - x for both sides (zero for the static side)."""
    c = len(ia)
    ra = np.zeros((c, 3))
    rb = np.zeros((c, 3))
    for k in range(c):
        a, b = ia[k], ib[k]
        for d in range(3):
            ra[k, d] = point[k, d] - x[a, d]
            if b >= 0:
                rb[k, d] = point[k, d] - x[b, d]
    return ra, rb


@nb.njit(cache=True)
def normal_velocity(ia, ib, ra, rb, normal, v, w):
    """(c,) relative normal velocity of side a against side b at each contact (rigid bodies:
    v + w x r; the static world -1 is at rest)."""
    c = len(ia)
    out = np.empty(c)
    for k in range(c):
        a, b = ia[k], ib[k]
        x0 = x1 = x2 = y0 = y1 = y2 = 0.0
        if a >= 0:
            c0, c1, c2 = _cross3(w[a, 0], w[a, 1], w[a, 2], ra[k, 0], ra[k, 1], ra[k, 2])
            x0, x1, x2 = v[a, 0] + c0, v[a, 1] + c1, v[a, 2] + c2
        if b >= 0:
            c0, c1, c2 = _cross3(w[b, 0], w[b, 1], w[b, 2], rb[k, 0], rb[k, 1], rb[k, 2])
            y0, y1, y2 = v[b, 0] + c0, v[b, 1] + c1, v[b, 2] + c2
        out[k] = (x0 - y0) * normal[k, 0] + (x1 - y1) * normal[k, 1] + (x2 - y2) * normal[k, 2]
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


# The sweeps' kernels are compiled twice: with ``groups`` the tuple of group arrays (some solver
# bodies are particles of deformable bodies), and with ``groups`` None (rigid bodies only), in
# which numba prunes every particle branch. The branches must stay out of the rigid-only code: a
# per-contact test of group_of, even one never taken, made the 100-box pile's sweeps 5x slower.
# Arrays are indexed element by element in the per-contact helpers (no row views).


@nb.njit(cache=True)
def _apply(i, r, k, j0, j1, j2, scale, inv_m, invI, v, w, groups):
    """Impulse scale * (j0, j1, j2) (world) on solver body i at arm r[k] (the warm start's; the
    sweeps spell the same out)."""
    if i < 0 or scale == 0.0:
        return
    _push(i, r, k, scale * j0, scale * j1, scale * j2, inv_m, invI, v, w, groups)


@nb.njit(cache=True)
def _apply_pair(j, k, l0, l1, l2, basis, ia, ib, ra, rb, scale_a, scale_b, inv_m, invI, v, w, groups):
    """Impulse l0 n + l1 t1 + l2 t2 (contact j's basis) on side a of contact k, its opposite on b."""
    J0 = l0 * basis[j, 0, 0] + l1 * basis[j, 1, 0] + l2 * basis[j, 2, 0]
    J1 = l0 * basis[j, 0, 1] + l1 * basis[j, 1, 1] + l2 * basis[j, 2, 1]
    J2 = l0 * basis[j, 0, 2] + l1 * basis[j, 1, 2] + l2 * basis[j, 2, 2]
    _apply(ia[k], ra, k, J0, J1, J2, scale_a[k], inv_m, invI, v, w, groups)
    _apply(ib[k], rb, k, -J0, -J1, -J2, scale_b[k], inv_m, invI, v, w, groups)


@nb.njit(cache=True, inline="always")
def _response(i, r, k, basis, j, scale, inv_m, invI, groups, K, Db):
    """Add to K[j] (3, 3) the velocity of body i at arm r[k] along the rows of basis[j] per unit
    impulse along them, times scale (Db: (3, 3) scratch)."""
    if i < 0 or scale == 0.0:
        return
    if groups is not None:
        if groups[0][i] >= 0:
            _add_pair_block(i, i, basis[j], scale, groups, K[j], Db)
            return
    r0, r1, r2 = r[k, 0], r[k, 1], r[k, 2]
    for e in range(3):
        d0, d1, d2 = basis[j, e, 0], basis[j, e, 1], basis[j, e, 2]
        c0, c1, c2 = r1 * d2 - r2 * d1, r2 * d0 - r0 * d2, r0 * d1 - r1 * d0   # r x d
        a0 = invI[i, 0, 0] * c0 + invI[i, 0, 1] * c1 + invI[i, 0, 2] * c2
        a1 = invI[i, 1, 0] * c0 + invI[i, 1, 1] * c1 + invI[i, 1, 2] * c2
        a2 = invI[i, 2, 0] * c0 + invI[i, 2, 1] * c1 + invI[i, 2, 2] * c2
        m = inv_m[i]
        dv0, dv1, dv2 = m * d0 + a1 * r2 - a2 * r1, m * d1 + a2 * r0 - a0 * r2, m * d2 + a0 * r1 - a1 * r0
        for f in range(3):
            K[j, f, e] += scale * (basis[j, f, 0] * dv0 + basis[j, f, 1] * dv1 + basis[j, f, 2] * dv2)


@nb.njit(cache=True)
def _responses(idx, basis, ia, ib, ra, rb, scale_a, scale_b, inv_m, invI, groups):
    """(m, 3, 3) response of each active contact's relative velocity, in its basis, per unit
    impulse along its basis (the Delassus block of the contact, both sides' scales applied); and
    (m, 2) each side's own part of the normal response (the share rigid.coarse weighs)."""
    K = np.zeros((len(idx), 3, 3))
    side = np.zeros((len(idx), 2))
    Db = np.empty((3, 3))
    for j in range(len(idx)):
        k = idx[j]
        a, b = ia[k], ib[k]
        _response(a, ra, k, basis, j, scale_a[k], inv_m, invI, groups, K, Db)
        side[j, 0] = K[j, 0, 0]
        _response(b, rb, k, basis, j, scale_b[k], inv_m, invI, groups, K, Db)
        side[j, 1] = K[j, 0, 0] - side[j, 0]
        if groups is not None:
            group_of = groups[0]
            if a >= 0 and b >= 0 and group_of[a] >= 0 and group_of[a] == group_of[b]:
                # both sides in one deformable body: an impulse on one side moves the other too
                _add_pair_block(a, b, basis[j], -scale_b[k], groups, K[j], Db)
                _add_pair_block(b, a, basis[j], -scale_a[k], groups, K[j], Db)
    return K, side


@nb.njit(cache=True)
def _inverse_responses(K):
    """(m, 2): per contact the inverse of its normal response K[j, 0, 0] and of the larger
    tangential one (0 where that is not positive). The sweeps multiply by them: a division in
    every row of every sweep lay on the chain of dependent operations from one contact to the
    next (the 100-box pile's sweeps 16% faster; the impulses change by round-off)."""
    out = np.zeros((len(K), 2))
    for j in range(len(K)):
        if K[j, 0, 0] > 0.0:
            out[j, 0] = 1.0 / K[j, 0, 0]
        ktt = max(K[j, 1, 1], K[j, 2, 2])
        if ktt > 0.0:
            out[j, 1] = 1.0 / ktt
    return out


@nb.njit(cache=True)
def _solve_normal(inv_kn, target, lam_n, un):
    """Normal row (inverse response inv_kn): the accumulated impulse, >= 0, that reaches the
    target normal velocity from the normal velocity un; returns it and its change."""
    new = max(lam_n + (target - un) * inv_kn, 0.0)
    return new, new - lam_n


@nb.njit(cache=True)
def _solve_friction(inv_ktt, limit, lam1, lam2, u1, u2):
    """Friction rows: both tangents at once, each stopped through the larger of the two
    tangential responses (inverse inv_ktt; never past the answer on either), and the pair
    projected radially into the Coulomb disk of radius ``limit`` (mu lambda_n), so a sliding
    contact's friction opposes its sliding velocity (u1, u2). Returns the new accumulated pair.

    Clamped one tangent after the other, a sliding node whose lateral vibration asked more than
    the disk held got friction at 45 degrees to its motion, or along it (a Newmark block slid at
    0.90 mu g); through the full 2x2 response, a sliding box's corners (whose response turns with
    their lever arms) pulled askew and it slid 2% too far down a slope."""
    f1 = lam1 - u1 * inv_ktt if inv_ktt > 0.0 else lam1
    f2 = lam2 - u2 * inv_ktt if inv_ktt > 0.0 else lam2
    norm = math.sqrt(f1 * f1 + f2 * f2)
    if norm > limit:
        scale = limit / norm if norm > 0.0 else 0.0
        f1, f2 = f1 * scale, f2 * scale
    return f1, f2


@nb.njit(cache=True)
def _sweeps(idx, K, inverse, basis, ia, ib, ra, rb, target, mu, scale_a, scale_b, lam, inv_m, invI,
            v, w, iterations, groups):
    """Gauss-Seidel sweeps over the active contacts (see pgs), until no impulse changes by more
    than 1e-7 of the largest. Each contact is a block: normal row, then both friction rows with
    the normal row's change seen through the 3x3 response K[j] (inverse: _inverse_responses);
    the sum is applied once. Returns the number of sweeps done.
    (Written flat: a call that passes arrays costs reference counts per contact, and the rigid
    bodies' velocities and impulses are spelt out here; particles go through their helpers.)"""
    for sweep in range(iterations):
        largest_change = 0.0
        largest = 0.0
        for j in range(len(idx)):
            if not K[j, 0, 0] > 0.0:    # no effective mass (both sides immovable): no row
                continue
            k = idx[j]
            a, b = ia[k], ib[k]
            # relative velocity of side a against side b at the contact, in its basis
            x0 = x1 = x2 = y0 = y1 = y2 = 0.0
            if a >= 0:
                if groups is not None and groups[0][a] >= 0:
                    x0, x1, x2 = _particle_velocity(a, v, groups)
                else:
                    x0, x1, x2 = _rigid_velocity(v[a, 0], v[a, 1], v[a, 2], w[a, 0], w[a, 1],
                                                 w[a, 2], ra[k, 0], ra[k, 1], ra[k, 2])
            if b >= 0:
                if groups is not None and groups[0][b] >= 0:
                    y0, y1, y2 = _particle_velocity(b, v, groups)
                else:
                    y0, y1, y2 = _rigid_velocity(v[b, 0], v[b, 1], v[b, 2], w[b, 0], w[b, 1],
                                                 w[b, 2], rb[k, 0], rb[k, 1], rb[k, 2])
            x0, x1, x2 = x0 - y0, x1 - y1, x2 - y2
            u0 = basis[j, 0, 0] * x0 + basis[j, 0, 1] * x1 + basis[j, 0, 2] * x2
            u1 = basis[j, 1, 0] * x0 + basis[j, 1, 1] * x1 + basis[j, 1, 2] * x2
            u2 = basis[j, 2, 0] * x0 + basis[j, 2, 1] * x1 + basis[j, 2, 2] * x2
            # normal row, then the friction rows seeing its change through the response
            new, d0 = _solve_normal(inverse[j, 0], target[k], lam[k, 0], u0)
            lam[k, 0] = new
            d1 = d2 = 0.0
            if mu[k] > 0.0:
                u1 += K[j, 1, 0] * d0
                u2 += K[j, 2, 0] * d0
                f1, f2 = _solve_friction(inverse[j, 1], mu[k] * new, lam[k, 1], lam[k, 2], u1, u2)
                d1 += f1 - lam[k, 1]
                d2 += f2 - lam[k, 2]
                lam[k, 1], lam[k, 2] = f1, f2
            largest = max(largest, new)
            change = max(abs(d0), abs(d1), abs(d2))
            if change == 0.0:
                continue
            largest_change = max(largest_change, change)
            # the block's change of impulse, world, on side a and its opposite on side b
            J0 = d0 * basis[j, 0, 0] + d1 * basis[j, 1, 0] + d2 * basis[j, 2, 0]
            J1 = d0 * basis[j, 0, 1] + d1 * basis[j, 1, 1] + d2 * basis[j, 2, 1]
            J2 = d0 * basis[j, 0, 2] + d1 * basis[j, 1, 2] + d2 * basis[j, 2, 2]
            for side in range(2):
                i, r, s = (a, ra, scale_a[k]) if side == 0 else (b, rb, scale_b[k])
                if i < 0 or s == 0.0:
                    continue
                if side == 1:
                    s = -s
                j0, j1, j2 = s * J0, s * J1, s * J2
                if groups is not None and groups[0][i] >= 0:
                    _apply_particle(i, j0, j1, j2, v, groups)
                    continue
                m = inv_m[i]
                v[i, 0] += m * j0
                v[i, 1] += m * j1
                v[i, 2] += m * j2
                c0, c1, c2 = _cross3(r[k, 0], r[k, 1], r[k, 2], j0, j1, j2)
                w[i, 0] += invI[i, 0, 0] * c0 + invI[i, 0, 1] * c1 + invI[i, 0, 2] * c2
                w[i, 1] += invI[i, 1, 0] * c0 + invI[i, 1, 1] * c1 + invI[i, 1, 2] * c2
                w[i, 2] += invI[i, 2, 0] * c0 + invI[i, 2, 1] * c1 + invI[i, 2, 2] * c2
        if sweep > 0 and largest_change <= 1e-7 * largest:
            return sweep + 1
    return iterations


@nb.njit(cache=True)
def _pgs(ia, ib, ra, rb, normal, target, mu, scale_a, scale_b, active, lam, inv_m, invI, v, w,
         iterations, groups, apply_lam):
    """:func:`pgs` with the group arrays as one tuple, or None when no solver body is a particle."""
    return solve_groups(ia, ib, ra, rb, np.zeros((0, 3)), normal, target, mu, scale_a, scale_b,
                        active, lam, inv_m, invI, v, w, iterations, groups, apply_lam)


@nb.njit(cache=True)
def solve_groups(ia, ib, ra, rb, point, normal, target, mu, scale_a, scale_b, active, lam, inv_m,
                 invI, v, w, iterations, groups, apply_lam):
    """:func:`pgs_at` with the particles' arrays as :func:`solver_groups` makes them (None when no
    solver body is a particle), compiled once for each of the two."""
    idx = np.nonzero(active)[0]
    basis = contact_basis(normal[idx])
    K, side_kn = _responses(idx, basis, ia, ib, ra, rb, scale_a, scale_b, inv_m, invI, groups)
    if groups is not None:      # particle velocities stay in their group's frame during the sweeps
        _rotate_particles(v, groups[0], groups[1], True)
    if apply_lam:       # warm start: the impulses lam holds act first
        for j in range(len(idx)):
            k = idx[j]
            if not K[j, 0, 0] > 0.0:    # a guess on a contact nothing can move: it takes none
                lam[k, 0] = lam[k, 1] = lam[k, 2] = 0.0
            else:
                _apply_pair(j, k, lam[k, 0], lam[k, 1], lam[k, 2], basis, ia, ib, ra, rb, scale_a,
                            scale_b, inv_m, invI, v, w, groups)
    inverse = _inverse_responses(K)
    # a body that takes too small a share of its rows' corrections converges slowly in the sweeps:
    # then they alternate with coarse corrections (rigid.coarse)
    ent, share, slow = entities(idx, side_kn, K, ia, ib, len(inv_m), groups)
    if not slow:
        _sweeps(idx, K, inverse, basis, ia, ib, ra, rb, target, mu, scale_a, scale_b, lam, inv_m,
                invI, v, w, iterations, groups)
    else:
        agg, weight = np.zeros(0, np.int64), np.zeros((0, 3))
        first, L = np.zeros(1, np.int64), np.zeros((0, 0))
        done = 0
        coarse = True
        while done < iterations:
            # sweeps in chunks between coarse corrections (the first longer: a warm-started solve
            # often converges without any)
            chunk = iterations - done
            if coarse:
                chunk = min(chunk, COARSE_EVERY * (3 if done == 0 else 1))
            swept = _sweeps(idx, K, inverse, basis, ia, ib, ra, rb, target, mu, scale_a, scale_b,
                            lam, inv_m, invI, v, w, chunk, groups)
            done += swept
            # converged (a warm-started resting solve often is), or the sweeps have had their
            # number and the last word (friction in its cone)
            if swept < chunk or done >= iterations:
                break
            if len(agg) == 0:       # the coarse space, once sweeps have found the load path
                agg, weight, first, L = coarse_space(idx, K, basis, ia, ib, ra, rb, point, target,
                                                     scale_a, scale_b, lam, inv_m, invI, v, w,
                                                     groups, ent, share)
            # once a correction changes nothing that counts, the sweeps go on alone
            coarse = coarse_step(idx, basis, ia, ib, ra, rb, target, scale_a, scale_b, lam, inv_m,
                                 invI, v, w, groups, agg, weight, first, L)
    if groups is not None:
        _rotate_particles(v, groups[0], groups[1], False)
    out = np.full((len(ia), 3), np.nan)
    for j in range(len(idx)):
        k = idx[j]
        for d in range(3):
            out[k, d] = lam[k, 0] * basis[j, 0, d] + lam[k, 1] * basis[j, 1, d] + lam[k, 2] * basis[j, 2, d]
    return out


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
    Sweeps stop early once no impulse changes by more than 1e-7 of the largest. When a body
    takes too small a share of its contacts' corrections (a heavy body on light ones), coarse
    corrections (rigid.coarse) alternate with the sweeps; here over uniform modes only (the contact
    points are not given: :func:`pgs_at` takes them). Returns the world impulse on side a of each
    contact, (c, 3) N s (NaN rows for inactive contacts).
    (A Python function choosing the compiled sweeps: see :func:`solver_groups`.)
    """
    groups = solver_groups(ia, ib, (group_of, group_R, w_ptr, w_col, W, corner, corner_w))
    return _pgs(ia, ib, ra, rb, normal, target, mu, scale_a, scale_b, active, lam, inv_m, invI, v,
                w, iterations, groups, apply_lam)


def pgs_at(ia, ib, ra, rb, point, normal, target, mu, scale_a, scale_b, active, lam, inv_m, invI,
           v, w, iterations, group_of, group_R, w_ptr, w_col, W, corner, corner_w, apply_lam):
    """:func:`pgs` with the contacts' world points ``point`` (c, 3) m, so the coarse corrections
    also span the moments across each contact patch (rigid.coarse.aggregates)."""
    groups = solver_groups(ia, ib, (group_of, group_R, w_ptr, w_col, W, corner, corner_w))
    return solve_groups(ia, ib, ra, rb, point, normal, target, mu, scale_a, scale_b, active, lam,
                        inv_m, invI, v, w, iterations, groups, apply_lam)


def solver_groups(ia, ib, groups):
    """What the compiled sweeps take for the particles: None when no solver body is one (the
    sweeps compiled without the particle branches), else ``groups`` (group_of, group_R, w_ptr,
    w_col, W, corner, corner_w) extended by the rows of the places any contact (ia, ib) touches
    (:func:`rigid.particle_kernels.with_place_rows`). Chosen here, outside the compiled code, so
    that a scene of rigid bodies never compiles the particle sweeps and one with deformable bodies
    compiles them once: a compiled choice compiled both (17-21 s on a cleared cache)."""
    if not (np.asarray(groups[0]) >= 0).any():
        return None
    return with_place_rows(ia, ib, groups)
