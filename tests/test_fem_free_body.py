"""Free elastic bodies: spin, rigid-motion invariance, stiff stability and energy."""
import numpy as np
import pytest

from fem.dynamics import (angular_momentum, elastic_energy, elastic_force, kinetic_energy,
                          linear_momentum, step, volume)
from fem.mesh import box_tet_mesh, select_nodes_in_box
from fem.model import build_fem_model, rest_state
from rigid.quaternion import from_rotation_vector, to_matrix


@pytest.mark.parametrize("frame", ["floating", "corotated"])
def test_spinning_cube_keeps_volume_and_angular_momentum(frame):
    points, tets = box_tet_mesh((0.2, 0.2, 0.2), 2)
    model = build_fem_model(points, tets, density=1000.0, young=1e6, poisson=0.3, frame=frame)
    omega = np.array([0.0, 0.0, 10.0])
    state = rest_state(model, v=np.cross(omega, points))
    L0, V0 = angular_momentum(model, state), volume(model, state.x)
    dt = 0.005
    worst_volume = worst_momentum = 0.0
    for _ in range(int(5.0 / dt)):
        state = step(model, state, dt)
        worst_volume = max(worst_volume, abs(volume(model, state.x) / V0 - 1))
        worst_momentum = max(worst_momentum, abs(np.linalg.norm(angular_momentum(model, state))
                                                 / np.linalg.norm(L0) - 1))
    print(f"{frame}: max volume error {worst_volume:.2e}, max |L| error {worst_momentum:.2e}")
    assert worst_volume < 0.01
    assert worst_momentum < 0.01
    # the vector L is conserved too (the lumped cube is not exactly isotropic, so it may wobble)
    np.testing.assert_allclose(angular_momentum(model, state), L0, atol=0.01 * np.linalg.norm(L0))
    if frame == "floating":
        assert model.factor_cache.factor_count == 1


@pytest.mark.parametrize("frame", ["floating", "corotated"])
@pytest.mark.parametrize("order", [1, 2])
def test_rigidly_moved_body_feels_no_elastic_force(frame, order):
    points, tets = box_tet_mesh((0.3, 0.2, 0.1), 3)
    model = build_fem_model(points, tets, order=order, density=1000.0, young=1e7, poisson=0.3,
                            frame=frame)
    Q = to_matrix(from_rotation_vector(np.array([0.9, -1.7, 2.3])))
    x = model.rest_points @ Q.T + [1.0, -2.0, 0.5]
    state = rest_state(model, x=x)
    scale = model.young * 0.1 * 0.1  # force of a unit strain over a face (N)
    assert np.abs(elastic_force(model, state)).max() < 1e-9 * scale
    assert elastic_energy(model, state) < 1e-12 * scale * 0.1
    # a small stretch is not invisible: the test can fail
    stretched = rest_state(model, x=(model.rest_points * [1.01, 1, 1]) @ Q.T)
    assert np.abs(elastic_force(model, stretched)).max() > 1e-4 * scale


def test_floating_frame_factorises_once_while_tumbling():
    points, tets = box_tet_mesh((0.3, 0.2, 0.1), 2)
    model = build_fem_model(points, tets, density=1000.0, young=1e6, poisson=0.3, dt=0.01)
    state = rest_state(model, v=np.cross([3.0, 5.0, 1.0], points) + [0.0, 0.0, 1.0])
    for _ in range(50):
        state = step(model, state, 0.01, gravity=(0, 0, -9.81))
    assert model.factor_cache.factor_count == 1
    # gravity is the only external force: momentum changes by m g t
    np.testing.assert_allclose(linear_momentum(model, state),
                               model.node_mass.sum() * np.array([0, 0, 1.0 - 9.81 * 0.5]), rtol=1e-9,
                               atol=1e-9)


def energy(model, state):
    return kinetic_energy(model, state) + elastic_energy(model, state)


def run_energy(model, state, dt, steps):
    E0 = energy(model, state)
    history = []
    for _ in range(steps):
        state = step(model, state, dt)
        history.append(energy(model, state))
        assert np.all(np.isfinite(state.x))
    return E0, np.array(history), state


@pytest.mark.parametrize("integrator", ["backward_euler", "newmark"])
def test_stiff_steel_beam_at_large_step_is_stable_and_never_gains_energy(integrator):
    points, tets = box_tet_mesh((1.0, 0.1, 0.1), (10, 1, 1))
    points = points + [0.5, 0, 0]
    clamp = select_nodes_in_box(points, [-1, -1, -1], [0, 1, 1])
    model = build_fem_model(points, tets, order=2, density=7800.0, young=2e11, poisson=0.3,
                            integrator=integrator, anchors=[(clamp, [0, 0, 0])])
    # released from a bent shape: u_z = a x^2 (a 2 mm tip deflection)
    x = model.rest_points + np.outer(0.002 * model.rest_points[:, 0] ** 2, [0, 0, 1])
    E0, history, state = run_energy(model, rest_state(model, x=x), 0.01, 100)
    print(f"steel beam {integrator}: max E/E0 {history.max() / E0:.6f}, final {history[-1] / E0:.3e}")
    assert history.max() <= 1.01 * E0
    assert np.abs(state.x - model.rest_points).max() < 0.01


@pytest.mark.parametrize("frame,integrator,spin", [("floating", "backward_euler", 5.0),
                                                   ("corotated", "backward_euler", 5.0),
                                                   ("floating", "newmark", 0.0)])
def test_rubber_block_at_large_step_is_stable_and_never_gains_energy(frame, integrator, spin):
    points, tets = box_tet_mesh((0.3, 0.2, 0.2), 3)
    model = build_fem_model(points, tets, density=1100.0, young=1e6, poisson=0.45, frame=frame,
                            integrator=integrator)
    rng = np.random.default_rng(1)
    x = points * [1.05, 0.97, 1.0] + 0.002 * rng.standard_normal(points.shape)
    state = rest_state(model, x=x, v=np.cross([0, spin, 0], points))
    E0, history, state = run_energy(model, state, 0.01, 100)
    print(f"rubber {frame} {integrator}: max E/E0 {history.max() / E0:.6f}")
    assert history.max() <= 1.01 * E0
