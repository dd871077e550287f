"""The corotated body's step system: a CG solve that does not converge is replaced by a direct
solve of the same warped system (the step the `lu` setting takes); a held body turned from its rest
shape is preconditioned in its frame; the system built on the stiffness pattern is scipy's sum."""
import numpy as np
import pytest

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
    points, tets = box_tet_mesh((0.2, 0.1, 0.1), 8)
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


@pytest.mark.parametrize("mass, order", [("lumped", 1), ("consistent", 1), ("lumped", 2), ("consistent", 2)])
def test_warped_system_on_the_stiffness_pattern_is_the_sparse_sum(mass, order):
    """The step's warped system taken value by value on K's pattern (fem.system._warped_system)
    multiplies as ``a_M M + a_K K_R`` and its free block do, built by scipy's sum and slicing, bit
    for bit; for a free body and for a held variant."""
    from fem.warping import warped_assembly
    from fem.model import holding
    from rigid import quaternion as quat
    rng = np.random.default_rng(4)
    points, tets = box_tet_mesh((0.2, 0.1, 0.1), 6)
    model = build_fem_model(points, tets, order=order, density=1000, young=1e6, poisson=0.3,
                            frame="corotated", mass=mass, damping_mass=0.5, damping_stiffness=0.01)
    for m in (model, holding(model, np.arange(0, model.node_count, 7))):
        R = quat.to_matrix(quat.normalize(rng.normal(size=(m.tet_count, 4))))
        a_M, a_K = system.system_coefficients(m, 1e-3)
        A_sum = (a_M * m.M + a_K * warped_assembly(m.elements, R, 3 * m.node_count)).tocsr()
        K, A, A_ff = system._warped_system(m, 1e-3, R)
        x, y = rng.normal(size=A.shape[0]), rng.normal(size=A_ff.shape[0])
        np.testing.assert_array_equal(A @ x, A_sum @ x)
        np.testing.assert_array_equal(A_ff @ y, system._free_block(m, A_sum) @ y)


@pytest.mark.parametrize("order", [1, 2])
def test_deformation_gradients_match_numpy(order):
    """The element rotations' deformation gradients in one compiled pass
    (fem.rotations.deformation_gradients) against the batched numpy products ``Ds Dm^-1``."""
    from fem.rotations import deformation_gradients
    points, tets = box_tet_mesh((0.2, 0.1, 0.1), 6)
    m = build_fem_model(points, tets, order=order, density=1000, young=1e6, poisson=0.3, frame="corotated")
    x = m.rest_points + 0.01 * np.random.default_rng(order).normal(size=m.rest_points.shape) + 50.0
    xs = x[m.tets[:, :4]]
    expected = (xs[:, 1:] - xs[:, :1]).transpose(0, 2, 1) @ m.elements.tet_rest_inverse
    got = deformation_gradients(x, m.tets, m.elements.tet_rest_inverse)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-14)


def test_linear_tets_warp_from_their_gradients_as_from_their_blocks():
    """Linear tets warp their stiffness and forces from their four gradients and Lame parameters
    (fem.warping._warp_linear_into, _warped_linear_forces_into): the same values, forces and
    energy as the element blocks ``tet_stiffness`` give, to round-off, turned, deformed and far
    from the origin."""
    from dataclasses import replace
    from fem.rotations import tet_rotations
    from fem.warping import warped_energy, warped_forces, warped_values
    rng = np.random.default_rng(9)
    points, tets = box_tet_mesh((0.2, 0.1, 0.1), 6)
    m = build_fem_model(points, tets, density=1000, young=1e6, poisson=0.3, frame="corotated")
    assert m.elements.lame is not None
    blocks = replace(m.elements, lame=None)
    x = m.rest_points + 0.01 * rng.normal(size=m.rest_points.shape) + 30.0
    R = tet_rotations(m, x)
    v = warped_values(blocks, R)
    np.testing.assert_allclose(warped_values(m.elements, R), v, rtol=0, atol=1e-13 * np.abs(v).max())
    f = warped_forces(blocks, R, x, m.rest_points, m.node_count)
    np.testing.assert_allclose(warped_forces(m.elements, R, x, m.rest_points, m.node_count), f,
                               rtol=0, atol=1e-12 * np.abs(f).max())
    e = warped_energy(blocks, R, x, m.rest_points)
    assert e > 0 and warped_energy(m.elements, R, x, m.rest_points) == pytest.approx(e, rel=1e-12)
