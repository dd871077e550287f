"""The compiled gather and scatter of fem.plastic_flow against a direct formulation on the element
data, for P1 (one quadrature point per element) and P2 (several)."""
import numpy as np
import pytest

from fem.mesh import box_tet_mesh
from fem.model import build_fem_model
from fem.plastic_flow import nodal_force, node_field_gradient


@pytest.fixture(scope="module", params=[1, 2], ids=["P1", "P2"])
def model(request):
    points, tets = box_tet_mesh((1.0, 0.5, 0.5), (4, 2, 2))
    return build_fem_model(points, tets, order=request.param, density=2700.0, young=70e9,
                           poisson=0.3, yield_stress=1e6)


def test_node_field_gradient_is_the_gradient_at_every_quadrature_point(model):
    e = model.elements
    v = np.random.default_rng(0).standard_normal((model.node_count, 3))
    expected = np.einsum("tai,tqaj->ijtq", v[e.tet_nodes], e.tet_gradients)
    H = node_field_gradient(model, v)
    assert H.shape == (3, 3, e.tet_weights.size)
    np.testing.assert_allclose(H, expected.reshape(H.shape), rtol=0, atol=1e-12 * np.abs(expected).max())


def test_nodal_force_scatters_weighted_tensor_times_gradient_and_is_the_adjoint_of_the_gradient(model):
    e = model.elements
    t, q = e.tet_weights.shape
    rng = np.random.default_rng(1)
    tau = rng.standard_normal((3, 3, t * q))                         # not symmetric
    points = np.flatnonzero(rng.random(t * q) < 0.5)
    for at in (None, points):
        k = np.arange(t * q) if at is None else at
        tau_k = np.ascontiguousarray(tau[..., k])
        per_node = np.einsum("k,ijk,kaj->kai", e.tet_weights.ravel()[k], tau_k,
                             e.tet_gradients.reshape(t * q, -1, 3)[k])
        expected = np.zeros((model.node_count, 3))
        np.add.at(expected, e.tet_nodes[k // q], per_node)
        f = nodal_force(model, tau_k, at)
        np.testing.assert_allclose(f, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    # virtual work: sum_n f_n . v_n = sum_k w_k tau_k : grad v (x_k)
    v = rng.standard_normal((model.node_count, 3))
    work = np.einsum("k,ijk,ijk->", e.tet_weights.ravel(), tau, node_field_gradient(model, v))
    assert np.sum(nodal_force(model, tau) * v) == pytest.approx(work, rel=1e-12)
