"""Compiled kernels of the coupled step's contact stages (numba, cached on disk).

Each replaces a chain of small numpy calls whose fixed cost, not their arithmetic, made up the
step's time (a 10k-tet slab meets a box with a few dozen points; the numpy chain cost 5-120 us a
call). They compute what the numpy code they replace computed, in the same order where it
matters (tests/test_step_kernels.py compares them on random inputs).
"""
import numba as nb
import numpy as np


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
            p = surface_nodes[triangles[f, 0]]
            q = surface_nodes[triangles[f, 1]]
            r = surface_nodes[triangles[f, 2]]
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


@nb.njit(cache=True, inline="always")
def _ratio(num, den):
    return num / (den if den != 0 else 1.0)


@nb.njit(cache=True)
def closest_weights(p0, p1, p2, a, b, c):
    """Barycentric weights ``(v, w)`` of the point of triangle ``a, b, c`` (3,) closest to
    ``(p0, p1, p2)``: ``a + v (b - a) + w (c - a)`` (Ericson, Real-Time Collision Detection,
    5.1.5; the regions of rigid.sdf.closest_point_weights in its order of priority)."""
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ac0, ac1, ac2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    ap0, ap1, ap2 = p0 - a[0], p1 - a[1], p2 - a[2]
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    bp0, bp1, bp2 = p0 - b[0], p1 - b[1], p2 - b[2]
    d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
    d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
    cp0, cp1, cp2 = p0 - c[0], p1 - c[1], p2 - c[2]
    d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
    d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    if d1 <= 0 and d2 <= 0:                                     # corner a
        return 0.0, 0.0
    if d3 >= 0 and d4 <= d3:                                    # corner b
        return 1.0, 0.0
    if d6 >= 0 and d5 <= d6:                                    # corner c
        return 0.0, 1.0
    if vc <= 0 and d1 >= 0 and d3 <= 0:                         # edge ab
        return _ratio(d1, d1 - d3), 0.0
    if vb <= 0 and d2 >= 0 and d6 <= 0:                         # edge ac
        return 0.0, _ratio(d2, d2 - d6)
    if va <= 0 and d4 >= d3 and d5 >= d6:                       # edge bc
        edge_bc = _ratio(d4 - d3, (d4 - d3) + (d5 - d6))
        return 1.0 - edge_bc, edge_bc
    total = va + vb + vc
    return _ratio(vb, total), _ratio(vc, total)


@nb.njit(cache=True, inline="always")
def _unit_normal(t0, t1, t2):
    a0, a1, a2 = t1[0] - t0[0], t1[1] - t0[1], t1[2] - t0[2]
    b0, b1, b2 = t2[0] - t0[0], t2[1] - t0[1], t2[2] - t0[2]
    n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    length = max(np.sqrt(n0 * n0 + n1 * n1 + n2 * n2), 1e-300)
    return n0 / length, n1 / length, n2 / length


@nb.njit(cache=True)
def turned(v, rest, now):
    """``v`` (3,) turned by the smallest rotation taking the unit normal of triangle ``rest``
    (3, 3) to that of ``now`` (3, 3) (Rodrigues); ``v`` itself where the triangle turned by more
    than 90 degrees (hybrid.coupling.fem_contact._turn)."""
    a0, a1, a2 = _unit_normal(rest[0], rest[1], rest[2])
    b0, b1, b2 = _unit_normal(now[0], now[1], now[2])
    x0, x1, x2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    cos = a0 * b0 + a1 * b1 + a2 * b2
    out = np.empty(3)
    if not cos > 0.0:
        out[:] = v
        return out
    k = 1.0 / (1.0 + cos)
    along = k * (x0 * v[0] + x1 * v[1] + x2 * v[2])
    out[0] = v[0] * cos + (x1 * v[2] - x2 * v[1]) + x0 * along
    out[1] = v[1] * cos + (x2 * v[0] - x0 * v[2]) + x1 * along
    out[2] = v[2] * cos + (x0 * v[1] - x1 * v[0]) + x2 * along
    return out


