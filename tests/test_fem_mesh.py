"""Tet mesh generators, orientation checks, quadratic layout and assembly."""
import numpy as np
import pytest

from fem.assembly import assemble, assemble_from_blocks
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
