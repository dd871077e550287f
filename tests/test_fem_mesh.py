"""Tet mesh generators, orientation checks, quadratic layout and assembly."""
import numpy as np
import pytest

from fem.assembly import assemble, assemble_from_blocks
from fem.warping import warped_assembly
from fem.mesh import (box_tet_mesh, check_tets, cylinder_tet_mesh, quadratic_tets,
                      sphere_tet_mesh, surface_triangles, tet_signed_volumes)
from fem.model import build_fem_model
from rigid.trimesh import is_closed, signed_volume


@pytest.mark.parametrize("make,args,exact_volume,tolerance", [
    (box_tet_mesh, ((0.4, 0.2, 0.1), 4), 0.4 * 0.2 * 0.1, 1e-12),
    (cylinder_tet_mesh, (0.5, 1.0, 8), np.pi * 0.25, 0.05),
    (sphere_tet_mesh, (1.0, 8), 4 / 3 * np.pi, 0.1),
])
def test_generated_meshes_are_closed_positive_and_centred(make, args, exact_volume, tolerance):
    points, tets = make(*args)
    volumes = tet_signed_volumes(points, tets)
    assert volumes.min() > 0
    surface = surface_triangles(tets)
    assert is_closed(surface)
    # outward surface encloses the tets' volume, close to the exact solid's
    np.testing.assert_allclose(signed_volume(points, surface), volumes.sum(), rtol=1e-12)
    assert abs(volumes.sum() / exact_volume - 1) < tolerance
    np.testing.assert_allclose(0.5 * (points.min(axis=0) + points.max(axis=0)), 0, atol=1e-12)


@pytest.mark.parametrize("cells", [4, 8, 12])
def test_sphere_mesh_keeps_the_cube_symmetries_and_the_asked_cell_size(cells):
    """The ball is the mirrored cube mesh mapped shell by shell onto the sphere: every mirror of
    the axes maps its node set onto itself, and its longest edge shrinks with the asked resolution
    (a cube cell's diagonal, sqrt(3) cells, stretched a little by the mapping)."""
    radius = 0.1
    points, tets = sphere_tet_mesh(radius, cells)
    key = lambda p: np.unique(np.round(p / radius, 9), axis=0)
    for axis in range(3):
        mirrored = points.copy()
        mirrored[:, axis] *= -1
        np.testing.assert_array_equal(key(mirrored), key(points))
    corners = points[tets]
    edges = np.linalg.norm(corners[:, [0, 0, 0, 1, 1, 2]] - corners[:, [1, 2, 3, 2, 3, 3]], axis=2)
    assert edges.max() < 2.1 * (2 * radius / cells)
    np.testing.assert_allclose(np.linalg.norm(points, axis=1).max(), radius, rtol=1e-12)


def test_check_tets_reorients_inverted_and_rejects_degenerate():
    points, tets = box_tet_mesh((1.0, 1.0, 1.0), 1)
    bad = tets.copy()
    bad[[1, 4]] = bad[[1, 4]][:, [1, 0, 2, 3]]
    fixed, flipped = check_tets(points, bad)
    assert flipped.tolist() == [1, 4]
    assert tet_signed_volumes(points, fixed).min() > 0
    # tetra10: the midside nodes follow the swapped vertices
    p2, t10 = quadratic_tets(points, tets)
    swapped = t10[:, [1, 0, 2, 3, 4, 6, 5, 8, 7, 9]]
    fixed10, flipped10 = check_tets(p2, swapped)
    assert len(flipped10) == len(t10)
    mid = p2[fixed10[:, 4:]]
    ends = 0.5 * (p2[fixed10[:, [0, 1, 0, 0, 1, 2]]] + p2[fixed10[:, [1, 2, 2, 3, 3, 3]]])
    np.testing.assert_allclose(mid, ends)
    flat = np.vstack([tets, [[0, 1, 2, 2]]])
    with pytest.raises(ValueError, match=str(len(tets))):
        check_tets(points, flat)


