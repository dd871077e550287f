"""A fracture event rebuilds only what changed, and what it reuses equals what it replaced.

A piece's matrices are summed from its parent's element blocks (fem.assembly.assemble_subset)
instead of assembled again with scikit-fem; the brittle check solves for principal stresses
only where a bound says the strength may be passed; the CSR pattern is found on node pairs and
boundary faces by one integer key per face. Each is compared here with what it replaced.
"""
import numpy as np
import pytest

from fem.assembly import _csr_pattern, assemble, assemble_subset
from fem.warping import warped_assembly
from fem.fracture import (find_crack, fracture_candidates, fracture_model, principal_tension,
                          tension_bound)
from fem.mesh import box_tet_mesh, quadratic_tets, surface_triangles
from fem.model import build_fem_model
from fem.split import split_bodies, split_mesh, tet_faces
from fem.system import system_factorisation
from rigid import quaternion as quat

YOUNG, POISSON, DENSITY = 2.0e8, 0.3, 1200.0


def _pieces(order):
    """A distorted box mesh of ``order`` cut along the plane x = 0 (and around it): the mesh,
    and its pieces (fem.split.Fragment, largest first)."""
    points, tets = box_tet_mesh(np.array([0.3, 0.2, 0.1]), 6)
    if order == 2:
        points, tets = quadratic_tets(points, tets)
    points = points + np.random.default_rng(1).normal(scale=0.004, size=points.shape)
    faces = tet_faces(tets)
    centre = points[faces.face_vertices].mean(axis=1)
    cut = np.flatnonzero(faces.interior & (np.abs(centre[:, 0]) < 0.02))
    split = split_mesh(points, tets, faces.face_vertices[cut], order, faces)
    pieces = sorted(split_bodies(split.points, split.tets), key=lambda f: -len(f.tet_index))
    return points, tets, pieces


def _relative(a, b):
    return abs(a - b).max() / abs(b).max()


@pytest.mark.parametrize("order", [1, 2])
def test_piece_matrices_from_parent_blocks_equal_scikit_fem_assembly(order):
    points, tets, pieces = _pieces(order)
    _, _, parent = assemble(points, tets, YOUNG, POISSON, DENSITY)
    assert len(pieces) > 2 and len(pieces[0].tet_index) > 50      # two halves and loose tets
    rng = np.random.default_rng(2)
    for piece in pieces[:3] + pieces[-1:]:
        K, M, data = assemble(piece.points, piece.tets, YOUNG, POISSON, DENSITY)
        K_sub, M_sub, sub = assemble_subset(parent, tets, piece.tet_index, piece.tets, DENSITY)
        assert K_sub.shape == K.shape and K_sub.nnz == K.nnz
        assert _relative(K_sub, K) < 1e-13 and _relative(M_sub, M) < 1e-13
        assert np.allclose(sub.tet_volume, data.tet_volume, rtol=1e-13, atol=0)
        assert np.allclose(sub.tet_rest_inverse, data.tet_rest_inverse, rtol=1e-12, atol=0)
        # element nodes, gradients, blocks and the CSR pattern belong together: a warped stiffness
        # and the displacement gradients of a random field are the same from either
        R = quat.to_matrix(quat.normalize(rng.normal(size=(len(piece.tet_index), 4))))
        n = len(piece.points)
        assert _relative(warped_assembly(sub, R, 3 * n), warped_assembly(data, R, 3 * n)) < 1e-13
        u = rng.normal(size=(n, 3))
        grad = [np.swapaxes(u[d.tet_nodes], 1, 2)[:, None] @ d.tet_gradients for d in (sub, data)]
        assert np.allclose(grad[0], grad[1], rtol=0, atol=1e-10 * abs(grad[1]).max())


@pytest.mark.parametrize("order", [1, 2])
def test_piece_model_built_from_parent_equals_one_assembled_again(order):
    points, tets, pieces = _pieces(order)
    parent = build_fem_model(points, tets, order=order, density=DENSITY, young=YOUNG,
                             poisson=POISSON)
    for piece in pieces[:2] + pieces[-1:]:
        kwargs = dict(order=order, density=DENSITY, young=YOUNG, poisson=POISSON, dt=1e-3)
        fresh = build_fem_model(piece.points, piece.tets, **kwargs)
        reused = build_fem_model(piece.points, piece.tets, elements_of=(parent, piece.tet_index),
                                 **kwargs)
        assert np.allclose(reused.node_mass, fresh.node_mass, rtol=1e-13, atol=0)
        assert np.isclose(reused.node_mass.sum(), DENSITY * fresh.elements.tet_volume.sum(),
                          rtol=1e-12)
        assert _relative(reused.K, fresh.K) < 1e-13 and _relative(reused.M, fresh.M) < 1e-13
        assert np.array_equal(reused.surface, fresh.surface)
        assert np.allclose(reused.rest_center, fresh.rest_center, rtol=0, atol=1e-15)
        # one step of the factorised system from either gives the same velocities
        b = np.random.default_rng(3).normal(size=3 * len(piece.points))
        free = fresh.free_dofs
        solve = [system_factorisation(m, 1e-3).solve(b[free])
                 for m in (reused, fresh)]
        assert np.allclose(solve[0], solve[1], rtol=0, atol=1e-10 * abs(solve[1]).max())
    with pytest.raises(ValueError, match="Young"):
        build_fem_model(pieces[0].points, pieces[0].tets, order=order, density=DENSITY,
                        young=2 * YOUNG, poisson=POISSON, elements_of=(parent, pieces[0].tet_index))


