"""The coupled step's compiled kernels against the numpy code they replaced, on random inputs.

Each reference below is the numpy implementation the step used before the kernel (kept here only
as the oracle); the kernels must give the same answers to round-off, and the same discrete
choices (nearest node, closest triangle, its ties).
"""
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from hybrid.coupling import fem_contact, kernels, places, rest_grid
from rigid import shapes
from rigid.sdf import SignedDistanceGrid, closest_point_weights

RNG_SEEDS = range(5)


def random_rotation(rng):
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


# --- numpy references (the step's code before the kernels) -------------------------------------

def reach_reference(x):
    centre = x.mean(axis=0)
    return centre, float(np.sqrt(((x - centre) ** 2).sum(axis=1).max()))


def node_normals_reference(x, surface_nodes, tri, around, local):
    faces = around[local]
    corners = x[surface_nodes[tri[np.maximum(faces, 0)]]]
    n = np.cross(corners[:, :, 1] - corners[:, :, 0], corners[:, :, 2] - corners[:, :, 0])
    n = (n * (faces >= 0)[:, :, None]).sum(axis=1)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def unit_normals_reference(tri):
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def turn_reference(v, a, b):
    axis = np.cross(a, b)
    cos = np.einsum("ij,ij->i", a, b)
    ok = cos > 0.0
    k = 1.0 / (1.0 + np.where(ok, cos, 1.0))
    turned = (v * cos[:, None] + np.cross(axis, v)
              + axis * (k * np.einsum("ij,ij->i", axis, v))[:, None])
    return np.where(ok[:, None], turned, v)


def rest_triangles_reference(P, tri, around, Y, close, moved=None, facing=None):
    candidates = around[close].reshape(len(Y), -1)
    row, slot = np.nonzero(candidates >= 0)
    face = candidates[row, slot]
    a, b, c = P[tri[face, 0]], P[tri[face, 1]], P[tri[face, 2]]
    v, w = closest_point_weights(Y[row], a, b, c)
    off = Y[row] - a - v[:, None] * (b - a) - w[:, None] * (c - a)
    distance = np.einsum("ij,ij->i", off, off)
    order = np.lexsort((distance, row))
    best = order[np.searchsorted(row[order], np.arange(len(Y)))]
    if facing is not None:
        # a node whose closest triangle turns away from it meets the nearest one facing it
        # within a hundredth of an edge farther
        now_n = unit_normals_reference(P[tri[face]] + moved[tri[face]])
        against = -np.einsum("ij,ij->i", now_n, facing[row])
        node = np.abs(np.einsum("ij,ij->i", facing, facing) - 1.0) < 1e-6
        for k in np.nonzero(node & (against[best] <= places.FACING_COS))[0]:
            reach = (np.sqrt(distance[best[k]])
                     + places.FACING_SLACK * np.linalg.norm(b[best[k]] - a[best[k]])) ** 2
            ok = np.nonzero((row == k) & (distance <= reach) & (against > places.FACING_COS))[0]
            if len(ok):
                best[k] = ok[np.argmin(distance[ok])]
    weights = np.column_stack([1.0 - v[best] - w[best], v[best], w[best]])
    edge = b[best] - a[best]
    size = np.einsum("ij,ij->i", edge, edge)
    tied = (distance <= (distance[best] + 1e-12 * size)[row]) & (face != face[best][row])
    if tied.any():
        pairs = np.column_stack([row[tied], face[tied]])
        repeat = np.ones(len(pairs), dtype=bool)
        repeat[np.unique(pairs, axis=0, return_index=True)[1]] = False
        tied[np.nonzero(tied)[0][repeat]] = False
    return tri[face[best]], weights, (row[tied], tri[face[tied]])


def pseudo_normal_reference(P, tri, around, moved, f, weights):
    """The angle-weighted pseudo-normal at the place of ``weights`` in triangle ``f`` now: the
    triangle's normal inside it; on an edge, the sum of the normals of the two triangles holding
    it; at a vertex, of the triangles around it, each times its angle there."""
    held = tri[f][weights > 1e-12]
    if len(held) == 3:
        return unit_normals_reference((P[tri[f]] + moved[tri[f]])[None])[0]
    around_s = around[held[0]][around[held[0]] >= 0]
    g = around_s[(tri[around_s] == held[-1]).any(axis=1)]
    now = P[tri[g]] + moved[tri[g]]
    normals = unit_normals_reference(now)
    if len(held) == 2:
        total = normals.sum(axis=0)
    else:
        at = np.argmax(tri[g] == held[0], axis=1)
        rows = np.arange(len(g))
        u, w = now[rows, (at + 1) % 3] - now[rows, at], now[rows, (at + 2) % 3] - now[rows, at]
        cos = np.einsum("ij,ij->i", u, w) / np.linalg.norm(u, axis=1) / np.linalg.norm(w, axis=1)
        total = (np.arccos(np.clip(cos, -1.0, 1.0))[:, None] * normals).sum(axis=0)
    return total / np.linalg.norm(total)


