"""Compiled kernels of the coupled step's contact stages (numba, cached on disk).

Each replaces a chain of small numpy calls whose fixed cost, not their arithmetic, made up the
step's time (a 10k-tet slab meets a box with a few dozen points; the numpy chain cost 5-120 us a
call). They compute what the numpy code they replace computed, in the same order where it
matters (tests/test_step_kernels.py compares them on random inputs).
"""
import numba as nb
import numpy as np

from .places import unit_normal


@nb.njit(cache=True)
def surface_motion(x, surface_nodes, c, R, rest_center, rest_points):
    """One pass over a deformable body's surface nodes: ``(centre (3,), radius, moved (s, 3),
    largest)``. ``centre`` and ``radius`` (m) bound the current surface nodes ``x[surface_nodes]``
    in a sphere (their mean, and the farthest from it); ``moved`` is how far the deformation moved
    each from its rest place, in the body's rest frame: ``(x - c) R + X_c - X`` (floating frame:
    best-fit rotation R and centre c; anchored bodies: R = I, c = X_c); ``largest`` the longest
    of those (m)."""
    s = len(surface_nodes)
    centre = np.zeros(3)
    for i in range(s):
        for a in range(3):
            centre[a] += x[surface_nodes[i], a]
    for a in range(3):
        centre[a] = centre[a] / s
    far = 0.0
    largest = 0.0
    moved = np.empty((s, 3))
    for i in range(s):
        node = surface_nodes[i]
        d0 = x[node, 0] - centre[0]
        d1 = x[node, 1] - centre[1]
        d2 = x[node, 2] - centre[2]
        r2 = d0 * d0 + d1 * d1 + d2 * d2
        if r2 > far:
            far = r2
        y0 = x[node, 0] - c[0]
        y1 = x[node, 1] - c[1]
        y2 = x[node, 2] - c[2]
        m2 = 0.0
        for a in range(3):
            v = (y0 * R[0, a] + y1 * R[1, a] + y2 * R[2, a]) + rest_center[a] - rest_points[node, a]
            moved[i, a] = v
            m2 += v * v
        if m2 > largest:
            largest = m2
    return centre, np.sqrt(far), moved, np.sqrt(largest)


@nb.njit(cache=True)
def nearest_rows(points, queries):
    """Index ``(q,)`` of the row of ``points`` (s, 3) nearest each of ``queries`` (q, 3), by
    brute force (the lowest index among equally near rows): for a few queries, cheaper than
    building a k-d tree of points that move every step."""
    out = np.zeros(len(queries), dtype=np.int64)
    for k in range(len(queries)):
        q0, q1, q2 = queries[k, 0], queries[k, 1], queries[k, 2]
        best = np.inf
        for i in range(len(points)):
            d0 = points[i, 0] - q0
            d1 = points[i, 1] - q1
            d2 = points[i, 2] - q2
            d = d0 * d0 + d1 * d1 + d2 * d2
            if d < best:
                best = d
                out[k] = i
    return out


@nb.njit(cache=True)
def nearest_three_rows(points, queries):
    """Indices ``(q, min(3, s))`` of the rows of ``points`` (s, 3) nearest each of ``queries``
    (q, 3), nearest first (the lower index first among equally near rows), by brute force: for a
    few queries against a small surface, cheaper than a k-d tree's query, whose Python-level
    set-up dominates when the step has left the caches cold."""
    s, k = len(points), min(3, len(points))
    out = np.zeros((len(queries), k), dtype=np.int64)
    d = np.empty(s)
    for j in range(len(queries)):
        q0, q1, q2 = queries[j, 0], queries[j, 1], queries[j, 2]
        for i in range(s):
            d0 = points[i, 0] - q0
            d1 = points[i, 1] - q1
            d2 = points[i, 2] - q2
            d[i] = d0 * d0 + d1 * d1 + d2 * d2
        best = np.full(k, np.inf)
        for i in range(s):
            if d[i] < best[k - 1]:
                m = k - 1
                while m > 0 and d[i] < best[m - 1]:
                    best[m], out[j, m] = best[m - 1], out[j, m - 1]
                    m -= 1
                best[m], out[j, m] = d[i], i
    return out