def _brute_force_candidates(sigma, strength, max_cracks, unbreakable):
    """fracture_candidates as it was: one eigensolve of every element."""
    sigma_1, normal = principal_tension(sigma)
    element = np.flatnonzero((sigma_1 > strength) & ~unbreakable)
    order = np.argsort(-(sigma_1[element] - strength) / strength, kind="stable")[:max_cracks]
    return element[order], normal[element[order]], sigma_1[element[order]]


def test_brittle_check_finds_the_candidates_of_a_full_eigensolve():
    rng = np.random.default_rng(4)
    strength = 1.0e6
    sigma = rng.normal(scale=0.6e6, size=(4000, 3, 3))
    sigma = 0.5 * (sigma + np.swapaxes(sigma, 1, 2))
    # elements exactly at the strength: diagonal stresses whose largest entry is the strength
    sigma[:200] = 0.0
    sigma[:200, 0, 0] = strength
    sigma[:200, 1, 1] = rng.uniform(-1, 1, 200) * strength
    sigma[200:300] *= 1e-3      # far below: skipped without an eigensolve
    # turned stresses whose largest principal stress passes the strength by a hair
    R = quat.to_matrix(quat.normalize(rng.normal(size=(100, 4))))
    principal = np.column_stack([strength * (1 + 1e-9 * rng.random(100)),
                                 rng.uniform(-2, 1, (100, 2)) * strength])
    sigma[300:400] = np.einsum("kij,kj,klj->kil", R, principal, R)
    sigma[400:500] = np.diag(principal[0]) * (1 + 1e-12)     # and axis-aligned ones
    unbreakable = rng.random(len(sigma)) < 0.1
    bound = tension_bound(sigma)
    assert np.all(bound >= principal_tension(sigma)[0])
    for max_cracks in (None, 7):
        found = fracture_candidates(sigma, strength, max_cracks, unbreakable)
        element, normal, sigma_1 = _brute_force_candidates(sigma, strength, max_cracks,
                                                           unbreakable)
        assert len(element) > 5 and (max_cracks or np.isin(np.arange(300, 500), element).sum() > 160)
        assert np.array_equal(found.element, element)
        assert np.array_equal(found.normal, normal)
        assert np.array_equal(found.principal_stress, sigma_1)


def _pattern_of_every_dof_pair(tet_nodes, dof_count):
    """The CSR pattern as fem.assembly built it before: every DOF pair of every element sorted."""
    t, b = tet_nodes.shape
    dofs = (3 * tet_nodes[:, :, None] + np.arange(3)).reshape(t, 3 * b)
    keys, block_to_csr = np.unique(np.repeat(dofs, 3 * b, axis=1).ravel() * dof_count
                                   + np.tile(dofs, (1, 3 * b)).ravel(), return_inverse=True)
    rows = keys // dof_count
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=dof_count))])
    return rows, keys % dof_count, indptr, block_to_csr.ravel()


def _surface_by_rows(tets):
    """Boundary faces as fem.mesh.surface_triangles found them before (a unique over rows)."""
    local = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    faces = tets[:, local].reshape(-1, 3)
    _, inverse, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True,
                                   return_counts=True)
    return faces[counts[inverse.ravel()] == 1]


@pytest.mark.parametrize("order", [1, 2])
def test_csr_pattern_from_node_pairs_is_the_pattern_of_every_dof_pair(order):
    _, tets, pieces = _pieces(order)
    rng = np.random.default_rng(5)
    shuffled = tets[rng.permutation(len(tets))][:, np.r_[rng.permutation(4), 4:tets.shape[1]]]
    for mesh, spare in ((tets, 0), (shuffled, 2), (pieces[-1].tets, 1)):
        dof_count = 3 * (int(mesh.max()) + 1 + spare)         # nodes no element uses, too
        new, old = _csr_pattern(mesh, dof_count), _pattern_of_every_dof_pair(mesh, dof_count)
        for a, b in zip(new, old):
            assert a.dtype == b.dtype and np.array_equal(a, b)
    if order == 1:
        for mesh in (tets, shuffled, pieces[0].tets, pieces[-1].tets):
            assert np.array_equal(surface_triangles(mesh), _surface_by_rows(mesh))


def test_a_piece_without_interior_faces_is_not_checked_because_it_cannot_open():
    """apply_fracture skips bodies whose FractureModel cannot open (a lone tet): find_crack would
    cut nothing there whatever the stress, so skipping it changes no result."""
    _, _, pieces = _pieces(1)
    lone, whole = pieces[-1], pieces[0]
    assert len(lone.tet_index) == 1 and len(whole.tet_index) > 1
    for piece, opens in ((lone, False), (whole, True)):
        volume = np.abs(np.linalg.det(piece.points[piece.tets[:, 1:]]
                                      - piece.points[piece.tets[:, :1]])) / 6.0
        fracture = fracture_model(piece.tets, volume, 1.0e6)
        sigma = np.broadcast_to(np.diag([5.0e7, 0.0, 0.0]), (len(piece.tets), 3, 3))
        cut, found = find_crack(fracture, piece.points, piece.tets, sigma)
        assert fracture.can_open == opens and (len(cut) > 0) == opens
        assert len(found.element) > 0 or not opens