def outside_reference(P, tri, around, moved, x, candidates, size):
    """The closest place to ``x`` in the ``candidates`` triangles now (the first of those as close
    to 1e-12 of ``size``), the line from it to ``x`` and the height of ``x`` along the
    pseudo-normal there."""
    now = P[tri[candidates]] + moved[tri[candidates]]
    a, b, c = now[:, 0], now[:, 1], now[:, 2]
    v, w = closest_point_weights(np.broadcast_to(x, a.shape), a, b, c)
    off = x - a - v[:, None] * (b - a) - w[:, None] * (c - a)
    distance = np.einsum("ij,ij->i", off, off)
    best = int(np.argmax(distance <= distance.min() + 1e-12 * size))
    weights = np.array([1.0 - v[best] - w[best], v[best], w[best]])
    line = x - weights @ now[best]
    n = pseudo_normal_reference(P, tri, around, moved, candidates[best], weights)
    return candidates[best], weights, line, line @ n


def places_reference(P, tri, around, moved, Y, close, grid_n, X_now, radius, facing):
    corners, weights, (tie_row, tie_corners) = rest_triangles_reference(P, tri, around, Y, close,
                                                                        moved, facing)
    rest = P[corners]
    now = rest + moved[corners]
    n_rest = unit_normals_reference(rest)
    n = turn_reference(n_rest, n_rest, unit_normals_reference(now))
    # pressed in behind the face, with the grid's normal opposed to it: the grid's stands
    behind = -np.einsum("ij,ij->i", X_now - np.einsum("pi,pij->pj", weights, now), n) \
        > places.CLEAR * np.linalg.norm(rest[:, 1] - rest[:, 0], axis=1)
    grid = turn_reference(grid_n, n_rest, unit_normals_reference(now))
    use = behind & (np.einsum("ij,ij->i", n, grid) < places.OPPOSED_COS)
    n[use] = grid[use]
    if len(tie_row):
        tie_rest = P[tie_corners]
        tie_now = tie_rest + moved[tie_corners]
        tie_n = unit_normals_reference(tie_rest)
        np.add.at(n, tie_row, turn_reference(tie_n, tie_n, unit_normals_reference(tie_now)))
        n[np.unique(tie_row)] /= np.linalg.norm(n[np.unique(tie_row)], axis=1, keepdims=True)
    place = np.einsum("pi,pij->pj", weights, now)
    line = X_now - place
    # a sharp edge or vertex (faces more than 30 degrees apart): outside by more than CLEAR of the
    # triangle's edge along the line to the point, else along the faces' normals summed
    edge = np.linalg.norm(rest[:, 1] - rest[:, 0], axis=1)
    for k in np.unique(tie_row):
        faces = unit_normals_reference(np.concatenate([now[k:k + 1], tie_now[tie_row == k]]))
        distinct = [faces[0]]
        for f in faces[1:]:
            if all(f @ g <= 1.0 - 1e-9 for g in distinct):
                distinct.append(f)
        if min(f @ distinct[0] for f in distinct) >= places.SHARP_COS:
            continue
        total = np.sum(distinct, axis=0)
        total /= np.linalg.norm(total)
        clear = line[k] @ total > places.CLEAR * edge[k]
        against = [-(f @ facing[k]) for f in distinct]
        if not clear and abs(facing[k] @ facing[k] - 1.0) < 1e-6 and max(against) > places.FACING_COS:
            n[k] = distinct[int(np.argmax(against))]       # the face facing the node
            continue
        n[k] = line[k] / np.linalg.norm(line[k]) if clear else total
    # read behind its place (a ball: its surface) but clearly in front of the surface where it is
    # closest to it now (along the pseudo-normal there): met there, at its distance along the line
    # (a ball only where that is farther than along the face)
    reading = np.einsum("ij,ij->i", line, n)
    met = []
    for k in np.nonzero(reading < radius)[0]:
        candidates = around[close[k]].ravel()
        f, w, to, height = outside_reference(P, tri, around, moved, X_now[k], candidates[candidates >= 0],
                                             edge[k] ** 2)
        farther = np.linalg.norm(to) > reading[k] + 1e-9 * edge[k]
        if height > places.CLEAR * edge[k] and (radius[k] == 0.0 or farther):
            corners[k], weights[k] = tri[f], w
            n[k], reading[k] = to / np.linalg.norm(to), np.linalg.norm(to)
            met.append(k)
    return corners, weights, n, reading - radius, len(tie_row), np.array(met, dtype=np.int64)


