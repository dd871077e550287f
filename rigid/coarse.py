"""Two-level contact solve: coarse corrections between the Gauss-Seidel sweeps of rigid.solver.

A sweep corrects a body's velocity, per contact row, by the body's share of the row's response.
A heavy body touched only by light ones (1,000 kg on 1 kg) has a share of ~1e-3 per row, so the
impulses that carry its weight converge at that rate per sweep. The coarse correction solves for
such modes at once: rows are gathered into aggregates (between one pair of entities: a rigid
body, a deformable body's particles, the static world; normals along one axis), each spanning
three normal-impulse modes (the impulses the rows carry, and that times the two coordinates across
the patch: the net force and the two moments a patch passes), and the Galerkin system
P^T A P y = P^T r (A the normal Delassus operator through the sweeps' own responses, r the normal
velocity residuals) is solved directly; the impulses take the correction projected to >= 0 and the
sweeps go on. Aggregation-based two-level iteration with near-null modes per aggregate (Vanek,
Mandel, Brezina 1996), projected Gauss-Seidel as smoother and the coarse step projected onto the
admissible impulses as in monotone multigrid for contact (Kornhuber 1994). It runs only when some
entity's share (its response over the row's, summed over its rows) is below SHARE_MIN, over the
components of the contact graph that hold such an entity: mild mass ratios cost one pass.
"""
import math

import numba as nb
import numpy as np

from .cholesky import cholesky, solve_factored
from .particle_kernels import _apply_particle, _particle_velocity

# an entity whose rows give it less than this share of their correction per sweep is slow
SHARE_MIN = 0.2
COARSE_EVERY = 4        # sweeps between coarse corrections
# a coarse mode whose pivot falls below this share of its diagonal depends on the others: dropped
PIVOT_DROP = 1e-10


@nb.njit(cache=True)
def _cross3(a0, a1, a2, b0, b1, b2):
    """a x b of two vectors given by their components."""
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@nb.njit(cache=True)
def _rigid_velocity(v0, v1, v2, w0, w1, w2, r0, r1, r2):
    """Velocity v + w x r of a rigid body's point at arm r."""
    return v0 + w1 * r2 - w2 * r1, v1 + w2 * r0 - w0 * r2, v2 + w0 * r1 - w1 * r0


@nb.njit(cache=True)
def _push(i, r, k, j0, j1, j2, inv_m, invI, v, w, groups):
    """Impulse (j0, j1, j2) (world) on solver body i at arm r[k] (particles through their group)."""
    if groups is not None and groups[0][i] >= 0:
        _apply_particle(i, j0, j1, j2, v, groups)
        return
    m = inv_m[i]
    v[i, 0] += m * j0
    v[i, 1] += m * j1
    v[i, 2] += m * j2
    c0, c1, c2 = _cross3(r[k, 0], r[k, 1], r[k, 2], j0, j1, j2)
    w[i, 0] += invI[i, 0, 0] * c0 + invI[i, 0, 1] * c1 + invI[i, 0, 2] * c2
    w[i, 1] += invI[i, 1, 0] * c0 + invI[i, 1, 1] * c1 + invI[i, 1, 2] * c2
    w[i, 2] += invI[i, 2, 0] * c0 + invI[i, 2, 1] * c1 + invI[i, 2, 2] * c2


@nb.njit(cache=True)
def _velocity(i, r, k, v, w, groups):
    """World velocity of solver body i at arm r[k] (zero for the static world)."""
    if i < 0:
        return 0.0, 0.0, 0.0
    if groups is not None and groups[0][i] >= 0:
        return _particle_velocity(i, v, groups)
    return _rigid_velocity(v[i, 0], v[i, 1], v[i, 2], w[i, 0], w[i, 1], w[i, 2],
                           r[k, 0], r[k, 1], r[k, 2])


@nb.njit(cache=True)
def _normal_velocity(j, k, basis, ia, ib, ra, rb, v, w, groups):
    """Relative normal velocity of side a against side b at active contact j (contact k)."""
    x0, x1, x2 = _velocity(ia[k], ra, k, v, w, groups)
    y0, y1, y2 = _velocity(ib[k], rb, k, v, w, groups)
    return (basis[j, 0, 0] * (x0 - y0) + basis[j, 0, 1] * (x1 - y1)
            + basis[j, 0, 2] * (x2 - y2))