@nb.njit(cache=True, inline="always")
def _corners(surface_nodes, triangles, f):
    """The node indices of surface triangle ``f``."""
    return surface_nodes[triangles[f, 0]], surface_nodes[triangles[f, 1]], surface_nodes[triangles[f, 2]]


@nb.njit(cache=True)
def flat_node_normals(x, surface_nodes, triangles, around, local, cos_min):
    """:func:`node_normals` of the surface nodes ``local`` that lie on a smooth part of their
    surface, every triangle around them within ``cos_min`` (cosine) of their normal; zero rows
    for the others (on an edge or a corner of their own body, where a node's normal is no
    surface's)."""
    out = node_normals(x, surface_nodes, triangles, around, local)
    for k in range(len(local)):
        for slot in range(around.shape[1]):
            f = around[local[k], slot]
            if f < 0:
                continue
            p, q, r = _corners(surface_nodes, triangles, f)
            m0, m1, m2 = unit_normal(x[p], x[q], x[r])
            if m0 * out[k, 0] + m1 * out[k, 1] + m2 * out[k, 2] < cos_min:
                out[k, 0], out[k, 1], out[k, 2] = 0.0, 0.0, 0.0
                break
    return out


@nb.njit(cache=True)
def node_normals(x, surface_nodes, triangles, around, local):
    """Outward unit normals ``(k, 3)`` of surface nodes ``local`` (indices into ``surface_nodes``):
    the sum of the cross products of the surface ``triangles`` (f, 3, indices into
    ``surface_nodes``) around each (``around`` (s, d), padded with -1) at positions ``x``, i.e.
    the area-weighted normal, normalised (a zero sum stays zero)."""
    out = np.zeros((len(local), 3))
    for k in range(len(local)):
        n0 = 0.0
        n1 = 0.0
        n2 = 0.0
        for slot in range(around.shape[1]):
            f = around[local[k], slot]
            if f < 0:
                continue
            p, q, r = _corners(surface_nodes, triangles, f)
            a0, a1, a2 = x[q, 0] - x[p, 0], x[q, 1] - x[p, 1], x[q, 2] - x[p, 2]
            b0, b1, b2 = x[r, 0] - x[p, 0], x[r, 1] - x[p, 1], x[r, 2] - x[p, 2]
            n0 += a1 * b2 - a2 * b1
            n1 += a2 * b0 - a0 * b2
            n2 += a0 * b1 - a1 * b0
        length = max(np.sqrt(n0 * n0 + n1 * n1 + n2 * n2), 1e-300)
        out[k, 0] = n0 / length
        out[k, 1] = n1 / length
        out[k, 2] = n2 / length
    return out


@nb.njit(cache=True)
def nearest_rows_of(x, rows, queries):
    """:func:`nearest_rows` of the points ``x[rows]`` (rows (s,) into x (n, 3)): the index into
    ``rows`` of the one nearest each query (the lowest among equally near ones). The points are
    gathered once into columns, so the distances of one query to all of them form a loop the
    compiler vectorises."""
    s = len(rows)
    px, py, pz = np.empty(s), np.empty(s), np.empty(s)
    for i in range(s):
        px[i], py[i], pz[i] = x[rows[i], 0], x[rows[i], 1], x[rows[i], 2]
    d = np.empty(s)
    out = np.zeros(len(queries), dtype=np.int64)
    for k in range(len(queries)):
        q0, q1, q2 = queries[k, 0], queries[k, 1], queries[k, 2]
        for i in range(s):
            d0 = px[i] - q0
            d1 = py[i] - q1
            d2 = pz[i] - q2
            d[i] = d0 * d0 + d1 * d1 + d2 * d2
        best = np.inf
        for i in range(s):
            if d[i] < best:
                best = d[i]
                out[k] = i
    return out


