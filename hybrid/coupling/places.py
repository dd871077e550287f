"""Where points lie on a deformable body's surface (numba kernels, cached on disk): the closest
place in a surface triangle, the normal there (the triangle's own, turned with it; at an edge or
vertex, :func:`_tied_normal`), and the gap along it (hybrid.coupling.fem_contact._against).
tests/test_step_kernels.py compares them with numpy code on random inputs.
"""
import numba as nb
import numpy as np


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
def unit_normal(t0, t1, t2):
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
    a0, a1, a2 = unit_normal(rest[0], rest[1], rest[2])
    b0, b1, b2 = unit_normal(now[0], now[1], now[2])
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
    a[0], a[1], a[2] = unit_normal(rest[0], rest[1], rest[2])
    return turned(a, rest, now)


# a triangle whose normal is turned more than 120 degrees from the grid's is the far side of a
# thin piece (places)
OPPOSED_COS = -0.5

# a node meets the face at a sharp edge whose normal is within 70 degrees of opposite its own
FACING_COS = np.cos(np.radians(70.0))

# a point outside a place on a sharp edge or vertex by more than this fraction of the triangle's
# edge is met along the line to it (:func:`places`); nearer, along the faces' normals there
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


# how much farther (a fraction of its edge) a triangle that faces a node may lie than the
# closest, which does not, for the node to meet it instead (:func:`places`)
FACING_SLACK = 0.01


@nb.njit(cache=True)
def _facing(f, triangles, P, moved, facing):
    """How squarely triangle ``f`` as it is now faces a node of outward normal ``facing``: the
    cosine between the triangle's normal and the opposite of the node's."""
    now = np.empty((3, 3))
    for i in range(3):
        for a in range(3):
            now[i, a] = P[triangles[f, i], a] + moved[triangles[f, i], a]
    m0, m1, m2 = unit_normal(now[0], now[1], now[2])
    return -(m0 * facing[0] + m1 * facing[1] + m2 * facing[2])


@nb.njit(cache=True)
def _facing_candidate(k, Y, facing, faces, dist, count, best, v, w, triangles, P, moved):
    """``(best, v, w)``: the candidate triangle point ``k`` (of :func:`places`) meets, and the
    barycentric weights of its closest point. A node with its own outward normal ``facing``
    (3,; zero: none) whose closest triangle turns away from it (its normal more than 70 degrees
    from opposite the node's) meets instead the nearest one that faces it, if that lies at most
    FACING_SLACK of an edge farther: beside another body's edge, where the closest face is the
    side face by a hair, as a node meets a rigid edge on the face its tie is broken towards
    (hybrid.coupling.detect._facing_faces). A soft slab's node just inside a soft block's
    bottom front edge, 0.6 um from its front face and 4 um from its bottom, met the front face
    as a wall, and the block sliding on the slab without friction lost a third of its speed."""
    if abs(facing[0] * facing[0] + facing[1] * facing[1] + facing[2] * facing[2] - 1.0) >= 1e-6:
        return best, v, w
    f = faces[best]
    if _facing(f, triangles, P, moved, facing) > FACING_COS:
        return best, v, w
    a, b = P[triangles[f, 0]], P[triangles[f, 1]]
    slack = FACING_SLACK * np.sqrt((b[0] - a[0]) ** 2 + (b[1] - a[1]) ** 2 + (b[2] - a[2]) ** 2)
    reach = (np.sqrt(dist[best]) + slack) ** 2
    chosen = -1
    for t in range(count):
        if dist[t] > reach or (chosen >= 0 and dist[t] >= dist[chosen]):
            continue
        if _facing(faces[t], triangles, P, moved, facing) > FACING_COS:
            chosen = t
    if chosen < 0:
        return best, v, w
    g = faces[chosen]
    v, w = closest_weights(Y[k, 0], Y[k, 1], Y[k, 2], P[triangles[g, 0]], P[triangles[g, 1]],
                           P[triangles[g, 2]])
    return chosen, v, w