# --- the kernels against them ------------------------------------------------------------------

@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_surface_motion_matches_the_numpy_bounding_sphere_and_moves(seed):
    rng = np.random.default_rng(seed)
    rest_points = rng.standard_normal((300, 3))
    surface_nodes = np.sort(rng.choice(300, 120, replace=False))
    R, c = random_rotation(rng), rng.standard_normal(3)
    rest_center = rest_points.mean(axis=0)
    x = (rest_points - rest_center) @ R.T + c + 0.01 * rng.standard_normal((300, 3))
    centre, radius, moved, largest = kernels.surface_motion(x, surface_nodes, c, R, rest_center, rest_points)
    want_centre, want_radius = reach_reference(x[surface_nodes])
    want_moved = (x[surface_nodes] - c) @ R + rest_center - rest_points[surface_nodes]
    np.testing.assert_allclose(centre, want_centre, rtol=1e-14, atol=1e-14)
    assert radius == pytest.approx(want_radius, rel=1e-13)
    np.testing.assert_allclose(moved, want_moved, rtol=1e-12, atol=1e-14)
    assert largest == pytest.approx(np.sqrt((want_moved ** 2).sum(axis=1).max()), rel=1e-12)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_nearest_rows_finds_what_a_kd_tree_finds(seed):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1, 1, (500, 3))
    queries = rng.uniform(-1.2, 1.2, (40, 3))
    np.testing.assert_array_equal(kernels.nearest_rows(points, queries), cKDTree(points).query(queries)[1])


@pytest.mark.parametrize("seed", RNG_SEEDS)
@pytest.mark.parametrize("count", [1, 2, 3, 500])
def test_three_nearest_rows_are_a_kd_trees_three_in_its_order(seed, count):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1, 1, (count, 3))
    queries = rng.uniform(-1.2, 1.2, (40, 3))
    want = np.asarray(cKDTree(points).query(queries, k=min(3, count))[1]).reshape(len(queries), -1)
    np.testing.assert_array_equal(kernels.nearest_three_rows(points, queries), want)
    # equally near rows: the lower index first
    twin = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 2.0, 0], [0, -1.0, 0]])
    assert kernels.nearest_three_rows(twin, np.zeros((1, 3))).tolist() == [[0, 1, 3]]


