"""Flat contact patches that spin: their normal load shared over the patch, so friction resists
the spin.

A rigid body resting on a face touches through many coplanar points, and how its weight is
shared among them is not determined: any split with the same total force and moment holds it.
Gauss-Seidel sweeps put it all on the first point they visit; when that is the middle of the
face (a cylinder's end fanned from its centre), friction there has no arm, and a puck spun on a
table turned at 20 rad/s for good. So for each flat patch between two rigid bodies (or a body
and a plane) that turns about its normal, the normal impulses are shared out again as equal
springs at the points would share them: the least-squares split with the same total force and
moment (linear in the points' place on the patch, none pulling). The sharing itself changes no
velocity; the patch's contacts are then swept again from it, friction acting at every point's
arm, in a few rounds of sharing and sweeping (the sweeps alone drift back to some other split,
and friction on it pushed a spinning puck 1 cm sideways).
"""
import numba as nb
import numpy as np

# a patch: at least this many contacts of one pair of bodies, their normals within this of each
# other (a body's points against the other's face and the other's against its own face, tilted
# by round-off: 1e-9 let a puck on a fixed box lose its patch for steps at a time)
MIN_POINTS = 3
SAME_NORMAL = 1e-6
# relative speed (m/s) of the patch's farthest point from turning about the normal below which it
# is taken to be at rest (the sweeps' own answer is kept)
SPIN_SPEED = 1e-3
# rounds of taking out points the linear split would have pulling
ROUNDS = 8


def spinning_patches(body_a, body_b, point, normal, rigid_pair, angular):
    """The flat patches that turn about their normal, as ``(rows, starts)``: contact indices
    grouped by patch, patch p being ``rows[starts[p]:starts[p + 1]]``; None if there are none.
    ``rigid_pair`` (c,): the contacts between rigid bodies or a rigid body and a plane
    (``body_b`` < 0); ``angular`` (n, 3) rad/s: the solver bodies' angular velocities.
    (:func:`spinning_patches_numpy` in one compiled pass over the sorted contacts: it runs in
    every contact pass, and its twenty array calls were a sixth of a step of the default scene.)"""
    rows = np.nonzero(rigid_pair)[0]
    if len(rows) < MIN_POINTS:
        return None
    rows = rows[np.argsort(_pair_keys(body_a[rows], body_b[rows], len(angular)), kind="stable")]
    keep, starts = _spinning(rows, body_a, body_b, point, normal, angular)
    if len(starts) == 1:
        return None
    return rows[keep], starts


def _pair_keys(a, b, n):
    """A key per contact for its pair of bodies ``a``, ``b`` (b < 0: a plane) whichever side
    each is on: a body's points against the other's surface and the other's against its own
    are one patch (the pair's weight may rest on either: a puck on a fixed box carried it all on
    the box's one point against the puck, and its 165 points against the box, sharing nothing,
    left it spinning)."""
    low = np.minimum(a, b).astype(np.int64)
    high = np.maximum(a, b).astype(np.int64)
    return (low + 1) * (n + 2) + high + 1


@nb.njit(cache=True)
def _spinning(rows, body_a, body_b, point, normal, angular):
    """Of contacts ``rows`` sorted by pair of bodies: which lie in a spinning patch (bool,) and
    the patches' starts in those, as :func:`spinning_patches` says."""
    c = len(rows)
    keep = np.zeros(c, dtype=np.bool_)
    starts = [0]
    kept = 0
    s = 0
    while s < c:
        a, b = body_a[rows[s]], body_b[rows[s]]
        e = s + 1
        while e < c and (body_a[rows[e]] == a and body_b[rows[e]] == b
                         or body_a[rows[e]] == b and body_b[rows[e]] == a):
            e += 1
        n = normal[rows[s]]
        deviation, centre = 0.0, np.zeros(3)
        for i in range(s, e):
            r = rows[i]
            side = 1.0 if body_a[r] == a else -1.0      # the other side's contacts face back
            for d in range(3):
                deviation = max(deviation, abs(side * normal[r, d] - n[d]))
                centre[d] += point[r, d]
        centre /= e - s
        arm = 0.0
        for i in range(s, e):
            r = rows[i]
            arm = max(arm, np.sqrt((point[r, 0] - centre[0]) ** 2 + (point[r, 1] - centre[1]) ** 2
                                   + (point[r, 2] - centre[2]) ** 2))
        spin = 0.0
        for d in range(3):
            spin += (angular[a, d] - (angular[b, d] if b >= 0 else 0.0)) * n[d]
        if e - s >= MIN_POINTS and deviation <= SAME_NORMAL and abs(spin) * arm > SPIN_SPEED:
            keep[s:e] = True
            kept += e - s
            starts.append(kept)
        s = e
    return keep, np.array(starts, dtype=np.int64)


