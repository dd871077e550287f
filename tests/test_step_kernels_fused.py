"""The coupled step's fused kernels (issue 24: the step's fixed work in one pass each) against the
numpy code they replaced, on random inputs. Each reference below is that numpy code, kept here
only as the oracle; the kernels must agree with it to round-off, and exactly where they pick."""
import numpy as np
import pytest
import scipy.sparse as sp

from fem import step_kernels
from fem.system import _blocks
from hybrid.coupling import kernels, nodes, resting, rest_grid, solve
from rigid.sdf import DEFAULT_PADDING_CELLS
from rigid.sdf_kernels import BEYOND_STEPS, PADDING_REACH, SETTLED

SEEDS = range(4)


def random_rotation(rng):
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def random_stiffness(rng, n):
    """A random symmetric (3n, 3n) CSR matrix with the sparsity of a mesh (node pairs), some
    entries of its 3x3 blocks zero (as K's are on a structured mesh)."""
    pairs = rng.integers(0, n, size=(4 * n, 2))
    rows = (3 * pairs[:, :1] + np.arange(3)).repeat(3, axis=1).ravel()
    cols = np.tile(3 * pairs[:, 1:] + np.arange(3), (1, 3)).ravel()
    values = rng.standard_normal(len(rows)) * (rng.random(len(rows)) < 0.7)
    K = sp.coo_matrix((values, (rows, cols)), shape=(3 * n, 3 * n)).tocsr()
    K = (K + K.T + sp.eye(3 * n) * 10).tocsr()
    K.eliminate_zeros()
    return K


@pytest.mark.parametrize("seed", SEEDS)
def test_elastic_force_from_blocks_matches_the_csr_product(seed):
    rng = np.random.default_rng(seed)
    n = 50
    K = random_stiffness(rng, n)
    x, rest = rng.standard_normal((n, 3)), rng.standard_normal((n, 3))
    c, R = rng.standard_normal(3), random_rotation(rng)
    reference = (-(K @ (((x - c) @ R - rest).ravel()))).reshape(-1, 3) @ R.T
    _, (ptr, col, blocks) = _blocks(K)
    force = step_kernels.frame_elastic_force(ptr, col, blocks, x, c, R, rest)
    np.testing.assert_allclose(force, reference, rtol=1e-12, atol=1e-12 * np.abs(reference).max())


