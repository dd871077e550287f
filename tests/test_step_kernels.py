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
    gap = np.einsum("ij,ij->i", line, n) - radius
    return corners, weights, n, gap, len(tie_row)


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
    assert want[4] > 0                                   # ties were met
    np.testing.assert_array_equal(corners, want[0])
    np.testing.assert_allclose(weights, want[1], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(normal, want[2], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(gap, want[3], rtol=1e-12, atol=1e-13)


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