def spinning_patches_numpy(body_a, body_b, point, normal, rigid_pair, angular):
    """:func:`spinning_patches` in array calls (the reference its kernel is tested against)."""
    rows = np.nonzero(rigid_pair)[0]
    if len(rows) < MIN_POINTS:
        return None
    pair = _pair_keys(body_a[rows], body_b[rows], len(angular))
    order = np.argsort(pair, kind="stable")
    rows = rows[order]
    starts = np.flatnonzero(np.r_[True, np.diff(pair[order]) != 0])
    size = np.diff(np.r_[starts, len(rows)])
    first = rows[starts]
    n = normal[first]
    side = np.where(body_a[rows] == np.repeat(body_a[first], size), 1.0, -1.0)[:, None]
    deviation = np.maximum.reduceat(np.abs(side * normal[rows] - np.repeat(n, size, axis=0)).max(axis=1),
                                    starts)
    a, b = body_a[first], body_b[first]
    spin = np.einsum("pd,pd->p", angular[a] - np.where((b >= 0)[:, None], angular[np.maximum(b, 0)], 0.0), n)
    centre = np.add.reduceat(point[rows], starts) / size[:, None]
    arm = np.maximum.reduceat(np.linalg.norm(point[rows] - np.repeat(centre, size, axis=0), axis=1), starts)
    spinning = (size >= MIN_POINTS) & (deviation <= SAME_NORMAL) & (np.abs(spin) * arm > SPIN_SPEED)
    if not spinning.any():
        return None
    keep = np.repeat(spinning, size)
    return rows[keep], np.r_[0, np.cumsum(size[spinning])]


@nb.njit(cache=True)
def share_loads(point, normal, rows, starts, load):
    """For each patch (``rows[starts[p]:starts[p + 1]]``, normal that of its first contact, up to
    sign: a contact of the other side's facing back pushes the pair apart as one of this side's
    at its point does) the
    normal impulses ``load`` (c,) of its contacts replaced by the least-squares split with the
    same total and moment, linear over the patch, with none below zero (points it would have
    pulling take none, the rest share it again), shared over the side with more points (the
    other side's take none); in place. A patch whose points lie on a line (not every moment can
    be met) keeps its loads."""
    for p in range(len(starts) - 1):
        group = rows[starts[p]:starts[p + 1]]
        k = len(group)
        n = normal[group[0]]
        t1 = _cross(n, np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
        t1 /= np.sqrt(t1 @ t1)
        t2 = _cross(n, t1)
        mean = np.zeros(3)
        for i in range(k):
            mean += point[group[i]]
        mean /= k
        basis = np.ones((k, 3))
        for i in range(k):
            d = point[group[i]] - mean
            basis[i, 1], basis[i, 2] = d @ t1, d @ t2
        wanted = basis.T @ load[group]
        scale = max(abs(wanted[0]), 1e-300)
        # shared over the side with more points (a body's face's sample points), the other
        # side's few points facing back giving theirs up (a table's point under a box's centre
        # would count that centre twice)
        keep = np.empty(k, dtype=np.bool_)
        for i in range(k):
            keep[i] = normal[group[i]] @ n > 0.0
        if 2 * keep.sum() < k:
            keep = ~keep
        for _ in range(ROUNDS):
            B = basis[keep]
            G = B.T @ B
            if abs(np.linalg.det(G)) <= 1e-12 * max(G[1, 1] * G[2, 2] * G[0, 0], 1e-300):
                break                           # (points on a line)
            c = np.linalg.solve(G, wanted)
            shared = basis @ c
            low = 0.0
            for i in range(k):
                if not keep[i]:
                    shared[i] = 0.0
                low = min(low, shared[i])
            if low >= -1e-12 * scale:
                for i in range(k):
                    load[group[i]] = max(shared[i], 0.0)
                break
            count = 0
            for i in range(k):
                keep[i] = keep[i] and shared[i] > 0.0
                count += keep[i]
            if count < MIN_POINTS:
                break


@nb.njit(cache=True)
def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])
