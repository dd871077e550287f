"""A corotated body whose CG solve does not converge takes the step by a direct solve of the same
warped system: the same step the `lu` setting takes."""
import numpy as np

import fem.system as system
from fem import dynamics as fem_dyn
from fem.mesh import box_tet_mesh
from fem.model import build_fem_model, rest_state


def _bent_step(corotated_solver, monkeypatch=None):
    points, tets = box_tet_mesh((0.4, 0.05, 0.05), 0.025)
    model = build_fem_model(points, tets, density=1000, young=1e6, poisson=0.3, frame="corotated",
                            corotated_solver=corotated_solver,
                            anchors=[(points[:, 0] < -0.19, (0.0, 0.0, 0.0))])
    x = points.copy()
    x[:, 2] += 0.5 * (x[:, 0] + 0.2) ** 2            # bent well away from the rest shape
    state = rest_state(model, x)
    return fem_dyn.step(model, state, 1e-3, gravity=(0, 0, -9.81))


def test_a_corotated_step_whose_cg_fails_is_solved_directly(monkeypatch):
    expected = _bent_step("lu")

    def fails(*args, **kwargs):
        raise RuntimeError("CG did not converge in 500 iterations")

    monkeypatch.setattr(system, "cg_solve", fails)
    got = _bent_step("cg")
    assert np.allclose(got.v, expected.v, rtol=1e-9, atol=1e-12)
    assert np.allclose(got.x, expected.x, rtol=1e-12, atol=1e-15)
