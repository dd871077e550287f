"""Signed distance grids against exact distances to spheres, boxes and a non-convex mesh."""

import numpy as np
import pytest

from rigid import shapes
from rigid.sdf import (SignedDistanceGrid, point_triangle_distance_squared, sdf_sample,
                       winding_number)

RADIUS = 0.5
BOX_HALF = np.array([0.3, 0.5, 0.7])


@pytest.fixture(scope="module")
def sphere():
    vertices, triangles = shapes.sphere_surface(RADIUS)
    return vertices, triangles, SignedDistanceGrid.build(vertices, triangles)


@pytest.fixture(scope="module")
def box():
    vertices, triangles = shapes.box_surface(2 * BOX_HALF)
    return vertices, triangles, SignedDistanceGrid.build(vertices, triangles)


def grid_nodes(grid):
    axes = [np.arange(n) for n in grid.shape]
    return grid.origin + grid.cell_size * np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def points_in_grid(grid, count, seed):
    upper = grid.origin + grid.cell_size * (grid.shape - 1)
    return np.random.default_rng(seed).uniform(grid.origin, upper, (count, 3))


def exact_box_distance(points, half):
    q = np.abs(points) - half
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


def brute_force_signed_distance(points, vertices, triangles):
    """Minimum over all triangles, signed by the winding number: the oracle for the grid nodes."""
    corners = vertices[triangles]
    distance = np.empty(len(points))
    for start in range(0, len(points), 64):
        p = np.repeat(points[start:start + 64], len(triangles), axis=0)
        c = np.tile(corners, (len(p) // len(triangles), 1, 1))
        d2 = point_triangle_distance_squared(p, c[:, 0], c[:, 1], c[:, 2])
        distance[start:start + 64] = np.sqrt(d2.reshape(-1, len(triangles)).min(axis=1))
    return np.where(winding_number(points, vertices, triangles) > 0.5, -distance, distance)


def test_point_triangle_distance_matches_dense_sampling_of_the_triangle():
    rng = np.random.default_rng(0)
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0.2, 0]), np.array([0.3, 0.9, 0.1])
    # points around the triangle hit all seven Voronoi regions
    points = rng.uniform(-1.0, 2.0, (300, 3))
    s, t = np.meshgrid(np.linspace(0, 1, 241), np.linspace(0, 1, 241))
    keep = s + t <= 1
    samples = a + s[keep, None] * (b - a) + t[keep, None] * (c - a)
    sampled = np.concatenate([np.sqrt(((samples[None] - chunk[:, None]) ** 2).sum(-1)).min(axis=1)
                              for chunk in np.array_split(points, 15)])
    k = len(points)
    exact = np.sqrt(point_triangle_distance_squared(points, np.tile(a, (k, 1)), np.tile(b, (k, 1)),
                                                    np.tile(c, (k, 1))))
    assert np.all(exact <= sampled + 1e-12)  # exact is a lower bound of the sampled minimum
    np.testing.assert_allclose(exact, sampled, atol=4e-3)  # sample spacing ~ 1/240
    # a degenerate (zero-area) triangle is the segment a-b
    seg = np.sqrt(point_triangle_distance_squared(np.array([[0.5, 1.0, 0.0]]), a[None], b[None], b[None]))
    assert seg[0] == pytest.approx(np.linalg.norm(np.cross([0.5, 1.0, 0.0], b) / np.linalg.norm(b)))


def test_winding_number_is_one_inside_and_zero_outside(sphere):
    vertices, triangles, _ = sphere
    inside = np.array([[0.0, 0, 0], [0.3, 0.1, -0.2], [0.0, 0.0, 0.47]])
    outside = np.array([[0.0, 0, 0.6], [5.0, 1.0, 2.0], [-0.4, 0.4, 0.0]])
    np.testing.assert_allclose(winding_number(inside, vertices, triangles), 1.0, atol=1e-9)
    np.testing.assert_allclose(winding_number(outside, vertices, triangles), 0.0, atol=1e-9)


