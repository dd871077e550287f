"""Fracture: principal-stress criterion, stress smoothing, crack faces, mesh splitting.

These are the functions the simulator's fracture event runs (hybrid.coupling.fracture calls
fem.fracture.find_crack and fem.split.split_mesh / split_bodies)."""

import numpy as np
import pytest
import scipy.sparse as sp
import skfem

from fem.fracture import (crack_faces, face_neighbours, find_crack, fracture_candidates,
                          fracture_model, smooth_stress, smoothing_operator, tearing_candidates)
from fem.mesh import quadratic_tets, tet_signed_volumes
from fem.split import (components, lumped_mass_from_elements, lumped_mass_p1,
                       split_bodies, split_mesh, tet_faces, transfer_node_state)

STRENGTH = 3.0e6  # Pa


def bar_mesh(cells=(4, 1, 1), size=(4.0, 1.0, 1.0), jitter=0.0, seed=0):
    """Box tet mesh (skfem, 6 tets per cube), all tets right-handed; optional interior jitter."""
    axes = [np.linspace(0.0, s, c + 1) for c, s in zip(cells, size)]
    mesh = skfem.MeshTet.init_tensor(*axes)
    points, tets = mesh.p.T.copy(), mesh.t.T.copy()
    flip = tet_signed_volumes(points, tets) < 0
    tets[flip, 2], tets[flip, 3] = tets[flip, 3], tets[flip, 2].copy()
    if jitter:
        rng = np.random.default_rng(seed)
        inside = np.all((points > 1e-9) & (points < np.array(size) - 1e-9), axis=1)
        points[inside] += jitter * rng.uniform(-1, 1, (inside.sum(), 3))
    return points, tets


def random_rotations(count, rng):
    q, r = np.linalg.qr(rng.normal(size=(count, 3, 3)))
    q *= np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    return q * np.sign(np.linalg.det(q))[:, None, None]


def plane_faces(points, tets, axis=0, value=2.0):
    """Interior face triples lying on the plane x_axis = value."""
    faces = tet_faces(tets)
    on_plane = np.all(np.isclose(points[faces.face_vertices, axis], value), axis=1)
    return faces.face_vertices[on_plane & faces.interior]


def sides(points, tets, axis=0, value=2.0):
    centroid = points[tets[:, :4]].mean(axis=1)[:, axis]
    return centroid < value, centroid > value


def opened_faces(points, tets, element, normal):
    """Vertex triples of the faces the cracking elements open (each face once)."""
    faces = tet_faces(tets)
    face = crack_faces(points, tets, element, normal, faces).face
    return faces.face_vertices[np.unique(face[face >= 0])]


def p1_mass(points, tets, density):
    return lumped_mass_p1(tets, tet_signed_volumes(points, tets), density, len(points))


def momenta(points, mass, velocity):
    return (mass.sum(), mass @ velocity,
            np.cross(points, mass[:, None] * velocity).sum(axis=0))


# --- 1. criterion -------------------------------------------------------------------

def uniaxial(stress, axis):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return stress * np.outer(axis, axis)


