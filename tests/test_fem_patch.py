"""Patch test, contact-impulse response and per-region reports."""
import numpy as np
import pytest

from fem.dynamics import (apply_impulse, finish, linear_momentum, predict,
                          effective_node_mass)
from fem.mesh import box_tet_mesh, select_nodes_in_box
from fem.model import build_fem_model, rest_state
from fem.static import static_displacement
from fem.stress import element_stress, principal_stress_max, quadrature_stress, von_mises

E, NU = 7e10, 0.33


@pytest.mark.parametrize("frame", ["floating", "corotated"])
@pytest.mark.parametrize("order", [1, 2])
def test_uniformly_stretched_block_has_uniaxial_stress_E_times_strain(order, frame):
    points, tets = box_tet_mesh((0.4, 0.2, 0.3), (3, 2, 2))
    # an anchor puts the body in the world frame; the static solve below replaces its constraint
    corner = select_nodes_in_box(points, [-1, -1, -1], [-0.2, -0.1, -0.15])
    model = build_fem_model(points, tets, order=order, density=2700.0, young=E, poisson=NU,
                            frame=frame, anchors=[(corner, [0, 0, 0])])
    X = model.rest_points
    strain = 1e-3
    # u_x = 0 on x = min, u_x = strain * length on x = max; one symmetry plane per lateral axis
    low, high = X[:, 0] == X[:, 0].min(), X[:, 0] == X[:, 0].max()
    ylow, zlow = X[:, 1] == X[:, 1].min(), X[:, 2] == X[:, 2].min()
    dofs = np.concatenate([3 * np.nonzero(low)[0], 3 * np.nonzero(high)[0],
                           3 * np.nonzero(ylow)[0] + 1, 3 * np.nonzero(zlow)[0] + 2])
    values = np.concatenate([np.zeros(low.sum()), np.full(high.sum(), strain * 0.4),
                             np.zeros(ylow.sum()), np.zeros(zlow.sum())])
    u = static_displacement(model, fixed_dofs=dofs, fixed_values=values)
    state = rest_state(model, x=X + u)
    expected = np.zeros((3, 3))
    expected[0, 0] = E * strain
    sigma = element_stress(model, state)
    np.testing.assert_allclose(sigma, np.broadcast_to(expected, sigma.shape), atol=1e-9 * E * strain)
    np.testing.assert_allclose(quadrature_stress(model, state),
                               np.broadcast_to(expected, model.elements.tet_gradients.shape[:2] + (3, 3)),
                               atol=1e-9 * E * strain)
    np.testing.assert_allclose(von_mises(sigma), E * strain, rtol=1e-9)
    np.testing.assert_allclose(principal_stress_max(sigma), E * strain, rtol=1e-9)
    # lateral contraction is Poisson's
    top = X[:, 1] == X[:, 1].max()
    np.testing.assert_allclose(u[top, 1] / (X[top, 1] - X[:, 1].min()), -NU * strain, rtol=1e-9)


@pytest.mark.parametrize("integrator", ["backward_euler", "newmark"])
def test_impulse_on_free_body_changes_momentum_by_the_impulse(integrator):
    points, tets = box_tet_mesh((0.3, 0.2, 0.2), 2)
    model = build_fem_model(points, tets, order=2, density=1000.0, young=1e6, poisson=0.3,
                            integrator=integrator)
    state = rest_state(model, v=np.cross([0.0, 0.0, 2.0], model.rest_points))
    dt = 0.01
    step = predict(model, state, dt, gravity=(0, 0, 0))
    p0 = linear_momentum(model, state)
    impulse = np.zeros_like(state.x)
    hit = model.surface_nodes[:5]
    impulse[hit] = [0.01, -0.02, 0.03]
    step = apply_impulse(model, state, step, impulse)
    # the momentum of the end-of-step velocities changes by exactly the impulse
    momentum = (model.M @ step.v.ravel()).reshape(-1, 3).sum(axis=0)
    np.testing.assert_allclose(momentum, p0 + impulse.sum(axis=0), atol=1e-12)
    # the struck nodes move towards the impulse; a node's response is below j / m_node
    dv = apply_impulse(model, state, step, impulse).v - step.v
    assert np.all(np.einsum("ij,ij->i", dv[hit], impulse[hit]) > 0)
    assert np.all(np.linalg.norm(dv[hit], axis=1)
                  <= np.linalg.norm(impulse[hit], axis=1) / effective_node_mass(model)[hit] + 1e-12)
    state = finish(model, state, step, dt)
    assert np.all(np.isfinite(state.x))


def test_anchored_nodes_do_not_respond_to_impulses():
    points, tets = box_tet_mesh((0.3, 0.1, 0.1), 3)
    wall = select_nodes_in_box(points, [-1, -1, -1], [-0.15, 1, 1])
    model = build_fem_model(points, tets, density=1000.0, young=1e6, poisson=0.3,
                            anchors=[(wall, [0.0, 0.1, 0.0])])
    state = rest_state(model)
    step = predict(model, state, 0.01)
    step = apply_impulse(model, state, step, np.ones_like(state.x))
    np.testing.assert_allclose(step.v[wall], np.tile([0.0, 0.1, 0.0], (len(wall), 1)))
    state = finish(model, state, step, 0.01)
    np.testing.assert_allclose(state.x[wall] - points[wall],
                               np.tile([0.0, 0.001, 0.0], (len(wall), 1)), atol=1e-15)
