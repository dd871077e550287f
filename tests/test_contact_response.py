"""The Delassus blocks of a deformable body equal the blocks of its inverse system matrix, however
the contact set grows and whatever the caches had to forget."""
import numpy as np
import pytest

from fem import contact_response as cr
from fem.dynamics import system_matrix
from fem.mesh import box_tet_mesh
from fem.model import build_fem_model

DT = 1e-3


def _model():
    points, tets = box_tet_mesh((0.3, 0.2, 0.1), (6, 4, 2))
    return build_fem_model(points, tets, density=1000.0, young=1e6, poisson=0.3)


def _dense(rows):
    """(k, k, 3, 3) from the solver's block rows (dropped blocks are zero)."""
    ptr, col, blocks = rows
    k = len(ptr) - 1
    W = np.zeros((k, k, 3, 3))
    for l in range(k):
        W[l, col[ptr[l]:ptr[l + 1]]] = blocks[ptr[l]:ptr[l + 1]]
    return W


def _exact(model, nodes):
    inverse = np.linalg.inv(system_matrix(model, DT).toarray())
    dofs = (3 * np.asarray(nodes)[:, None] + np.arange(3)).ravel()
    k = len(nodes)
    return inverse[np.ix_(dofs, dofs)].reshape(k, 3, k, 3).transpose(0, 2, 1, 3)


def _check(model, nodes):
    W, exact = _dense(cr.delassus_block(model, DT, np.asarray(nodes))), _exact(model, nodes)
    kept = np.abs(W).sum(axis=(2, 3)) > 0
    scale = np.abs(exact).max()
    np.testing.assert_allclose(W[kept], exact[kept], rtol=0, atol=1e-10 * scale)
    # a dropped block is negligible against its nodes' own response (DROP_TOL)
    assert np.abs(exact[~kept]).max(initial=0.0) <= 10 * cr.DROP_TOL * scale


@pytest.mark.parametrize("tight", [False, True])
def test_growing_and_moving_contact_sets_give_the_inverse_system_blocks(monkeypatch, tight):
    if tight:   # caches too small to keep anything beyond the current set
        monkeypatch.setattr(cr, "MAX_BLOCK_BYTES", 1.0)
        monkeypatch.setattr(cr, "MAX_COLUMN_BYTES", 1.0)
        monkeypatch.setattr(cr, "BATCH_BYTES", 1.0)     # one node per batch
    model = _model()
    rng = np.random.default_rng(3)
    nodes = np.sort(rng.choice(model.node_count, 12, replace=False))
    _check(model, nodes)
    grown = np.union1d(nodes, rng.choice(model.node_count, 5, replace=False))
    _check(model, grown)                                     # a patch that creeps
    moved = np.sort(rng.choice(model.node_count, 9, replace=False))
    _check(model, moved)                                     # a patch elsewhere
    cache = model.cache.response
    if tight:
        assert set(cache.known.tolist()) == set(moved.tolist())
        assert not cache.columns
    else:
        assert set(cache.known.tolist()) == set(np.union1d(grown, moved).tolist())


def test_impulses_apply_the_same_through_columns_or_a_solve(monkeypatch):
    model = _model()
    nodes = np.array([3, 17, 40, 41])
    cr.delassus_block(model, DT, nodes)
    impulse = np.random.default_rng(0).standard_normal((4, 3))
    by_product = cr.impulse_response(model, DT, nodes, impulse)
    assert by_product is not None
    A = system_matrix(model, DT).toarray()
    j = np.zeros((model.node_count, 3))
    j[nodes] = impulse
    np.testing.assert_allclose(by_product.ravel(), np.linalg.solve(A, j.ravel()), rtol=0,
                               atol=1e-10 * np.abs(by_product).max())


def test_a_long_column_solve_reports_its_progress(monkeypatch):
    monkeypatch.setattr(cr, "BATCH_BYTES", 1.0)
    monkeypatch.setattr(cr, "REPORT_EVERY", 0.0)
    model = _model()
    heard = []
    cr.delassus_block(model, DT, np.arange(6), report=heard.append)
    assert len(heard) == 5              # after every batch but the last
    assert "6 new contact nodes: 1 solved" in heard[0]