@nb.njit(cache=True)
def face_normal(rest, now):
    """Unit outward normal (3,) of triangle ``now`` (3, 3), as its rest normal (``rest`` (3, 3))
    turned with it (:func:`turned`: the rest normal itself where it turned by more than 90
    degrees, an inverted triangle)."""
    a = np.empty(3)
    a[0], a[1], a[2] = _unit_normal(rest[0], rest[1], rest[2])
    return turned(a, rest, now)


# a point outside a place on a sharp edge or vertex by more than this fraction of the triangle's
# edge is met along the line to it (kernels.places); nearer, along the faces' normals there
CLEAR = 1e-3
# faces meeting at an edge or vertex whose normals' cosine is below this make it sharp
SHARP_COS = np.cos(np.radians(30.0))


@nb.njit(cache=True)
def _candidates(k, Y, close, around, triangles, P, faces, dist):
    """The triangles around point ``k``'s nearest surface nodes (into ``faces``, with the squared
    distance of ``Y[k]`` to each into ``dist``): ``(count, best, v, w)``, the closest first found
    and the barycentric weights of the closest point in it."""
    count, best, best_v, best_w = 0, -1, 0.0, 0.0
    for j in range(close.shape[1]):
        for slot in range(around.shape[1]):
            f = around[close[k, j], slot]
            if f < 0:
                continue
            a, b, c = P[triangles[f, 0]], P[triangles[f, 1]], P[triangles[f, 2]]
            v, w = closest_weights(Y[k, 0], Y[k, 1], Y[k, 2], a, b, c)
            o0 = Y[k, 0] - a[0] - v * (b[0] - a[0]) - w * (c[0] - a[0])
            o1 = Y[k, 1] - a[1] - v * (b[1] - a[1]) - w * (c[1] - a[1])
            o2 = Y[k, 2] - a[2] - v * (b[2] - a[2]) - w * (c[2] - a[2])
            faces[count] = f
            dist[count] = o0 * o0 + o1 * o1 + o2 * o2
            if best < 0 or dist[count] < dist[best]:
                best, best_v, best_w = count, v, w
            count += 1
    return count, best, best_v, best_w


@nb.njit(cache=True)
def _tied_normal(n, line, faces, dist, count, best, size, triangles, P, moved, seen_n, rest, now):
    """The normal at a place held as closely (to 1e-12 of ``size``, the triangle's squared edge)
    by several of the ``faces`` (``n``: the closest one's normal, :func:`face_normal`; ``line``
    (3,): from the place to the point now). Such a place lies on an edge or a vertex.

    On a sharp one (faces turned more than 30 degrees apart) the grid's gradient is any blend of
    the faces around, decided by round-off (two soft cubes meeting face on with coinciding edges
    parted spinning at 5 rad/s): a point clearly outside is met along ``line`` (the closest-point
    direction, the normal of the face it lies in front of); one on the edge or in the body (a node
    on the edge line pressing into the body lies nearer the side face than the face it presses
    on) along the sum of the distinct faces' own normals there, each once however many triangles
    of one face hold it. Elsewhere (an edge between triangles of one face, bent or not) the normals
    of the triangles holding it, averaged: the rest place under a bent face is not the closest
    place now, and ``line`` would not follow the bend."""
    distinct, tied = 0, False
    for t in range(count):
        g = faces[t]
        if not dist[t] <= dist[best] + 1e-12 * size:
            continue
        for i in range(3):
            for a in range(3):
                rest[i, a] = P[triangles[g, i], a]
                now[i, a] = rest[i, a] + moved[triangles[g, i], a]
        m0, m1, m2 = _unit_normal(now[0], now[1], now[2])     # outward (surface triangles are)
        seen = False
        for u in range(distinct):
            seen = seen or seen_n[u, 0] * m0 + seen_n[u, 1] * m1 + seen_n[u, 2] * m2 > 1.0 - 1e-9
        if not seen:
            seen_n[distinct, 0], seen_n[distinct, 1], seen_n[distinct, 2] = m0, m1, m2
            distinct += 1
        seen = g == faces[best]
        for u in range(t):
            seen = seen or faces[u] == g
        if not seen:
            tied = True
            n += face_normal(rest, now)
    sharp = False
    for u in range(1, distinct):
        sharp = sharp or seen_n[u, 0] * seen_n[0, 0] + seen_n[u, 1] * seen_n[0, 1] + seen_n[u, 2] * seen_n[0, 2] < SHARP_COS
    if sharp:
        faces_n = np.zeros(3)
        for u in range(distinct):
            faces_n += seen_n[u]
        faces_n /= np.sqrt(faces_n[0] * faces_n[0] + faces_n[1] * faces_n[1] + faces_n[2] * faces_n[2])
        if line[0] * faces_n[0] + line[1] * faces_n[1] + line[2] * faces_n[2] > CLEAR * np.sqrt(size):
            return line / np.sqrt(line[0] * line[0] + line[1] * line[1] + line[2] * line[2])
        return faces_n
    if tied:
        n /= np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    return n