@nb.njit(cache=True)
def _tied_normal(n, line, facing, faces, dist, count, best, size, triangles, P, moved, seen_n,
                 rest, now):
    """The normal at a place held as closely (to 1e-12 of ``size``, the triangle's squared edge)
    by several of the ``faces`` (``n``: the closest one's normal, :func:`face_normal`; ``line``
    (3,): from the place to the point now; ``facing`` (3,): the point's own outward unit normal,
    a node's on its own body's surface, or zero). Such a place lies on an edge or a vertex.

    On a sharp one (faces turned more than 30 degrees apart) the grid's gradient is any blend of
    the faces around, decided by round-off (two soft cubes meeting face on with coinciding edges
    parted spinning at 5 rad/s): a point clearly outside is met along ``line`` (the closest-point
    direction, the normal of the face it lies in front of); one on the edge or in the body (a node
    on the edge line pressing into the body lies nearer the side face than the face it presses
    on) along the sum of the distinct faces' own normals there, each once however many triangles
    of one face hold it; but a node with its own normal there meets the face that faces it
    (whose normal is most nearly opposite its own, if within 70 degrees of it), as a node meets
    a rigid edge on the face its tie is broken towards
    (hybrid.coupling.detect._facing_faces): a soft slab's nodes under the bottom edges of a soft
    block sliding on it met the sum of its bottom and side faces' normals, and were pushed
    sideways and the block back. Elsewhere (an edge between triangles of one face, bent or not)
    the normals of the triangles holding it, averaged: the rest place under a bent face is not
    the closest place now, and ``line`` would not follow the bend."""
    distinct, tied = 0, False
    for t in range(count):
        g = faces[t]
        if not dist[t] <= dist[best] + 1e-12 * size:
            continue
        for i in range(3):
            for a in range(3):
                rest[i, a] = P[triangles[g, i], a]
                now[i, a] = rest[i, a] + moved[triangles[g, i], a]
        m0, m1, m2 = unit_normal(now[0], now[1], now[2])     # outward (surface triangles are)
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
        if abs(facing[0] * facing[0] + facing[1] * facing[1] + facing[2] * facing[2] - 1.0) < 1e-6:
            toward, most = -1, FACING_COS
            for u in range(distinct):
                against = -(seen_n[u, 0] * facing[0] + seen_n[u, 1] * facing[1] + seen_n[u, 2] * facing[2])
                if against > most:
                    toward, most = u, against
            if toward >= 0:
                return seen_n[toward].copy()
        return faces_n
    if tied:
        n /= np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    return n


@nb.njit(cache=True)
def _now_corners(f, triangles, P, moved, now):
    """Triangle ``f``'s corners as they are now into ``now`` (3, 3)."""
    for i in range(3):
        for a in range(3):
            now[i, a] = P[triangles[f, i], a] + moved[triangles[f, i], a]


@nb.njit(cache=True)
def _pseudo_normal(f, weights, triangles, around, P, moved, now):
    """The angle-weighted pseudo-normal (Baerentzen and Aanaes, 2005) at the place of barycentric
    ``weights`` (3,) in triangle ``f`` as it is now: the triangle's normal inside it; on an edge
    (a weight within 1e-12 of zero), the sum of the normals of the triangles around its first
    end that hold its other end too; at a vertex, of all the triangles around it, each weighted
    by its angle there. A point whose closest place on the closed surface this is lies outside
    it exactly when it lies in front of it along this normal; on a sharp edge or vertex, in
    front of one face's plane or behind another's tells nothing (a tet's corner: 5 mm off it
    along one face's normal, a point lies 1.7 mm behind the plane of each other face)."""
    held = np.zeros(3, dtype=np.int64)
    count = 0
    for i in range(3):
        if weights[i] > 1e-12:
            held[count] = triangles[f, i]
            count += 1
    out = np.zeros(3)
    if count == 3:
        _now_corners(f, triangles, P, moved, now)
        out[0], out[1], out[2] = unit_normal(now[0], now[1], now[2])
        return out
    s = held[0]
    for slot in range(around.shape[1]):
        g = around[s, slot]
        if g < 0:
            continue
        at = -1
        other = count == 1
        for i in range(3):
            if triangles[g, i] == s:
                at = i
            other = other or triangles[g, i] == held[1]
        if not other:
            continue
        _now_corners(g, triangles, P, moved, now)
        m0, m1, m2 = unit_normal(now[0], now[1], now[2])
        angle = 1.0
        if count == 1:
            u, w = now[(at + 1) % 3] - now[at], now[(at + 2) % 3] - now[at]
            cos = (u[0] * w[0] + u[1] * w[1] + u[2] * w[2]) / max(
                np.sqrt((u[0] * u[0] + u[1] * u[1] + u[2] * u[2]) * (w[0] * w[0] + w[1] * w[1] + w[2] * w[2])),
                1e-300)
            angle = np.arccos(min(max(cos, -1.0), 1.0))
        out[0] += angle * m0
        out[1] += angle * m1
        out[2] += angle * m2
    out /= max(np.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2]), 1e-300)
    return out


