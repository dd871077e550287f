"""Element stresses in one compiled pass (hybrid.app.peaks.element_strains: the run's stress peaks
and the frames' fields): against fem.stress.element_stress (numpy) on random deformed states,
both frames, P1 and P2, with and without plastic strain."""
import numpy as np
import pytest

from fem.mesh import box_tet_mesh
from fem.model import build_fem_model, rest_state
from fem.plasticity import elastic_stress
from fem.stress import element_stress, principal_stress_max, von_mises
from hybrid.app.observe import tet_fields
from hybrid.app.peaks import element_strains, strain_tensors


@pytest.mark.parametrize("frame", ["floating", "corotated"])
@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("plastic", [False, True])
def test_peak_stresses_match_the_element_stresses(frame, order, plastic):
    rng = np.random.default_rng(order + 2 * plastic)
    points, tets = box_tet_mesh((0.2, 0.1, 0.1), 6)
    m = build_fem_model(points, tets, order=order, density=1000, young=1e6, poisson=0.3, frame=frame,
                        yield_stress=1e5 if plastic else None)
    # turned, far from the origin, and deformed by about 3% strain
    turn = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    turn *= np.sign(np.linalg.det(turn))
    x = (m.rest_points + 0.003 * rng.normal(size=m.rest_points.shape)) @ turn.T + 100.0
    s = rest_state(m, x)
    if plastic:
        eps_p = 1e-3 * rng.normal(size=s.tet_plastic_strain.shape)
        s = s.replace(tet_plastic_strain=0.5 * (eps_p + np.swapaxes(eps_p, -1, -2)))
    sigma = element_stress(m, s, s.tet_plastic_strain)
    e, vm, mean, _ = element_strains(m, s)
    rows = np.arange(0, m.tet_count, 5)
    scale = np.abs(sigma).max()
    assert scale > 1e3
    np.testing.assert_allclose(vm, von_mises(sigma), rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(mean, np.trace(sigma, axis1=1, axis2=2) / 3.0, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(elastic_stress(strain_tensors(e[rows]), 0.0, m.mu, m.lam), sigma[rows],
                               rtol=0, atol=1e-9 * scale)
    # the frames' cell fields come from the same pass
    fields = tet_fields(m, s)
    np.testing.assert_allclose(fields["von_mises"], von_mises(sigma), rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(fields["principal_stress"], principal_stress_max(sigma), rtol=0, atol=1e-9 * scale)
    # as the run's writer computes it (the frame hands over the strain rows)
    deferred = tet_fields(m, s, deferred=True)["principal_stress"]
    assert len(deferred) == m.tet_count
    np.testing.assert_array_equal(deferred.value(), fields["principal_stress"])