@pytest.mark.parametrize("order", [1, 2])
def test_assembled_matrices_match_element_blocks_and_rigid_modes(order):
    points, tets = cylinder_tet_mesh(0.1, 0.3, 4)
    if order == 2:
        points, tets = quadratic_tets(points, tets)
    K, M_scalar, data = assemble(points, tets, 1e9, 0.3, 1200.0)
    np.testing.assert_allclose((K - assemble_from_blocks(data, data.tet_stiffness, K.shape[0])).data,
                               0, atol=1e-12 * abs(K).max())
    volume = tet_signed_volumes(points, tets).sum()
    np.testing.assert_allclose(M_scalar.sum(), 1200.0 * volume, rtol=1e-12)
    np.testing.assert_allclose(data.tet_volume.sum(), volume, rtol=1e-12)
    # rigid translations and infinitesimal rotations are in the null space of K
    for mode in [np.tile([1.0, -2.0, 0.5], (len(points), 1)), np.cross([0.3, -0.7, 1.1], points)]:
        assert np.abs(K @ mode.ravel()).max() < 1e-9 * abs(K).max()
    # HRZ lumped mass is positive and sums to the total mass
    model = build_fem_model(points, tets, order=order, density=1200.0, young=1e9, poisson=0.3)
    assert model.node_mass.min() > 0
    np.testing.assert_allclose(model.node_mass.sum(), 1200.0 * volume, rtol=1e-12)
    assert is_closed(model.surface)
    np.testing.assert_allclose(signed_volume(model.rest_points, model.surface), volume, rtol=1e-12)


@pytest.mark.parametrize("order", [1, 2])
def test_warped_stiffness_of_a_rigidly_rotated_body_is_the_rotated_stiffness(order):
    """Every element turned by the same Q: sum_e Q K_e Q^T = (I_n kron Q) K (I_n kron Q)^T; and for
    element rotations of their own, each rotated block sums as the element loop would."""
    points, tets = cylinder_tet_mesh(0.1, 0.3, 4)
    if order == 2:
        points, tets = quadratic_tets(points, tets)
    K, _, data = assemble(points, tets, 1e9, 0.3, 1200.0)
    c, s = np.cos(0.7), np.sin(0.7)
    Q = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    big = np.kron(np.eye(len(points)), Q)
    warped = warped_assembly(data, np.broadcast_to(Q, (len(tets), 3, 3)), K.shape[0])
    np.testing.assert_allclose(warped.toarray(), big @ K.toarray() @ big.T, rtol=0, atol=1e-12 * abs(K).max())
    rng = np.random.default_rng(2)
    R = np.linalg.qr(rng.standard_normal((len(tets), 3, 3)))[0]
    t, m, _ = data.tet_stiffness.shape
    blocks = np.einsum("tik,takbl,tjl->taibj", R, data.tet_stiffness.reshape(t, m // 3, 3, m // 3, 3), R)
    reference = assemble_from_blocks(data, blocks.reshape(t, m, m), K.shape[0])
    np.testing.assert_allclose(warped_assembly(data, R, K.shape[0]).toarray(), reference.toarray(),
                               rtol=0, atol=1e-12 * abs(K).max())


def test_warped_forces_vanish_under_rigid_motion_and_equal_linear_forces_unrotated():
    from fem.warping import warped_forces
    points, tets = cylinder_tet_mesh(0.1, 0.3, 4)
    K, _, data = assemble(points, tets, 1e9, 0.3, 1200.0)
    n = len(points)
    c, s = np.cos(1.1), np.sin(1.1)
    Q = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    moved = points @ Q.T + [3.0, -2.0, 5.0]
    f = warped_forces(data, np.broadcast_to(Q, (len(tets), 3, 3)), moved, points, n)
    assert np.abs(f).max() <= 1e-12 * abs(K).max() * np.abs(points).max()
    u = 1e-4 * np.random.default_rng(0).standard_normal((n, 3))
    f = warped_forces(data, np.broadcast_to(np.eye(3), (len(tets), 3, 3)), points + u, points, n)
    np.testing.assert_allclose(f.ravel(), -(K @ u.ravel()), rtol=0, atol=1e-10 * np.abs(K @ u.ravel()).max())


def test_default_mesh_of_a_box_has_the_boxs_mirror_symmetries():
    """A box without a ``resolution`` is meshed with an even number of cells along each side, so
    its mesh maps onto itself mirrored in each axis (with three cells a side it did not, and a
    rubber cube dropped flat drifted 14 mm sideways and tilted 3.6 degrees)."""
    from hybrid.app.deformable import default_box_mesh
    for size in [(0.1, 0.1, 0.1), (0.3, 0.1, 0.1), (0.3, 0.3, 0.01), (0.2, 0.15, 0.1)]:
        points, tets = box_tet_mesh(size, default_box_mesh(size).cells)
        key = lambda p: np.round(p / np.max(size), 9)
        for axis in range(3):
            flip = points.copy()
            flip[:, axis] *= -1
            index = {tuple(p): i for i, p in enumerate(key(points))}
            image = np.array([index[tuple(p)] for p in key(flip)])
            assert {tuple(sorted(t)) for t in image[tets]} == {tuple(sorted(t)) for t in tets}