@nb.njit(cache=True)
def _outside(x, faces, dist, count, size, triangles, around, P, moved, now):
    """``(f, weights (3,), line (3,), height)``: the closest place to ``x`` (3,) in the candidate
    ``faces`` as they are now (the first found among those as close to 1e-12 of ``size``, a
    squared edge: at an edge or a vertex round-off would choose), the line from it to ``x`` and
    how far ``x`` lies in front of the surface there, along its pseudo-normal
    (:func:`_pseudo_normal`): negative behind it, in the body. ``dist`` (count,): scratch."""
    least = np.inf
    for t in range(count):
        _now_corners(faces[t], triangles, P, moved, now)
        v, w = closest_weights(x[0], x[1], x[2], now[0], now[1], now[2])
        dist[t] = 0.0
        for a in range(3):
            o = x[a] - now[0, a] - v * (now[1, a] - now[0, a]) - w * (now[2, a] - now[0, a])
            dist[t] += o * o
        least = min(least, dist[t])
    best = 0
    while dist[best] > least + 1e-12 * size:
        best += 1
    best = faces[best]
    _now_corners(best, triangles, P, moved, now)
    v, w = closest_weights(x[0], x[1], x[2], now[0], now[1], now[2])
    weights = np.array([1.0 - v - w, v, w])
    line = x - (weights[0] * now[0] + weights[1] * now[1] + weights[2] * now[2])
    n = _pseudo_normal(best, weights, triangles, around, P, moved, now)
    return best, weights, line, line[0] * n[0] + line[1] * n[1] + line[2] * n[2]


@nb.njit(cache=True)
def places(Y, close, around, triangles, P, moved, n_rest, X_now, radius, facing):
    """Where rest surface points ``Y`` (p, 3) of a deformable body lie on its surface now.

    ``close`` (p, kc): each point's nearest surface nodes (indices into the surface nodes, whose
    rest positions are ``P`` (s, 3) and moves ``moved`` (s, 3)); the point's triangle is the
    closest among the ``triangles`` (f, 3) ``around`` (s, d) them (the first found among equally
    close ones), and its normal that triangle's (:func:`face_normal`; a point on an edge or
    vertex: :func:`_tied_normal`), not the signed-distance grid's gradient, which across a body
    a cell or two thick is any blend of its faces (a frictionless box sliding on a plank as
    thick as a cell met its top face on sideways normals at every node line, and stopped);
    but a point pressed in behind that triangle (by more than CLEAR of its edge) whose grid
    rest normal ``n_rest`` (p, 3, turned with it) is opposed to it by more than 120 degrees is
    nearer the far side of a thin piece, and the grid's normal stands (met along the near face,
    points pressed into a shattered pane's slivers went through them and the pieces gained a
    third of their energy).
    ``X_now`` (p, 3): the points moved as the surface moved, ``radius`` (p,) m, ``facing``
    (p, 3) the points' own outward unit normals in the body's rest frame (nodes of other
    deformable bodies; zero rows for points without one, see :func:`_tied_normal`).
    A point read as behind its place but lying clearly in front of the surface where it is
    closest to it now (by more than CLEAR of the edge, :func:`_outside`) is met there, at its
    true distance along the line to it: ``Y`` is the grid's closest place, off an edge or a
    vertex by a percent of an edge, and a point a piece's width off that vertex met one face
    there (tied, or the one facing it), behind whose plane it lay: a shattered pane's nodes 5 mm
    off one-tet pieces' vertices were read 1 to 3.6 mm inside, the recovery strained the pieces
    apart, and the pane blew up (benchmarks/pane_rebound.py, 5 mm elements). Returns
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
        best, v, w = _facing_candidate(k, Y, facing[k], faces, dist, count, best, v, w, triangles, P,
                                       moved)
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
        depth = -(line[0] * n[0] + line[1] * n[1] + line[2] * n[2])      # behind the face
        if depth > CLEAR * np.sqrt(e0 * e0 + e1 * e1 + e2 * e2):
            grid_n = turned(n_rest[k], rest, now)
            if n[0] * grid_n[0] + n[1] * grid_n[1] + n[2] * grid_n[2] < OPPOSED_COS:
                n = grid_n
        n = _tied_normal(n, line, facing[k], faces, dist, count, best, e0 * e0 + e1 * e1 + e2 * e2,
                         triangles, P, moved, seen_n, rest, now)
        normal[k] = n
        gap[k] = line[0] * n[0] + line[1] * n[1] + line[2] * n[2]
        if gap[k] < radius[k]:
            size = e0 * e0 + e1 * e1 + e2 * e2
            g, w3, line, height = _outside(X_now[k], faces, dist, count, size, triangles, around, P,
                                           moved, now)
            length = np.sqrt(line[0] * line[0] + line[1] * line[1] + line[2] * line[2])
            # a ball's centre in front of the surface but within its radius of the face's plane
            # is met there only where that reads it farther off (off the face's edge; over the
            # face both read alike, but for round-off): a ball
            # beside a one-tet piece read 4 mm inside it along a face whose plane it was near,
            # and the piece was shoved 8 mm sideways and into the ground
            farther = length > gap[k] + 1e-9 * np.sqrt(size)
            if height > CLEAR * np.sqrt(size) and (radius[k] == 0.0 or farther):
                corners[k] = triangles[g]
                weights[k] = w3
                normal[k] = line / length
                gap[k] = length
        gap[k] -= radius[k]
    return corners, weights, normal, gap
