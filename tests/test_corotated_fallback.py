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


def test_a_held_corotated_body_turned_from_its_rest_shape_is_preconditioned_in_its_frame():
    """A corotated box turned rigidly by 90 degrees and lying on its held bottom nodes (resting
    contact, fem.model.holding: it keeps its floating frame): its warped system is the rest system
    turned into its best-fit frame, so CG preconditioned by that turned rest system converges at
    once, and the step is the direct solve's (lu)."""
    from fem.model import holding
    from rigid import quaternion as quat
    points, tets = box_tet_mesh((0.2, 0.1, 0.1), 0.025)
    turn = quat.to_matrix(np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]))     # 90 deg about x
    x = points @ turn.T
    bottom = np.nonzero(x[:, 2] < x[:, 2].min() + 1e-9)[0]
    steps = {}
    for solver in ("cg", "lu"):
        model = build_fem_model(points, tets, density=1000, young=1e6, poisson=0.3, frame="corotated",
                                corotated_solver=solver)
        held = holding(model, bottom)
        state = rest_state(held, x)
        assert np.allclose(state.R, turn, atol=1e-12)
        steps[solver] = fem_dyn.predict(held, state, 1e-3, (0.0, 0.0, -9.81),
                                        held_velocity=np.zeros((len(bottom), 3)))
    assert steps["cg"].iterations[0] <= 2
    assert np.allclose(steps["cg"].v, steps["lu"].v, rtol=1e-8, atol=1e-12)
    assert np.abs(steps["cg"].v[bottom]).max() == 0.0