@nb.njit(cache=True)
def off_nodes_kept(x, surface_nodes, close, points, n_rest, R, distance, depth):
    """Which ``points`` (q, 3) world lie farther than ``distance`` (m) across their normal
    (``n_rest`` (q, 3) turned by ``R``) from the current position ``x`` of their nearest surface
    node ``surface_nodes[close]`` (q,), or more than ``depth`` (m) behind it along the normal,
    under it rather than over it: ``(q,)`` bool (hybrid.coupling.fem_contact._against)."""
    q = len(points)
    keep = np.empty(q, dtype=np.bool_)
    for k in range(q):
        i = surface_nodes[close[k]]
        a0, a1, a2 = x[i, 0] - points[k, 0], x[i, 1] - points[k, 1], x[i, 2] - points[k, 2]
        m0 = n_rest[k, 0] * R[0, 0] + n_rest[k, 1] * R[0, 1] + n_rest[k, 2] * R[0, 2]
        m1 = n_rest[k, 0] * R[1, 0] + n_rest[k, 1] * R[1, 1] + n_rest[k, 2] * R[1, 2]
        m2 = n_rest[k, 0] * R[2, 0] + n_rest[k, 1] * R[2, 1] + n_rest[k, 2] * R[2, 2]
        along = a0 * m0 + a1 * m1 + a2 * m2
        a0, a1, a2 = a0 - along * m0, a1 - along * m1, a2 - along * m2
        keep[k] = along > depth or a0 * a0 + a1 * a1 + a2 * a2 > distance * distance
    return keep


@nb.njit(cache=True)
def edge_turns(normal, gap, body_b, own, edge_cos, near):
    """Normals ``(c, 3)``, gaps ``(c,)`` and which contacts are met from the front ``(c,)`` of
    surface nodes' contacts (stacked node a, rigid body ``body_b`` >= 0 or a plane) whose nodes
    have their own outward normals ``own`` (r, 3), one per contact with a rigid body in order
    (hybrid.coupling.fem_contact.edge_normals; a node whose own normal is not a unit vector, or
    whose gap exceeds its contact's ``near`` (c,) m, keeps the contact's normal and gap)."""
    c = len(gap)
    out_n = normal.copy()
    out_gap = gap.copy()
    front = np.ones(c, dtype=np.bool_)
    r = 0
    for k in range(c):
        if body_b[k] < 0:
            continue
        m0, m1, m2 = -own[r, 0], -own[r, 1], -own[r, 2]
        r += 1
        along = normal[k, 0] * m0 + normal[k, 1] * m1 + normal[k, 2] * m2
        if along < -edge_cos:
            front[k] = False
        if along < edge_cos and gap[k] <= near[k] and abs(m0 * m0 + m1 * m1 + m2 * m2 - 1.0) < 1e-6:
            out_n[k, 0], out_n[k, 1], out_n[k, 2] = m0, m1, m2
            out_gap[k] = gap[k] * along     # the offset to the rigid surface, along the new normal
    return out_n, out_gap, front


@nb.njit(cache=True)
def sample_points(near, point_start, point_local, point_kind, skip_kind, position, rotation):
    """The sample points of rigid bodies ``near`` (b,) other than those of kind ``skip_kind``:
    their bodies ``owner`` (p,), indices ``at`` (p,) into ``point_local`` and world positions
    (p, 3), ``position[owner] + rotation[owner] point_local[at]``, body by body in order
    (hybrid.coupling.fem_contact.detect_rigid_points, in one pass)."""
    total = 0
    for j in range(len(near)):
        total += point_start[near[j] + 1] - point_start[near[j]]
    owner = np.empty(total, dtype=np.int64)
    at = np.empty(total, dtype=np.int64)
    x = np.empty((total, 3))
    p = 0
    for j in range(len(near)):
        b = near[j]
        for i in range(point_start[b], point_start[b + 1]):
            if point_kind[i] == skip_kind:
                continue
            owner[p], at[p] = b, i
            l0, l1, l2 = point_local[i, 0], point_local[i, 1], point_local[i, 2]
            for a in range(3):
                x[p, a] = position[b, a] + (rotation[b, a, 0] * l0 + rotation[b, a, 1] * l1
                                            + rotation[b, a, 2] * l2)
            p += 1
    return owner[:p], at[:p], x[:p]