def test_a_place_between_nodes_moves_with_them_and_pushes_them_by_its_weights():
    """In the contact solver a place (a surface point between three nodes) has the weighted sum of
    their velocities, and an impulse on it acts on them in those proportions: solving one contact
    that asks the place to move at 0.5 m/s gives the nodes exactly the body's response to the
    shared impulse."""
    from rigid.solver import pgs
    model = _model()
    nodes = np.array([3, 17, 40])
    weights = np.array([0.2, 0.3, 0.5])
    ptr, col, blocks = cr.delassus_block(model, DT, nodes, scale=0.5)
    n = 4                                   # three particles, then the place
    v, w = np.zeros((n, 3)), np.zeros((n, 3))
    corner = np.array([[-1, -1, -1]] * 3 + [[0, 1, 2]])
    corner_w = np.vstack([np.zeros((3, 3)), weights])
    normal = np.array([[0.3, -0.2, 0.9]]) / np.linalg.norm([0.3, -0.2, 0.9])
    impulse = pgs(np.array([3]), np.array([-1]), np.zeros((1, 3)), np.zeros((1, 3)), normal,
                  np.array([0.5]), np.array([0.0]), np.ones(1), np.ones(1), np.ones(1, bool),
                  np.zeros((1, 3)), np.zeros(n), np.zeros((n, 3, 3)), v, w, 50,
                  np.zeros(n, np.int64), np.eye(3)[None], np.append(ptr, ptr[-1]), col, blocks,
                  corner, corner_w, False)[0]
    inverse = np.linalg.inv(system_matrix(model, DT).toarray())
    dofs = (3 * nodes[:, None] + np.arange(3)).ravel()
    expected = 0.5 * inverse[np.ix_(dofs, dofs)] @ np.kron(weights, impulse)
    np.testing.assert_allclose(v[:3].ravel(), expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    assert np.isclose(weights @ v[:3] @ normal[0], 0.5, rtol=1e-9)


def test_place_lying_on_an_anchored_node_is_held_and_takes_no_impulse():
    """Crack faces at a grip: an anchored node meets a place of another fragment that lies on an
    anchored node of its own (weight 1 there, round-off on its free corners). The place moves with
    its held corner and answers nothing; with the round-off weights it met a response of 1e-30 and
    took an impulse of 1e9 N s (the grip's anchor force read 1e13 N)."""
    from hybrid.coupling.problem import Particles, stack_rows
    from rigid.contacts import Contacts
    from rigid.step import ContactSettings, SolverBodies, resolve_contacts
    W = np.zeros((4, 4, 3, 3))
    W[1, 1] = W[2, 2] = 10.0 * np.eye(3)               # nodes 0 and 3 anchored: no response
    rows = [cr.sparse_rows(W)]
    parts = Particles(nodes=np.arange(4), corners=np.array([[0, 1, 2]]),
                      weights=np.array([[1.0, 3e-17, 0.0]]), node_body=np.zeros(4, np.int64))
    none = SolverBodies(*(np.zeros((0, 3, 3)) if name == "inv_inertia" else np.zeros(0, bool)
                          if name == "static" else np.zeros(0) if name == "inv_mass" else np.zeros((0, 3))
                          for name in ("inv_mass", "inv_inertia", "position", "velocity", "velocity_at_t",
                                       "angular", "accel", "static")))
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0]])
    v = np.array([[0.0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, -1e-3]])      # node 3 closing on node 0
    bodies = parts.solver_bodies(none, stack_rows(rows, 0), [np.eye(3)], x, v)
    assert bodies.static[3] and bodies.static[4]
    contacts = Contacts(np.array([3]), np.array([4]), np.zeros((1, 3)), np.array([[0.0, 0, 1]]),
                        np.array([0.0]), np.array([0.5]), np.array([0.0]))
    res = resolve_contacts(bodies, contacts, 1e-3, np.zeros(3), ContactSettings())
    assert np.abs(res.contact_impulse).max() < 1e-12


def test_contact_set_keeps_the_previous_set_only_when_given_it():
    """Resting contact flickers a node in and out of the margin: given the previous set, the
    solver keeps it (or grows it by the new node); without one, the set is the touched nodes. The
    answer depends on the arguments alone, whatever was asked before."""
    model = _model()
    touched = np.array([9, 3, 5, 3])
    first = cr.contact_set(model, DT, touched)
    np.testing.assert_array_equal(first, [3, 5, 9])
    np.testing.assert_array_equal(cr.contact_set(model, DT, [3, 9], previous=first), [3, 5, 9])
    np.testing.assert_array_equal(cr.contact_set(model, DT, [3, 9, 11], previous=first), [3, 5, 9, 11])
    np.testing.assert_array_equal(cr.contact_set(model, DT, [3, 9]), [3, 9])
    # a patch that has moved on: with the previous set it would be far larger (over 1.5 k + 8)
    np.testing.assert_array_equal(cr.contact_set(model, DT, [40, 41], previous=np.arange(30)), [40, 41])