def test_uniaxial_tension_just_above_strength_cracks_perpendicular_to_load():
    rng = np.random.default_rng(1)
    axes = rng.normal(size=(20, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    sigma = np.stack([uniaxial(1.001 * STRENGTH, a) for a in axes])
    found = fracture_candidates(sigma, STRENGTH)
    assert np.array_equal(np.sort(found.element), np.arange(20))
    aligned = np.abs(np.einsum("ki,ki->k", found.normal, axes[found.element]))
    assert np.all(aligned > 0.999)
    assert np.allclose(found.principal_stress, 1.001 * STRENGTH)


def test_uniaxial_tension_just_below_strength_does_not_crack():
    sigma = np.stack([uniaxial(0.999 * STRENGTH, a) for a in np.eye(3)])
    assert fracture_candidates(sigma, STRENGTH).element.size == 0


@pytest.mark.parametrize("pressure", [1.0, 1e3 * STRENGTH, 1e12 * STRENGTH])
def test_hydrostatic_compression_of_any_size_never_cracks(pressure):
    sigma = np.stack([-pressure * np.eye(3), uniaxial(-pressure, [1, 2, 3])])
    assert fracture_candidates(sigma, STRENGTH).element.size == 0


def test_criterion_is_invariant_under_rotation_of_the_stress():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(500, 3, 3)) * STRENGTH
    sigma = a + np.swapaxes(a, 1, 2)
    rotation = random_rotations(500, rng)
    rotated = rotation @ sigma @ np.swapaxes(rotation, 1, 2)
    base, turned = fracture_candidates(sigma, STRENGTH), fracture_candidates(rotated, STRENGTH)
    assert 0 < base.element.size < 500
    assert np.array_equal(np.sort(base.element), np.sort(turned.element))
    order = np.argsort(turned.element)
    normal_turned = turned.normal[order]
    expected = np.einsum("kij,kj->ki", rotation[np.sort(base.element)],
                         base.normal[np.argsort(base.element)])
    assert np.all(np.abs(np.einsum("ki,ki->k", normal_turned, expected)) > 1 - 1e-8)


def test_max_cracks_keeps_the_most_overstressed_and_unbreakable_never_cracks():
    level = STRENGTH * np.array([1.5, 3.0, 0.5, 2.0, 4.0])
    sigma = np.stack([uniaxial(s, [0, 0, 1]) for s in level])
    assert np.array_equal(fracture_candidates(sigma, STRENGTH).element, [4, 1, 3, 0])
    assert np.array_equal(fracture_candidates(sigma, STRENGTH, max_cracks=2).element, [4, 1])
    unbreakable = np.array([False, True, False, False, False])
    assert np.array_equal(
        fracture_candidates(sigma, STRENGTH, unbreakable=unbreakable).element, [4, 3, 0])
    # Per-element strength: element 4 is the strongest material and does not crack.
    per_element = np.full(5, STRENGTH)
    per_element[4] = 5 * STRENGTH
    assert np.array_equal(fracture_candidates(sigma, per_element).element, [1, 3, 0])


def test_tearing_needs_plastic_strain_past_the_limit_while_the_element_flows():
    axes = ([0, 0, 1], [1, 0, 0], [0, 1, 1], [0, 0, 1])
    sigma = np.stack([uniaxial(0.5 * STRENGTH, a) for a in axes])
    peeq = np.array([0.06, 0.04, 0.08, 0.07])
    flowing = np.array([True, True, False, True])
    # element 1 is below the tearing strain, element 2 has stopped flowing (unloaded): neither
    # tears; the most strained first, across the largest principal stress
    found = tearing_candidates(sigma, peeq, flowing, 0.05)
    assert np.array_equal(found.element, [3, 0])
    assert np.allclose(np.abs(found.normal[:, 2]), 1.0)
    assert np.allclose(found.principal_stress, 0.5 * STRENGTH)
    unbreakable = np.array([False, False, False, True])
    assert np.array_equal(tearing_candidates(sigma, peeq, flowing, 0.05, unbreakable).element, [0])


# --- 2. smoothing -------------------------------------------------------------------

def test_face_neighbours_are_tets_sharing_three_vertices():
    points, tets = bar_mesh((3, 2, 2), (3.0, 2.0, 2.0))
    shared = (tets[:, None, :, None] == tets[None, :, None, :]).sum(axis=(2, 3))
    expected = (shared == 3).astype(float)
    assert (face_neighbours(tets) != sp.csr_matrix(expected)).nnz == 0


def test_smoothing_leaves_a_uniform_stress_unchanged_and_weights_sum_to_one():
    points, tets = bar_mesh((4, 2, 2), (4.0, 2.0, 2.0), jitter=0.2)
    volume = tet_signed_volumes(points, tets)
    assert volume.min() > 0 and volume.std() > 0.05 * volume.mean()
    adjacency = face_neighbours(tets)
    weights = smoothing_operator(volume, adjacency)
    assert np.allclose(weights.sum(axis=1), 1.0, atol=1e-14)
    assert weights.min() >= 0.0
    rng = np.random.default_rng(3)
    a = rng.normal(size=(3, 3))
    uniform = np.broadcast_to(a + a.T, (tets.shape[0], 3, 3))
    assert np.allclose(smooth_stress(uniform, weights), uniform, atol=1e-13)


def test_a_stress_spike_spreads_only_to_face_neighbours_by_volume_weight():
    points, tets = bar_mesh((4, 2, 2), (4.0, 2.0, 2.0), jitter=0.2)
    volume = tet_signed_volumes(points, tets)
    adjacency = face_neighbours(tets)
    neighbour_count = np.asarray(adjacency.sum(axis=1)).ravel()
    spike = int(np.flatnonzero(neighbour_count == 4)[0])
    sigma = np.zeros((tets.shape[0], 3, 3))
    sigma[spike] = np.eye(3)
    smoothed = smooth_stress(sigma, smoothing_operator(volume, adjacency))[:, 0, 0]
    reached = np.flatnonzero(smoothed != 0.0)
    stencil = np.append(adjacency[spike].indices, spike)
    assert np.array_equal(np.sort(reached), np.sort(stencil))
    for e in reached:  # a handful of elements: closed form of the weight
        neighbourhood = np.append(adjacency[e].indices, e)
        assert np.isclose(smoothed[e], volume[spike] / volume[neighbourhood].sum(), rtol=1e-13)


# --- 3. splitting -------------------------------------------------------------------

@pytest.mark.parametrize("cells,size", [((4, 1, 1), (4.0, 1.0, 1.0)),
                                        ((6, 2, 2), (4.0, 2.0, 2.0))])
def test_cut_through_the_mid_plane_splits_the_bar_in_two_conserving_momentum(cells, size):
    points, tets = bar_mesh(cells, size)
    cut = plane_faces(points, tets, 0, 2.0)
    assert cut.shape[0] == 2 * cells[1] * cells[2]
    new_points, new_tets, origin = split_mesh(points, tets, cut)

    labels, count = components(new_tets, new_points.shape[0])
    assert count == 2
    left, right = sides(points, tets)
    assert len(set(labels[left])) == 1 and len(set(labels[right])) == 1
    # Every node of the plane, and only those, is duplicated once.
    plane_node_count = (cells[1] + 1) * (cells[2] + 1)
    assert new_points.shape[0] == points.shape[0] + plane_node_count
    assert np.all(np.isclose(points[origin[points.shape[0]:], 0], 2.0))
    # No node is used by tets on both sides, including tets touching the plane
    # only at an edge or a vertex.
    on_plane = np.isclose(points[tets, 0], 2.0).sum(axis=1)
    assert np.any(left & (on_plane == 1)) or np.any(left & (on_plane == 2))
    assert not set(new_tets[left].ravel()) & set(new_tets[right].ravel())
    # Same geometry: positions copied, volumes unchanged and positive.
    assert np.array_equal(new_points, points[origin])
    assert np.array_equal(tets, origin[new_tets])
    assert np.allclose(tet_signed_volumes(new_points, new_tets), tet_signed_volumes(points, tets))
    assert tet_signed_volumes(new_points, new_tets).min() > 0

    rng = np.random.default_rng(4)
    velocity = rng.normal(size=points.shape)
    points_offset = points + np.array([0.3, -1.2, 2.5])
    old = momenta(points_offset, p1_mass(points, tets, 7800.0), velocity)
    new_mass = p1_mass(new_points, new_tets, 7800.0)
    new = momenta(points_offset[origin], new_mass, transfer_node_state(origin, velocity))
    for before, after in zip(old, new):
        assert np.allclose(after, before, rtol=1e-12, atol=1e-12 * np.abs(before).max())


def test_a_cut_that_stops_inside_the_bar_keeps_one_piece_and_shares_the_crack_front():
    points, tets = bar_mesh((6, 2, 2), (4.0, 2.0, 2.0))
    cut = plane_faces(points, tets, 0, 2.0)
    half = points[cut, 1].mean(axis=1) < 1.0  # the half of the plane with y < 1
    new_points, new_tets, origin = split_mesh(points, tets, cut[half])
    assert components(new_tets, new_points.shape[0])[1] == 1
    # Nodes strictly behind the front (y = 0 on the plane) open; the front (y = 1) and
    # the uncut half stay shared.
    duplicated = points[origin[points.shape[0]:]]
    assert np.allclose(duplicated[:, [0, 1]], [2.0, 0.0])
    assert duplicated.shape[0] == 3


def test_split_bodies_gives_compact_fragments_that_tile_the_bar():
    points, tets = bar_mesh((6, 2, 2), (4.0, 2.0, 2.0))
    new_points, new_tets, origin = split_mesh(points, tets, plane_faces(points, tets))
    fragments = split_bodies(new_points, new_tets)
    assert len(fragments) == 2
    volume = [tet_signed_volumes(f.points, f.tets).sum() for f in fragments]
    assert np.allclose(volume, 8.0)
    for fragment in fragments:
        assert np.array_equal(np.unique(fragment.tets), np.arange(fragment.points.shape[0]))
        assert np.array_equal(fragment.points, new_points[fragment.node_index])
        assert np.array_equal(new_tets[fragment.tet_index], fragment.node_index[fragment.tets])
    assert np.array_equal(np.sort(np.concatenate([f.tet_index for f in fragments])),
                          np.arange(tets.shape[0]))


def test_quadratic_bar_cut_through_the_mid_plane_splits_edge_nodes_too():
    points1, tets1 = bar_mesh((4, 2, 2), (4.0, 2.0, 2.0))
    points, tets = quadratic_tets(points1, tets1)
    cut = plane_faces(points1, tets1, 0, 2.0)
    new_points, new_tets, origin = split_mesh(points, tets, cut, order=2)
    assert components(new_tets, new_points.shape[0])[1] == 2
    left, right = sides(points, tets)
    assert not set(new_tets[left].ravel()) & set(new_tets[right].ravel())
    # Each node on the plane (3x3 vertices and 16 edge midpoints) is duplicated once.
    plane_nodes = np.flatnonzero(np.isclose(points[:, 0], 2.0))
    assert plane_nodes.size == 9 + 16
    assert np.array_equal(np.sort(origin[points.shape[0]:]), plane_nodes)
    assert np.array_equal(new_points, points[origin])
    # Conservation holds for any per-element lumping.
    rng = np.random.default_rng(5)
    tet_node_mass = rng.uniform(0.1, 1.0, tets.shape)
    velocity = rng.normal(size=points.shape)
    old = momenta(points, lumped_mass_from_elements(tets, tet_node_mass, len(points)), velocity)
    new = momenta(new_points, lumped_mass_from_elements(new_tets, tet_node_mass, len(new_points)),
                  transfer_node_state(origin, velocity))
    for before, after in zip(old, new):
        assert np.allclose(after, before, rtol=1e-12, atol=1e-12 * np.abs(before).max())


# --- 4. crack faces -----------------------------------------------------------------

def test_crack_faces_under_tension_along_x_are_the_faces_most_normal_to_x():
    points, tets = bar_mesh((6, 2, 2), (4.0, 2.0, 2.0))
    faces = tet_faces(tets)
    element = np.arange(tets.shape[0])
    normal = np.tile([1.0, 0.0, 0.0], (tets.shape[0], 1))
    chosen = opened_faces(points, tets, element, normal)
    corner = points[chosen]
    face_normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    cosine = np.abs(face_normal[:, 0]) / np.linalg.norm(face_normal, axis=1)
    assert np.all(cosine >= np.cos(np.radians(45.0)) - 1e-12)
    # An element with an interior face on a plane x = const picks exactly that face.
    for e in (0, 7, 30):
        own = faces.face_vertices[faces.tet_face[e]]
        flat = np.all(np.isclose(points[own, 0], points[own[:, :1], 0]), axis=1)
        flat &= faces.interior[faces.tet_face[e]]
        mine = opened_faces(points, tets, [e], normal[:1])
        if flat.any():
            assert np.array_equal(mine, own[flat])
        else:
            assert mine.shape == (1, 3)


def test_tension_cracking_the_layer_at_mid_length_separates_the_bar():
    points, tets = bar_mesh((6, 2, 2), (4.0, 2.0, 2.0))
    sigma = np.broadcast_to(uniaxial(2 * STRENGTH, [1, 0, 0]), (tets.shape[0], 3, 3))
    volume = tet_signed_volumes(points, tets)
    # Layer = the tets with a face on x = 2 (both sides); the rest is unbreakable.
    touching = np.isclose(points[tets, 0], 2.0).sum(axis=1) == 3
    fracture = fracture_model(tets, volume, STRENGTH, tet_unbreakable=~touching)
    cut, found = find_crack(fracture, points, tets, sigma)
    cut = fracture.faces.face_vertices[cut]
    assert np.array_equal(np.sort(found.element), np.flatnonzero(touching))
    assert {tuple(f) for f in cut} == {tuple(f) for f in plane_faces(points, tets)}
    new_points, new_tets, _ = split_mesh(points, tets, cut)
    assert components(new_tets, new_points.shape[0])[1] == 2
    # A whole cell layer cracking cuts both of its planes: the ends come apart.
    centroid = points[tets].mean(axis=1)[:, 0]
    layer = (centroid > 2.0) & (centroid < 2.0 + 4.0 / 6)
    chosen = opened_faces(points, tets, np.flatnonzero(layer),
                          np.tile([1.0, 0, 0], (layer.sum(), 1)))
    new_points, new_tets, _ = split_mesh(points, tets, chosen)
    labels, count = components(new_tets, new_points.shape[0])
    assert count >= 2
    assert labels[np.argmin(centroid)] != labels[np.argmax(centroid)]


def test_max_cracks_limits_the_faces_opened_in_one_step():
    points, tets = bar_mesh((6, 2, 2), (4.0, 2.0, 2.0))
    sigma = np.broadcast_to(uniaxial(2 * STRENGTH, [1, 0, 0]), (tets.shape[0], 3, 3))
    fracture = fracture_model(tets, tet_signed_volumes(points, tets), STRENGTH, max_cracks=3)
    cut, found = find_crack(fracture, points, tets, sigma)
    assert found.element.size == 3
    assert 1 <= cut.shape[0] <= 3


def test_a_waiting_crack_grows_across_the_bar_check_after_check_where_its_front_is_most_stressed():
    """A crack inside a finely meshed bar waits to open until it reaches the surface, and the
    stress peaks at its front: every check took the most overstressed elements up to max_cracks,
    found their faces already waiting, chose nothing new, and the bar never broke while its load
    rose to 2.7 times its strength. The elements on the plane whose faces wait are passed over:
    each check adds faces of the plane until the crack crosses the bar and splits it in two."""
    points, tets = bar_mesh((6, 4, 4), (4.0, 2.0, 2.0))
    centroid = points[tets].mean(axis=1)
    # tension along x, highest at the middle of the section at x = 2 (a crack's front there)
    peak = 1.0 + 0.5 * np.exp(-np.sum((centroid - [2.0, 1.0, 1.0]) ** 2, axis=1))
    sigma = peak[:, None, None] * uniaxial(2 * STRENGTH, [1, 0, 0])
    fracture = fracture_model(tets, tet_signed_volumes(points, tets), STRENGTH, max_cracks=4)
    pending, checks = np.zeros(0, np.int64), 0
    while True:
        cut, _ = find_crack(fracture, points, tets, sigma, pending=pending)
        checks += 1
        assert len(cut) > len(pending), f"check {checks} chose nothing new with {len(pending)} faces waiting"
        new_points, new_tets, _ = split_mesh(points, tets, fracture.faces.face_vertices[cut])
        if components(new_tets, new_points.shape[0])[1] == 2:
            break
        pending = cut
        assert checks < 50
    # the crack it made is the plane at x = 2 (faces of one plane, the one the seed chose)
    opened = fracture.faces.face_vertices[cut]
    assert np.allclose(points[opened, 0], points[opened, 0].mean(), atol=0.7)