@nb.njit(cache=True)
def _push_normal(j, k, amount, basis, ia, ib, ra, rb, scale_a, scale_b, inv_m, invI, v, w, groups):
    """Normal impulse ``amount`` at active contact j (contact k): on side a, its opposite on b."""
    J0, J1, J2 = amount * basis[j, 0, 0], amount * basis[j, 0, 1], amount * basis[j, 0, 2]
    if ia[k] >= 0 and scale_a[k] != 0.0:
        s = scale_a[k]
        _push(ia[k], ra, k, s * J0, s * J1, s * J2, inv_m, invI, v, w, groups)
    if ib[k] >= 0 and scale_b[k] != 0.0:
        s = -scale_b[k]
        _push(ib[k], rb, k, s * J0, s * J1, s * J2, inv_m, invI, v, w, groups)


@nb.njit(cache=True)
def entities(idx, side_kn, K, ia, ib, n, groups):
    """Per active contact j, the entity of each side (m, 2): a rigid body's own index, n + g for
    the particles and places of group g (one deformable body), -1 for a side that does not move
    (the static world, a fixed body, a frozen side, a held node: no response); and whether any
    entity is slow: the sum over its rows of its normal response over the row's (side_kn (m, 2)
    over K[j, 0, 0]) is below SHARE_MIN. Rows inside one entity are left out (-1, -1)."""
    m = len(idx)
    # an entity can only be slow if one of its rows gives it less than SHARE_MIN: without such a
    # row (mild mass ratios) nothing more is needed
    low = False
    for j in range(m):
        for side in range(2):
            if 0.0 < side_kn[j, side] < SHARE_MIN * K[j, 0, 0]:
                low = True
    if not low:
        return np.zeros((0, 2), np.int64), np.zeros(0), False
    ent = np.full((m, 2), -1, np.int64)
    count = n
    if groups is not None:
        count += len(groups[1])
    share = np.zeros(count)
    touched = np.zeros(len(share), np.bool_)
    for j in range(m):
        if not K[j, 0, 0] > 0.0:
            continue
        k = idx[j]
        for side in range(2):
            i = ia[k] if side == 0 else ib[k]
            if i < 0 or not side_kn[j, side] > 0.0:
                continue
            e = i
            if groups is not None and groups[0][i] >= 0:
                e = n + groups[0][i]
            ent[j, side] = e
        if ent[j, 0] == ent[j, 1]:
            ent[j, 0] = ent[j, 1] = -1
            continue
        for side in range(2):
            e = ent[j, side]
            if e >= 0:
                share[e] += side_kn[j, side] / K[j, 0, 0]
                touched[e] = True
    slow = False
    for e in range(len(share)):
        if touched[e] and share[e] < SHARE_MIN:
            slow = True
    return ent, share, slow


@nb.njit(cache=True)
def _direction_bin(n0, n1, n2):
    """0..5: the world axis and sign a unit normal is closest to."""
    a0, a1, a2 = abs(n0), abs(n1), abs(n2)
    if a0 >= a1 and a0 >= a2:
        return 0 if n0 > 0 else 1
    if a1 >= a2:
        return 2 if n1 > 0 else 3
    return 4 if n2 > 0 else 5


@nb.njit(cache=True)
def _components(ent, share, count):
    """Connected components of the entities through the rows (the static world joins nothing);
    per component whether it holds a slow entity. Returns (component of each entity, slow)."""
    parent = np.arange(count)
    for j in range(len(ent)):
        a, b = ent[j, 0], ent[j, 1]
        if a < 0 or b < 0:
            continue
        while parent[a] != a:
            a = parent[a]
        while parent[b] != b:
            b = parent[b]
        if a != b:
            parent[max(a, b)] = min(a, b)
    for e in range(count):
        r = e
        while parent[r] != r:
            r = parent[r]
        parent[e] = r
    slow = np.zeros(count, np.bool_)
    for e in range(count):
        if share[e] > 0.0 and share[e] < SHARE_MIN:
            slow[parent[e]] = True
    return parent, slow


@nb.njit(cache=True)
def aggregates(idx, ent, share, rows, basis, point, lam):
    """The coarse space over the active contacts ``rows`` (bool (m,)): each row's aggregate
    (-1: none) and weights (m, 3) on its aggregate's modes (:func:`_mode_weights`), the
    aggregates' entities (A, 2), and each aggregate's first mode (A + 1,). Rows join an aggregate
    when they lie between the same two entities with normals closest to the same world axis (a
    box between the ground and a wall has one aggregate per face), in a component holding a slow
    entity."""
    m = len(idx)
    count = len(share)
    comp, slow = _components(ent, share, count)
    keys = np.full(m, -1, np.int64)
    for j in range(m):
        a, b = ent[j, 0], ent[j, 1]
        if not rows[j] or (a < 0 and b < 0) or not slow[comp[a] if a >= 0 else comp[b]]:
            continue
        n0, n1, n2 = basis[j, 0, 0], basis[j, 0, 1], basis[j, 0, 2]
        if a > b:                   # one orientation per pair: the lower entity on side a
            a, b, n0, n1, n2 = b, a, -n0, -n1, -n2
        keys[j] = ((a + 1) * (count + 1) + (b + 1)) * 6 + _direction_bin(n0, n1, n2)
    order = np.argsort(keys)
    agg = np.full(m, -1, np.int64)
    A = np.int64(0)     # (not the literal 0: _mode_weights would be compiled twice)
    for t in range(m):
        j = order[t]
        if keys[j] >= 0:
            if t == 0 or keys[j] != keys[order[t - 1]]:
                A += 1
            agg[j] = A - 1
    pair = np.full((A, 2), -1, np.int64)
    for j in range(m):
        if agg[j] >= 0:
            pair[agg[j], 0], pair[agg[j], 1] = ent[j, 0], ent[j, 1]
    weight, first = _mode_weights(idx, agg, A, basis, point, lam)
    return agg, weight, pair, first