def box_index(rng, cells=4):
    """A box surface meshed with ``cells`` per side, randomly scaled, as the rest surface of a
    body whose surface nodes are every vertex: (model-like object, tri, around)."""
    vertices, triangles = shapes.box_surface(rng.uniform(0.5, 2.0, 3), resolution=1.0 / cells)
    m = SimpleNamespace(rest_points=vertices, surface_nodes=np.arange(len(vertices)), surface=triangles,
                        cache=SimpleNamespace(surface_index=None))
    _, tri, around = fem_contact._surface_index(m)
    return m, tri, around


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_node_normals_match_the_numpy_area_weighted_normals(seed):
    rng = np.random.default_rng(seed)
    m, tri, around = box_index(rng)
    x = m.rest_points @ random_rotation(rng).T + 0.02 * rng.standard_normal(m.rest_points.shape)
    local = rng.choice(len(m.surface_nodes), 50)
    np.testing.assert_allclose(kernels.node_normals(x, m.surface_nodes, tri, around, local),
                               node_normals_reference(x, m.surface_nodes, tri, around, local),
                               rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_grid_query_matches_the_grid_s_own_query(seed):
    rng = np.random.default_rng(seed)
    vertices, triangles = shapes.box_surface(rng.uniform(0.5, 2.0, 3))
    grid = SignedDistanceGrid.build(vertices, triangles)
    # inside, near the faces, and outside the grid
    X = rng.uniform(-1.0, 1.0, (300, 3)) * (np.abs(vertices).max(axis=0) + 2 * grid.padding)
    phi, normal = rest_grid.grid_query(grid.origin, grid.cell_size, grid.shape, grid.values, X)
    want_phi, want_normal = grid.query(X)
    assert (want_normal == 0).all(axis=1).any() and not (want_normal == 0).all()   # both kinds met
    np.testing.assert_allclose(phi, want_phi, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(normal, want_normal, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_closest_weights_match_the_numpy_regions(seed):
    rng = np.random.default_rng(seed)
    a, b, c = rng.standard_normal((3, 400, 3))
    c[:40] = a[:40] + 2.0 * (b[:40] - a[:40])     # degenerate: collinear corners
    b[40:60] = a[40:60]                            # and coincident ones
    p = rng.standard_normal((400, 3)) * 2.0
    want_v, want_w = closest_point_weights(p, a, b, c)
    got = np.array([places.closest_weights(p[k, 0], p[k, 1], p[k, 2], a[k], b[k], c[k])
                    for k in range(400)])
    np.testing.assert_allclose(got[60:, 0], want_v[60:], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got[60:, 1], want_w[60:], rtol=1e-12, atol=1e-12)
    # a degenerate triangle's point has several weights (round-off picks the edge): the same point
    point = a + got[:, :1] * (b - a) + got[:, 1:] * (c - a)
    want = a + want_v[:, None] * (b - a) + want_w[:, None] * (c - a)
    np.testing.assert_allclose(point, want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_places_match_the_numpy_triangles_turned_normals_and_gaps(seed):
    rng = np.random.default_rng(seed)
    m, tri, around = box_index(rng)
    P = m.rest_points
    moved = 0.01 * rng.standard_normal(P.shape)
    # points on the rest surface: random places in random triangles, a third of them on edges
    # and vertices, where several triangles hold them as closely (ties)
    face = rng.choice(len(tri), 60)
    w = rng.dirichlet(np.ones(3), 60)
    w[:10] = [1.0, 0.0, 0.0]
    w[10:20, 0] = 0.0
    w[10:20] /= w[10:20].sum(axis=1, keepdims=True)
    Y = np.einsum("pi,pij->pj", w, P[tri[face]])
    close = cKDTree(P).query(Y, k=3)[1]
    X_now = Y + 0.003 * rng.standard_normal(Y.shape)
    radius = rng.uniform(0.0, 0.01, 60)
    # half the points are nodes with normals of their own (random), the others have none
    facing = rng.standard_normal(Y.shape)
    facing /= np.linalg.norm(facing, axis=1, keepdims=True)
    facing[::2] = 0.0
    # the grid's normals: the triangle's own, for a third of the points reversed (a thin piece's
    # far side), for a third random
    grid_n = unit_normals_reference(P[tri[face]])
    grid_n[::3] *= -1.0
    grid_n[1::3] = rng.standard_normal((len(grid_n[1::3]), 3))
    grid_n /= np.linalg.norm(grid_n, axis=1, keepdims=True)
    corners, weights, normal, gap = places.places(Y, close, around, tri, P, moved, grid_n, X_now,
                                                   radius, facing)
    want = places_reference(P, tri, around, moved, Y, close, grid_n, X_now, radius, facing)
    assert want[4] > 0 and len(want[5]) > 0      # ties were met, and points clearly outside read in
    np.testing.assert_array_equal(corners, want[0])
    np.testing.assert_allclose(weights, want[1], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(normal, want[2], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(gap, want[3], rtol=1e-12, atol=1e-13)


def tet_index(corners):
    """The surfaces of tetrahedra ``corners`` (t, 4, 3) (one-tet pieces of a shattered body), as a
    body's rest surface whose surface nodes are every corner: (P, tri, around)."""
    P = corners.reshape(-1, 3)
    tri = []
    for t in range(len(corners)):
        for face in ((0, 1, 2), (0, 3, 1), (0, 2, 3), (1, 3, 2)):
            f = [4 * t + i for i in face]
            n = np.cross(P[f[1]] - P[f[0]], P[f[2]] - P[f[0]])
            tri.append(f if n @ (P[f].mean(axis=0) - corners[t].mean(axis=0)) > 0 else f[::-1])
    m = SimpleNamespace(rest_points=P, surface_nodes=np.arange(len(P)), surface=np.array(tri),
                        cache=SimpleNamespace(surface_index=None))
    _, tri, around = fem_contact._surface_index(m)
    return P, tri, around


def off_corners(rng, P, tri, around, count, reach):
    """``count`` points (rows) a random distance up to ``reach`` off random corners of the
    surface, in random directions within the corners' normal cones (conic blends of the normals
    of the triangles around), so that the corner is each one's closest place: ``(x, corner,
    direction, distance)``."""
    corner = rng.choice(len(P), count)
    direction = np.zeros((count, 3))
    for k, c in enumerate(corner):
        faces = around[c][around[c] >= 0]
        direction[k] = rng.dirichlet(np.ones(len(faces))) @ unit_normals_reference(P[tri[faces]])
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    distance = rng.uniform(0.2, 1.0, count) * reach
    return P[corner] + distance[:, None] * direction, corner, direction, distance


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_places_match_the_numpy_pseudo_normals_off_sharp_edges_and_corners(seed):
    # one-tet pieces (sharp edges and corners), points around their corners and edges, inside
    # and out, the grid's place a percent of an edge off the corner: the kernel's reading of
    # points clearly outside, along the pseudo-normals at edges and vertices, is numpy's
    rng = np.random.default_rng(seed)
    P, tri, around = tet_index(0.005 * rng.uniform(-1.0, 1.0, (6, 4, 3)) + 0.02 * np.arange(6)[:, None, None])
    moved = 1e-5 * rng.standard_normal(P.shape)
    x, corner, direction, _ = off_corners(rng, P, tri, around, 40, 0.004)
    edge_end = tri[around[corner, 0], 1]
    x[:10] = 0.5 * (P[corner[:10]] + P[edge_end[:10]]) + 0.002 * rng.standard_normal((10, 3))
    x[10:15] = P[corner[10:15]] + 0.3 * (P[edge_end[10:15]] - P[corner[10:15]])    # on an edge
    Y = P[corner] + 0.01 * (P[edge_end] - P[corner]) + 5e-5 * rng.standard_normal((40, 3))
    close = cKDTree(P).query(Y, k=3)[1]
    facing = -direction
    facing[::2] = 0.0
    radius = np.zeros(40)
    corners, weights, normal, gap = places.places(Y, close, around, tri, P, moved, direction, x,
                                                   radius, facing)
    want = places_reference(P, tri, around, moved, Y, close, direction, x, radius, facing)
    held = (want[1][want[5]] > 1e-12).sum(axis=1)
    assert {1, 2} <= set(held.tolist())              # met at corners and on edges
    np.testing.assert_array_equal(corners, want[0])
    np.testing.assert_allclose(weights, want[1], rtol=1e-12, atol=1e-12)
    # the line to a point 10 um off an edge 0.1 m out, made a unit normal: round-off times 1e4
    np.testing.assert_allclose(normal, want[2], rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(gap, want[3], rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("facing", [False, True])
def test_a_point_a_piece_s_width_off_a_one_tet_piece_s_corner_is_met_at_its_distance(facing):
    # the shattered pane of benchmarks/pane_rebound.py (5 mm elements): a one-tet piece, nodes of
    # other pieces up to 5 mm off its corners, the grid's closest place 50 um off the corner. Met
    # along the face there facing them (or the first found), behind whose plane they lay, they
    # were read up to 3.6 mm inside, and the pane blew up. Clearly outside, each must be met at
    # its distance to the corner, along the line to it; a point pressed into the piece still
    # reads its depth
    rng = np.random.default_rng(7)
    piece = np.array([[[0.0, 0.0, -5.0], [5.0, 0.0, -5.0], [5.0, 0.0, 0.0], [5.0, 5.0, 0.0]]]) * 1e-3
    P, tri, around = tet_index(piece)
    x, corner, direction, distance = off_corners(rng, P, tri, around, 200, 0.005)
    to_y = rng.standard_normal((200, 3))
    Y = P[corner] + 5e-5 * to_y / np.linalg.norm(to_y, axis=1, keepdims=True)
    own = -direction if facing else np.zeros((200, 3))
    _, _, normal, gap = places.places(Y, cKDTree(P).query(Y, k=3)[1], around, tri, P, np.zeros_like(P),
                                      direction, x, np.zeros(200), own)
    assert (gap > 0.0).all()
    # the node of the pane that blew up: 5.0083 mm off the piece by its corner (5, 5, 0) mm, read
    # 3.54 mm inside
    node = np.array([[5.01499, 4.99567, 5.00828]]) * 1e-3
    _, _, normal, gap = places.places(np.array([[4.95358e-3, 4.99752e-3, 2.6e-6]]), np.array([[3, 2, 1]]),
                                      around, tri, P, np.zeros_like(P), np.array([[0.01218, 0.0, 0.99993]]),
                                      node, np.zeros(1), np.array([[0.0, 0.0, 1.0]]) if facing else np.zeros((1, 3)))
    a, b, c = P[tri[:, 0]], P[tri[:, 1]], P[tri[:, 2]]
    v, w = closest_point_weights(np.repeat(node, 4, axis=0), a, b, c)
    off = node - (a + v[:, None] * (b - a) + w[:, None] * (c - a))
    off = off[np.argmin(np.linalg.norm(off, axis=1))]          # to the piece's closest place
    assert gap[0] == pytest.approx(np.linalg.norm(off), rel=1e-9)
    np.testing.assert_allclose(normal[0], off / np.linalg.norm(off), atol=1e-9)
    # 0.2 mm behind the face (2, 1, 3) (x = 5 mm), under its centre: 0.2 mm deep
    inside = np.array([[5.0e-3 - 2e-4, 5e-3 / 3, -5e-3 / 3]])
    _, _, _, depth = places.places(inside + [[2e-4, 0.0, 0.0]], np.array([[1, 2, 3]]), around, tri, P,
                                   np.zeros_like(P), np.array([[1.0, 0.0, 0.0]]), inside, np.zeros(1),
                                   np.zeros((1, 3)))
    assert depth[0] == pytest.approx(-2e-4, rel=1e-9)


# --- the deformable body's step (fem.step_kernels) ---------------------------------------------

@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_frame_kernels_match_numpy_products(seed):
    from fem import step_kernels
    rng = np.random.default_rng(seed)
    n = 200
    x, v, force, rest = rng.standard_normal((4, n, 3))
    mass, c, R, dt = rng.uniform(0.1, 2.0, n), rng.standard_normal(3), random_rotation(rng), 1e-3
    np.testing.assert_allclose(step_kernels.frame_offsets(x, c, R, rest), (x - c) @ R - rest,
                               rtol=1e-12, atol=1e-14)
    M = np.diag(np.repeat(mass, 3))
    np.testing.assert_allclose(step_kernels.lumped_rhs(mass, v, R, force, dt),
                               M @ (v @ R).ravel() + dt * (force @ R).ravel(), rtol=1e-12, atol=1e-14)
    v_b = rng.standard_normal(3 * n)
    np.testing.assert_allclose(step_kernels.rotate_back(v_b, R), v_b.reshape(-1, 3) @ R.T,
                               rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_fit_moment_gives_the_best_fit_frame_of_shape_matching(seed):
    from fem import step_kernels
    from rigid.shape_matching import best_fit_frame, rotation_of
    rng = np.random.default_rng(seed)
    rest = rng.standard_normal((300, 3))
    w = rng.uniform(0.1, 2.0, 300)
    offsets = rest - w @ rest / w.sum()
    x = offsets @ random_rotation(rng).T + rng.standard_normal(3) + 0.05 * rng.standard_normal((300, 3))
    c, A = step_kernels.fit_moment(w, x, offsets)
    want_R, want_c = best_fit_frame(offsets, x, w)
    np.testing.assert_allclose(c, want_c, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(A, np.einsum("i,ij,ik->jk", w, x - want_c, offsets), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(rotation_of(A), want_R, rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_block_rows_match_the_sparse_rows_of_the_dense_delassus_matrix(seed):
    from fem import contact_response, step_kernels
    rng = np.random.default_rng(seed)
    m, k = 40, 25
    # a symmetric inverse-system block whose entries fall off with the distance between nodes,
    # so that some blocks drop below the tolerance; two nodes anchored (no response)
    points = rng.uniform(0, 1, (m, 3))
    falloff = np.exp(-30 * np.linalg.norm(points[:, None] - points[None], axis=2))
    B = rng.standard_normal((3 * m, 3 * m)) * np.kron(falloff, np.ones((3, 3)))
    W_full = B @ B.T
    W_full[:6] = W_full[:, :6] = 0.0
    slots = rng.choice(m, k, replace=False)
    scale = rng.uniform(0.5, 1.0)
    dofs = (3 * slots[:, None] + np.arange(3)).ravel()
    dense = W_full[np.ix_(dofs, dofs)].reshape(k, 3, k, 3).transpose(0, 2, 1, 3)
    want = contact_response.sparse_rows(scale * np.ascontiguousarray(dense), tol=1e-3)
    got = step_kernels.block_rows(W_full, slots, scale, 1e-3)
    assert 0 < len(want[1]) < k * k                     # some blocks dropped, some kept
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_array_equal(got[2], want[2])