@pytest.mark.parametrize("seed", SEEDS)
def test_free_response_added_as_rotate_back_of_the_scattered_change(seed):
    rng = np.random.default_rng(seed)
    n = 40
    v, R = rng.standard_normal((n, 3)), random_rotation(rng)
    free = np.sort(rng.choice(3 * n, size=2 * n, replace=False))
    dv_free = rng.standard_normal(len(free))
    dv = np.zeros(3 * n)
    dv[free] = dv_free
    reference = v + dv.reshape(-1, 3) @ R.T
    out = step_kernels.add_free_response(v, dv_free, free, R)
    np.testing.assert_allclose(out, reference, rtol=1e-14, atol=1e-14)
    assert np.array_equal(out[np.setdiff1d(np.arange(n), free // 3)],
                          v[np.setdiff1d(np.arange(n), free // 3)])      # nodes with no free DOF


@pytest.mark.parametrize("seed", SEEDS)
def test_stacked_moving_nodes_match_gathers_and_the_mean_velocity(seed):
    rng = np.random.default_rng(seed)
    n, h, rate = 60, 1e-3, 0.5e-3
    x, x_base, v = rng.standard_normal((n, 3)), rng.standard_normal((n, 3)), rng.standard_normal((n, 3))
    picked = np.sort(rng.choice(n, size=25, replace=False))
    out_x, out_v = np.full((30, 3), np.nan), np.full((30, 3), np.nan)
    nodes.stack_moving(x, x_base, v, rate, picked, h, out_x, out_v, 5)
    assert np.array_equal(out_x[5:], x[picked])
    np.testing.assert_allclose(out_v[5:], (x_base[picked] - x[picked] + rate * v[picked]) / h, rtol=1e-14)
    assert np.isnan(out_x[:5]).all() and np.isnan(out_v[:5]).all()         # other bodies' rows untouched
    sweep = nodes.row_norms(out_v[5:], h)
    np.testing.assert_allclose(sweep, np.linalg.norm(out_v[5:], axis=1) * h, rtol=1e-14)


@pytest.mark.parametrize("seed", SEEDS)
def test_normal_part_and_slide_match_einsum_and_norm(seed):
    rng = np.random.default_rng(seed)
    impulse = rng.standard_normal((30, 3))
    normal = rng.standard_normal((30, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    lam, slide = resting.normal_and_slide(impulse, normal)
    ref_lam = np.einsum("cd,cd->c", impulse, normal)
    np.testing.assert_allclose(lam, ref_lam, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(slide, np.linalg.norm(impulse - ref_lam[:, None] * normal, axis=1),
                               rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("seed", SEEDS)
def test_median_and_sorted_membership_match_numpy(seed):
    rng = np.random.default_rng(seed)
    values = rng.standard_normal(31 + seed)
    mask = rng.random(len(values)) < 0.6
    mask[0] = True
    assert resting.median_of(values, mask) == np.median(values[mask])
    pool = np.sort(rng.choice(100, size=20, replace=False))
    queries = rng.integers(-5, 110, size=50)
    assert np.array_equal(resting.sorted_isin(queries, pool), np.isin(queries, pool))
    assert not resting.sorted_isin(queries, pool[:0]).any()


def edge_normals_reference(normal, gap, body_b, own, edge_cos, near):
    """fem_contact.edge_normals and detect._edge_normals as numpy code, before the kernel."""
    normal, gap = normal.copy(), gap.copy()
    front = np.ones(len(gap), dtype=bool)
    at = np.nonzero(body_b >= 0)[0]
    along = np.einsum("ij,ij->i", normal[at], -own)
    turned = (along < edge_cos) & (gap[at] <= near[at])
    out_n, out_g = normal.copy(), gap.copy()
    out_n[at[turned]] = -own[turned]
    out_g[at[turned]] *= along[turned]
    front[at[along < -edge_cos]] = False
    unit = np.abs(np.einsum("ij,ij->i", out_n, out_n) - 1.0) < 1e-6
    return np.where(unit[:, None], out_n, normal), np.where(unit, out_g, gap), front


@pytest.mark.parametrize("seed", SEEDS)
def test_edge_turns_match_the_numpy_edge_normals(seed):
    rng = np.random.default_rng(seed)
    c = 60
    normal = rng.standard_normal((c, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    gap = rng.standard_normal(c) * 1e-3
    body_b = rng.integers(-1, 3, size=c)
    own = rng.standard_normal(((body_b >= 0).sum(), 3))
    own /= np.linalg.norm(own, axis=1, keepdims=True)
    own[::7] = 0.0                      # nodes without a face normal of their own
    near = rng.uniform(5e-4, 2e-3, c)   # some gaps beyond it: those keep the rigid normal
    reference = edge_normals_reference(normal, gap, body_b, own, float(np.cos(np.radians(70.0))), near)
    out = kernels.edge_turns(normal, gap, body_b, own, float(np.cos(np.radians(70.0))), near)
    np.testing.assert_allclose(out[0], reference[0], rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(out[1], reference[1], rtol=1e-14, atol=1e-18)
    assert np.array_equal(out[2], reference[2])
    assert not out[2].all() and (out[0] != normal).any()     # the sample turns and drops some


@pytest.mark.parametrize("seed", SEEDS)
def test_nearest_of_indexed_points_matches_the_gathered_search(seed):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((80, 3))
    rows = np.sort(rng.choice(80, size=40, replace=False))
    queries = np.concatenate([rng.standard_normal((10, 3)), x[rows[:3]]])
    assert np.array_equal(kernels.nearest_rows_of(x, rows, queries), kernels.nearest_rows(x[rows], queries))
    assert np.array_equal(kernels.nearest_rows_of(x, rows, queries)[-3:], np.arange(3))


@pytest.mark.parametrize("seed", SEEDS)
def test_anchor_reaction_matches_the_sparse_rows_product(seed):
    rng = np.random.default_rng(seed)
    n, dt = 30, 1e-3
    A = random_stiffness(rng, n)
    fixed = np.sort(rng.choice(3 * n, size=12, replace=False))
    v, impulse, R = rng.standard_normal((n, 3)), rng.standard_normal((n, 3)), random_rotation(rng)
    rhs = rng.standard_normal(3 * n)
    rows = A[fixed]
    r = np.zeros(3 * n)
    r[fixed] = (rows @ (v @ R).ravel() - rhs[fixed] - (impulse @ R).ravel()[fixed]) / dt
    reference = r.reshape(-1, 3) @ R.T
    out = step_kernels.anchor_reaction(rows.indptr, rows.indices, rows.data, fixed, v, impulse, rhs, R, dt)
    np.testing.assert_allclose(out, reference, rtol=1e-12, atol=1e-12 * np.abs(reference).max())
    free_nodes = np.setdiff1d(np.arange(n), fixed // 3)
    assert not out[free_nodes].any()


def box_grid():
    """The signed-distance grid of a 0.4 x 0.3 x 0.2 m box's surface (rigid.sdf)."""
    from rigid import shapes
    from rigid.sdf import SignedDistanceGrid
    points, triangles = shapes.box_surface([0.4, 0.3, 0.2])
    return SignedDistanceGrid.build(points, triangles)


@pytest.mark.parametrize("seed", SEEDS)
def test_rest_query_matches_the_numpy_steps_of_against(seed):
    rng = np.random.default_rng(seed)
    grid = box_grid()
    p, s = 40, 30
    x = rng.uniform(-0.3, 0.3, size=(p, 3))
    moved = rng.standard_normal((s, 3)) * 1e-3
    nearest = rng.integers(0, s, size=p)
    c, R, rest_center = rng.standard_normal(3) * 0.01, random_rotation(rng), rng.standard_normal(3) * 0.01
    radius = np.where(rng.random(p) < 0.5, 0.0, 0.01)
    reach = rng.uniform(0.0, 0.05, size=p)
    largest = float(np.linalg.norm(moved, axis=1).max())
    # the numpy code of fem_contact._against the kernel replaced
    X = (x - c) @ R + rest_center - moved[nearest]
    phi, n_rest = grid.query(X)
    # beyond the grid: the nearest surface point, from the grid's point nearest X and then, for
    # points with a radius, from points of the line towards X within the padding until it
    # settles (rigid.sdf_kernels.grid_sdf)
    low, high = grid.origin, grid.origin + (grid.shape - 1) * grid.cell_size
    beyond = np.nonzero(np.any(np.clip(X, low, high) != X, axis=1))[0]
    assert len(beyond) > 0 and np.any(radius[beyond] > 0) and np.any(radius[beyond] == 0)
    for k in beyond:
        q, surface = np.clip(X[k], low, high), np.clip(X[k], low, high)
        for step in range(BEYOND_STEPS + 1 if radius[k] > 0 else 1):
            at, toward = grid.query(q[None])
            shift = np.sum((q - at[0] * toward[0] - surface) ** 2)
            surface = q - at[0] * toward[0]
            u = (X[k] - surface) / np.linalg.norm(X[k] - surface)
            if step > 0 and shift < (SETTLED * grid.cell_size) ** 2:
                break
            q = np.clip(surface + PADDING_REACH * DEFAULT_PADDING_CELLS * grid.cell_size * u, low, high)
        phi[k], n_rest[k] = np.linalg.norm(X[k] - surface), u
    phi = phi - radius
    near = np.nonzero((phi < reach + largest)
                      & (np.any(n_rest != 0, axis=1) | (np.abs(phi + radius) <= grid.cell_size)))[0]
    out = rest_grid.rest_query(x, nearest, moved, c, R, rest_center, grid.origin, grid.cell_size,
                             grid.shape, grid.values, radius, reach, largest)
    assert np.array_equal(out[0], near) and 0 < len(near) < p
    np.testing.assert_allclose(out[1], X, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(out[2], phi, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(out[3], n_rest, rtol=1e-12, atol=1e-14)


def test_points_beyond_the_grid_s_padding_get_their_distance_to_the_surface():
    """Over a box's faces and beyond its grid's padding (3 cells), the grid's own query has no
    normal; the rest query gives the distance to the face and the face's normal, as for a point
    within the grid (a sphere larger than the padding touches the surface with its centre out
    there)."""
    grid = box_grid()
    pad = grid.padding
    X = np.array([[0.05, 0.02, 0.1 + 1.5 * pad], [0.2 + 2.0 * pad, -0.05, 0.03],
                  [0.0, -0.15 - 1.2 * pad, 0.0], [0.05, 0.02, 0.1 + 0.5 * pad]])
    expected = np.array([1.5 * pad, 2.0 * pad, 1.2 * pad, 0.5 * pad])
    normals = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]])
    assert np.all(grid.query(X[:3])[1] == 0)
    out = rest_grid.rest_query(X, np.zeros(4, np.int64), np.zeros((1, 3)), np.zeros(3), np.eye(3),
                               np.zeros(3), grid.origin, grid.cell_size, grid.shape, grid.values,
                               np.zeros(4), np.full(4, 1.0), 0.0)
    assert np.array_equal(out[0], np.arange(4))
    np.testing.assert_allclose(out[2], expected, rtol=0, atol=1e-3 * grid.cell_size)
    np.testing.assert_allclose(out[3], normals, rtol=0, atol=1e-6)


@pytest.mark.parametrize("seed", SEEDS)
def test_points_off_their_nodes_match_the_numpy_filter(seed):
    rng = np.random.default_rng(seed)
    n, q = 50, 30
    x = rng.standard_normal((n, 3))
    surface_nodes = np.sort(rng.choice(n, size=20, replace=False))
    close = rng.integers(0, 20, size=q)
    points = x[surface_nodes[close]] + rng.standard_normal((q, 3)) * 0.1
    n_rest = rng.standard_normal((q, 3))
    n_rest /= np.linalg.norm(n_rest, axis=1, keepdims=True)
    R, off = random_rotation(rng), 0.1
    across = x[surface_nodes[close]] - points
    normal = n_rest @ R.T
    across -= np.einsum("ij,ij->i", across, normal)[:, None] * normal
    behind = np.einsum("ij,ij->i", x[surface_nodes[close]] - points, normal)
    reference = (np.einsum("ij,ij->i", across, across) > off ** 2) | (behind > 0.05)
    keep = kernels.off_nodes_kept(x, surface_nodes, close, points, n_rest, R, off, 0.05)
    assert np.array_equal(keep, reference) and keep.any() and not keep.all()


@pytest.mark.parametrize("seed", SEEDS)
def test_sample_points_match_the_numpy_gather(seed):
    rng = np.random.default_rng(seed)
    b = 6
    count = rng.integers(0, 8, size=b)
    point_start = np.concatenate([[0], np.cumsum(count)]).astype(np.int64)
    point_local = rng.standard_normal((point_start[-1], 3))
    point_kind = rng.integers(0, 3, size=point_start[-1])
    position = rng.standard_normal((b, 3))
    rotation = np.array([random_rotation(rng) for _ in range(b)])
    near = np.sort(rng.choice(b, size=4, replace=False))
    # the numpy code of fem_contact.detect_rigid_points the kernel replaced
    c = point_start[near + 1] - point_start[near]
    owner = np.repeat(near, c)
    at = np.repeat(point_start[near] - np.cumsum(c) + c, c) + np.arange(c.sum())
    plain = point_kind[at] != 1
    owner, at = owner[plain], at[plain]
    x = position[owner] + np.einsum("pij,pj->pi", rotation[owner], point_local[at])
    out = kernels.sample_points(near, point_start, point_local, point_kind, 1, position, rotation)
    assert np.array_equal(out[0], owner) and np.array_equal(out[1], at)
    np.testing.assert_allclose(out[2], x, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("seed", SEEDS)
def test_particle_impulses_match_add_at_over_both_sides(seed):
    rng = np.random.default_rng(seed)
    nb, count, c = 3, 12, 40
    body_a = rng.integers(0, nb + count, size=c)
    body_b = rng.integers(-1, nb + count, size=c)
    increment = rng.standard_normal((c, 3))
    on_a, on_b = body_a >= nb, body_b >= nb
    reference = np.zeros((count, 3))
    np.add.at(reference, body_a[on_a] - nb, increment[on_a])
    np.add.at(reference, body_b[on_b] - nb, -increment[on_b])
    out = solve.particle_impulses(body_a, body_b, increment, nb, count)
    np.testing.assert_allclose(out, reference, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("seed", range(3))
def test_bounding_box_in_one_pass_matches_numpy_min_and_max(seed):
    from hybrid.app.impact_contacts import _bounds
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(int(rng.integers(1, 500)), 3)) * rng.uniform(0.01, 100, size=3)
    low, high = _bounds(x)
    assert np.array_equal(low, x.min(axis=0)) and np.array_equal(high, x.max(axis=0))