def test_sphere_sdf_matches_distance_to_sphere_within_a_fraction_of_a_cell(sphere):
    vertices, triangles, grid = sphere
    h = grid.cell_size
    assert h == pytest.approx(2 * RADIUS / 40)
    # the icosphere lies inside the sphere; its largest gap is the inradius defect of a face
    corners = vertices[triangles]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    gap = RADIUS - np.min(np.einsum("ij,ij->i", corners[:, 0], normal) / np.linalg.norm(normal, axis=1))
    assert 0 < gap < 0.1 * h
    points = points_in_grid(grid, 20000, seed=1)
    r = np.linalg.norm(points, axis=1)
    phi, _ = grid.query(points)
    error = phi - (r - RADIUS)
    shell = (r > 0.3 * RADIUS)  # the cone tip of |p| at the centre is not trilinear
    print(f"sphere: h={h:.4f}, gap={gap / h:.3f} h, max error {np.abs(error[shell]).max() / h:.3f} h")
    assert np.abs(error[shell]).max() < gap + 0.15 * h
    assert np.abs(error).max() < gap + 0.5 * h
    assert np.all(np.sign(phi[np.abs(r - RADIUS) > gap + h]) == np.sign(r - RADIUS)[np.abs(r - RADIUS) > gap + h])


def test_grid_nodes_store_exact_signed_distance_to_the_mesh(sphere):
    vertices, triangles, grid = sphere
    nodes = grid_nodes(grid)
    pick = np.random.default_rng(2).choice(len(nodes), 600, replace=False)
    exact = brute_force_signed_distance(nodes[pick], vertices, triangles)
    error = grid.values.ravel()[pick] - exact
    band = np.abs(exact) <= 2 * grid.cell_size  # exact band
    assert np.abs(error[band]).max() < 1e-12
    # far nodes: closest-triangle propagation is an upper bound on |phi| within a small fraction
    assert np.all(np.abs(grid.values.ravel()[pick]) >= np.abs(exact) - 1e-12)
    assert np.abs(error).max() < 0.15 * grid.cell_size


def test_box_sdf_matches_exact_box_distance_inside_and_outside(box):
    _, _, grid = box
    h = grid.cell_size
    nodes = grid_nodes(grid)
    exact_nodes = exact_box_distance(nodes, BOX_HALF)
    assert np.abs(grid.values.ravel() - exact_nodes).max() < 1e-12
    assert (exact_nodes < 0).any() and (exact_nodes > 0).any()
    points = points_in_grid(grid, 30000, seed=3)
    phi, _ = grid.query(points)
    error = np.abs(phi - exact_box_distance(points, BOX_HALF))
    # Trilinear interpolation only errs in cells crossed by a kink of the field (edges, corners,
    # medial planes). It is a convex combination of corner values of a 1-Lipschitz field, so the
    # error is at most the weighted mean distance to the corners, sqrt(3)/2 h at a cell centre.
    print(f"box: max interpolation error {error.max() / h:.3f} h, 95th percentile "
          f"{np.percentile(error, 95) / h:.4f} h")
    assert error.max() < np.sqrt(3) / 2 * h
    assert np.median(error) < 1e-12  # most cells see a linear field
    assert np.percentile(error, 95) < 0.15 * h
    # A slab over the +z face centre whose cells (corners up to h away) stay closer to that face
    # than to any other: the distance is linear in z there and is reproduced exactly.
    low = [-0.05, -0.1, BOX_HALF[2] - 0.15]
    high = [0.05, 0.1, BOX_HALF[2] + 0.08]
    slab = np.random.default_rng(5).uniform(low, high, (2000, 3))
    phi, normal = grid.query(slab)
    np.testing.assert_allclose(phi, slab[:, 2] - BOX_HALF[2], atol=1e-12)
    np.testing.assert_allclose(normal, np.tile([0.0, 0.0, 1.0], (len(slab), 1)), atol=1e-9)