@nb.njit(cache=True)
def _mode_weights(idx, agg, A, basis, point, lam):
    """Each row's weights (m, 3) on its aggregate's modes and each aggregate's first mode. The
    modes follow the impulses the rows carry now (the load path: under a box on a slab on the
    ground, the ground's rows below the box), scaled to a mean of one: that distribution, and it
    times the two coordinates across the patch from its centroid along the tangents of one of its
    rows, over the patch's radius (the moments a flat patch passes between rigid sides). The
    distribution alone for a single row or where the points are not given (``point`` empty)."""
    m = len(idx)
    size, carried, radius = np.zeros(A), np.zeros(A), np.zeros(A)
    centre, tangent = np.zeros((A, 3)), np.zeros((A, 2, 3))
    for j in range(m):
        g = agg[j]
        if g >= 0:
            size[g] += 1.0
            carried[g] += lam[idx[j], 0]
            for d in range(3):
                tangent[g, 0, d], tangent[g, 1, d] = basis[j, 1, d], basis[j, 2, d]
                if len(point):
                    centre[g, d] += point[idx[j], d]
    for j in range(m):
        g = agg[j]
        if g >= 0 and len(point):
            for d in range(3):
                radius[g] += (point[idx[j], d] - centre[g, d] / size[g]) ** 2
    first = np.zeros(A + 1, np.int64)
    for g in range(A):
        radius[g] = math.sqrt(radius[g] / size[g])
        first[g + 1] = first[g] + (3 if size[g] > 1 and radius[g] > 0.0 else 1)
    weight = np.zeros((m, 3))
    for j in range(m):
        g = agg[j]
        if g < 0:
            continue
        weight[j, 0] = lam[idx[j], 0] * size[g] / carried[g] if carried[g] > 0.0 else 1.0
        if first[g + 1] - first[g] == 3:
            for t in range(2):
                acc = 0.0
                for d in range(3):
                    acc += (point[idx[j], d] - centre[g, d] / size[g]) * tangent[g, t, d]
                weight[j, 1 + t] = weight[j, 0] * acc / radius[g]
    return weight, first


@nb.njit(cache=True)
def coarse_matrix(idx, agg, weight, pair, first, basis, ia, ib, ra, rb, scale_a, scale_b,
                  inv_m, invI, groups):
    """P^T A P (M, M): each mode's impulses applied to zero velocities through the solver
    bodies' responses, read back as the normal velocities of the rows of every aggregate that
    shares a moving entity with the mode's."""
    m, A = len(idx), len(pair)
    M = first[A]
    n = len(inv_m)
    dv, dw = np.zeros((n, 3)), np.zeros((n, 3))
    members = np.argsort(agg)          # rows grouped by aggregate (unaggregated first)
    start = np.zeros(A + 1, np.int64)
    for j in range(m):
        if agg[j] >= 0:
            start[agg[j] + 1] += 1
    for g in range(A):
        start[g + 1] += start[g]
    skip = m - start[A]
    Ac = np.zeros((M, M))
    for g in range(A):
        for t in range(first[g + 1] - first[g]):
            col = first[g] + t
            dv[:] = 0.0
            dw[:] = 0.0
            for s in range(start[g], start[g + 1]):
                j = members[skip + s]
                if weight[j, t] == 0.0:
                    continue
                _push_normal(j, idx[j], weight[j, t], basis, ia, ib, ra, rb, scale_a, scale_b,
                             inv_m, invI, dv, dw, groups)
            for h in range(A):
                if not _adjacent(pair, g, h):
                    continue
                for s in range(start[h], start[h + 1]):
                    j = members[skip + s]
                    du = _normal_velocity(j, idx[j], basis, ia, ib, ra, rb, dv, dw, groups)
                    for u in range(first[h + 1] - first[h]):
                        Ac[first[h] + u, col] += weight[j, u] * du
    for r in range(M):             # symmetric up to round-off
        for c in range(r + 1, M):
            s = 0.5 * (Ac[r, c] + Ac[c, r])
            Ac[r, c] = Ac[c, r] = s
    return Ac