@nb.njit(cache=True)
def places(Y, close, around, triangles, P, moved, X_now, radius):
    """Where rest surface points ``Y`` (p, 3) of a deformable body lie on its surface now.

    ``close`` (p, kc): each point's nearest surface nodes (indices into the surface nodes, whose
    rest positions are ``P`` (s, 3) and moves ``moved`` (s, 3)); the point's triangle is the
    closest among the ``triangles`` (f, 3) ``around`` (s, d) them (the first found among equally
    close ones), and its normal that triangle's (:func:`face_normal`; a point on an edge or
    vertex: :func:`_tied_normal`), not the signed-distance grid's gradient, which across a body
    a cell or two thick is any blend of its faces (a frictionless box sliding on a plank as
    thick as a cell met its top face on sideways normals at every node line, and stopped).
    ``X_now`` (p, 3): the points moved as the surface moved, ``radius`` (p,) m. Returns
    ``(corners (p, 3), weights (p, 3), normal (p, 3), gap (p,))``: the triangle, the barycentric
    weights, the normal and the gap along it to the place as it is now."""
    p = len(Y)
    corners = np.zeros((p, 3), dtype=np.int64)
    weights = np.zeros((p, 3))
    normal = np.zeros((p, 3))
    gap = np.zeros(p)
    faces = np.empty(close.shape[1] * around.shape[1], dtype=np.int64)
    dist = np.empty(len(faces))
    seen_n = np.empty((len(faces), 3))
    rest = np.empty((3, 3))
    now = np.empty((3, 3))
    for k in range(p):
        count, best, v, w = _candidates(k, Y, close, around, triangles, P, faces, dist)
        f = faces[best]
        place = np.zeros(3)
        weights[k, 0], weights[k, 1], weights[k, 2] = 1.0 - v - w, v, w
        for i in range(3):
            corners[k, i] = triangles[f, i]
            for a in range(3):
                rest[i, a] = P[triangles[f, i], a]
                now[i, a] = rest[i, a] + moved[triangles[f, i], a]
                place[a] += weights[k, i] * now[i, a]
        n = face_normal(rest, now)
        e0, e1, e2 = rest[1, 0] - rest[0, 0], rest[1, 1] - rest[0, 1], rest[1, 2] - rest[0, 2]
        line = X_now[k] - place
        n = _tied_normal(n, line, faces, dist, count, best, e0 * e0 + e1 * e1 + e2 * e2,
                         triangles, P, moved, seen_n, rest, now)
        normal[k] = n
        gap[k] = line[0] * n[0] + line[1] * n[1] + line[2] * n[2] - radius[k]
    return corners, weights, normal, gap


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
def off_nodes_kept(x, surface_nodes, close, points, n_rest, R, distance):
    """Which ``points`` (q, 3) world lie farther than ``distance`` (m) across their normal
    (``n_rest`` (q, 3) turned by ``R``) from the current position ``x`` of their nearest surface
    node ``surface_nodes[close]`` (q,): ``(q,)`` bool (hybrid.coupling.fem_contact._against)."""
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
        keep[k] = a0 * a0 + a1 * a1 + a2 * a2 > distance * distance
    return keep