def test_normals_point_outward_along_the_sphere_radius(sphere):
    _, _, grid = sphere
    rng = np.random.default_rng(6)
    direction = rng.normal(size=(2000, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = direction * RADIUS * rng.uniform(0.85, 1.15, (len(direction), 1))
    _, normal = grid.query(points)
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-12)
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", normal, direction), -1, 1)))
    print(f"normal angle to the radius: mean {angle.mean():.2f} deg, max {angle.max():.2f} deg")
    assert angle.mean() < 3.0 and angle.max() < 10.0  # facets of a level-3 icosphere: ~11 deg apart


def test_query_outside_the_grid_is_positive_with_zero_normal(box):
    _, _, grid = box
    far = np.array([[10.0, 0, 0], [0, -3.0, 0.1], [0.0, 0.0, 2.5], [100.0, 100.0, -100.0]])
    phi, normal = grid.query(far)
    true_distance = exact_box_distance(far, BOX_HALF)
    upper = grid.origin + grid.cell_size * (grid.shape - 1)
    to_grid = np.linalg.norm(far - np.clip(far, grid.origin, upper), axis=1)
    # nodes on the grid boundary are at least `padding` from the surface
    assert grid.padding == pytest.approx(3 * grid.cell_size)
    assert np.all(phi >= to_grid + grid.padding - 1e-12)
    np.testing.assert_allclose(phi, true_distance, rtol=0.1)
    np.testing.assert_array_equal(normal, 0.0)
    # continuous across the grid boundary
    edge = grid.origin[0]
    inside_phi, _ = grid.query([[edge + 1e-9, 0.0, 0.0]])
    outside_phi, _ = grid.query([[edge - 1e-9, 0.0, 0.0]])
    assert outside_phi[0] == pytest.approx(inside_phi[0], abs=1e-8)


def test_numba_sample_matches_query(box, sphere):
    for _, _, grid in (box, sphere):
        points = np.concatenate([points_in_grid(grid, 300, seed=8), [[9.0, 9.0, 9.0], [-4.0, 0.0, 0.1]]])
        phi, normal = grid.query(points)
        sampled = np.array([sdf_sample(grid.values, grid.origin, grid.cell_size, p) for p in points])
        np.testing.assert_allclose(sampled[:, 0], phi, atol=1e-12)
        np.testing.assert_allclose(sampled[:, 1:], normal, atol=1e-12)


def test_non_convex_star_shape_sign_and_distance_at_nodes():
    vertices, triangles = shapes.sphere_surface(1.0, 0.5)  # level 2, 162 vertices
    bumps = 1.0 + 0.35 * np.sin(3 * vertices[:, 0]) * np.cos(4 * vertices[:, 1])
    vertices = vertices * bumps[:, None]  # star shaped, with concave pits
    grid = SignedDistanceGrid.build(vertices, triangles, cell_size=0.1)
    nodes = grid_nodes(grid)
    pick = np.random.default_rng(9).choice(len(nodes), 800, replace=False)
    exact = brute_force_signed_distance(nodes[pick], vertices, triangles)
    stored = grid.values.ravel()[pick]
    assert np.all(np.sign(stored[np.abs(exact) > 1e-9]) == np.sign(exact[np.abs(exact) > 1e-9]))
    assert np.abs(stored - exact).max() < 0.2 * grid.cell_size


def test_compiled_point_triangle_distance_matches_the_numpy_one_in_every_region():
    """The grid build's compiled loops (rigid.sdf_build) use a scalar copy of
    the closest-point classification; on random points around random, thin and degenerate
    triangles it gives the numpy version's squared distances to round-off."""
    from rigid.sdf_build import pair_distances
    rng = np.random.default_rng(7)
    k = 4000
    corners = rng.standard_normal((k, 3, 3))
    corners[: k // 8, 2] = corners[: k // 8, 1]                       # a segment
    corners[k // 8: k // 4, 1:] = corners[k // 8: k // 4, :1]          # a point
    corners[k // 4: k // 2, 2] = corners[k // 4: k // 2, 0] + 1e-9 * rng.standard_normal((k // 4, 3))
    origin, h, shape = np.zeros(3), 1.0, np.array([1, 1, 1])
    # one grid node (the origin) against every triangle moved by a random offset
    corners -= 2.0 * rng.standard_normal((k, 1, 3))
    want = point_triangle_distance_squared(np.zeros((k, 3)), corners[:, 0], corners[:, 1], corners[:, 2])
    got = pair_distances(np.zeros(k, dtype=np.int64), np.arange(k), corners, origin, h, shape)
    assert np.allclose(got, want, rtol=1e-12, atol=1e-15)