@nb.njit(cache=True)
def _adjacent(pair, g, h):
    """Whether aggregates g and h share a moving entity."""
    for x in range(2):
        e = pair[g, x]
        if e >= 0 and (e == pair[h, 0] or e == pair[h, 1]):
            return True
    return False


@nb.njit(cache=True)
def coarse_space(idx, K, basis, ia, ib, ra, rb, point, target, scale_a, scale_b, lam, inv_m,
                 invI, v, w, groups, ent, share):
    """The coarse space of a solve and its factorised Galerkin matrix (agg, weight, first, L), over
    the rows that push or close faster than their target. Built once per solve, after its first
    sweeps have found the load path (a Galerkin correction over a fixed space only lowers the
    error's energy norm)."""
    m = len(idx)
    rows = np.zeros(m, np.bool_)
    for j in range(m):
        if not K[j, 0, 0] > 0.0 or (ent[j, 0] < 0 and ent[j, 1] < 0):
            continue
        k = idx[j]
        un = _normal_velocity(j, k, basis, ia, ib, ra, rb, v, w, groups)
        rows[j] = lam[k, 0] > 0.0 or un < target[k]
    agg, weight, pair, first = aggregates(idx, ent, share, rows, basis, point, lam)
    L = cholesky(coarse_matrix(idx, agg, weight, pair, first, basis, ia, ib, ra, rb, scale_a,
                               scale_b, inv_m, invI, groups), PIVOT_DROP)
    return agg, weight, first, L


@nb.njit(cache=True)
def coarse_step(idx, basis, ia, ib, ra, rb, target, scale_a, scale_b, lam, inv_m, invI, v, w,
                groups, agg, weight, first, L):
    """One coarse correction over the space :func:`coarse_space` built (lam, v, w change in place).
    Returns whether it mattered: it changed an impulse by more than 1e-5 of the largest."""
    m = len(idx)
    M = len(L)
    if M == 0:
        return False
    # Galerkin right-hand side: the modes' share of the normal velocity residuals
    b = np.zeros(M)
    for j in range(m):
        g = agg[j]
        if g < 0:
            continue
        k = idx[j]
        r = target[k] - _normal_velocity(j, k, basis, ia, ib, ra, rb, v, w, groups)
        for t in range(first[g + 1] - first[g]):
            b[first[g] + t] += weight[j, t] * r
    y = solve_factored(L, b)
    # the correction, projected onto non-negative impulses, applied once per row
    largest = change = 0.0
    step = np.zeros(m)
    residual = np.zeros(m)
    for j in range(m):
        g = agg[j]
        if g < 0:
            continue
        k = idx[j]
        d = 0.0
        for t in range(first[g + 1] - first[g]):
            d += weight[j, t] * y[first[g] + t]
        new = max(lam[k, 0] + d, 0.0)
        d = new - lam[k, 0]
        largest = max(largest, new)
        if d == 0.0:
            continue
        residual[j] = target[k] - _normal_velocity(j, k, basis, ia, ib, ra, rb, v, w, groups)
        step[j] = d
        change = max(change, abs(d))
    for j in range(m):
        if step[j] != 0.0:
            lam[idx[j], 0] += step[j]
            _push_normal(j, idx[j], step[j], basis, ia, ib, ra, rb, scale_a, scale_b, inv_m, invI,
                         v, w, groups)
    # the projection keeps the correction a descent only where the modes are well apart: nearly
    # dependent ones (rows between different pairs of bodies at one point along nearly one normal,
    # the corners that a pane's pieces share at its grips) cancel in huge opposite amounts, of
    # which the projection keeps one (impulses of 1e99 N s). A correction that raises the
    # energy 1/2 l.A l - l.target of the normal rows (its change -d.(r0 + r1)/2 over the rows it
    # changed, r the residuals before and after) is taken back
    gain = 0.0
    for j in range(m):
        if step[j] != 0.0:
            after = target[idx[j]] - _normal_velocity(j, idx[j], basis, ia, ib, ra, rb, v, w, groups)
            gain -= 0.5 * step[j] * (residual[j] + after)
    if gain > 0.0:
        for j in range(m):
            if step[j] != 0.0:
                lam[idx[j], 0] -= step[j]
                _push_normal(j, idx[j], -step[j], basis, ia, ib, ra, rb, scale_a, scale_b, inv_m,
                             invI, v, w, groups)
        return False
    return change > 1e-5 * largest
