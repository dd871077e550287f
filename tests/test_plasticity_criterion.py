"""Von Mises yield criterion and perfect-plastic return mapping checked against closed forms."""
import numpy as np
import pytest

from fem.plasticity import (
    capped_increment, deviatoric, elastic_stress, equivalent_plastic_strain, isotropic_stress,
    plastic_dissipation_increment, plastic_element_forces, plastic_nodal_forces, return_map,
    tet_shape_gradients, von_mises, yield_function,
)

# structural steel
E = 200e9
NU = 0.3
MU = E / (2 * (1 + NU))
LAM = E * NU / ((1 + NU) * (1 - 2 * NU))
Y = 250e6


def random_symmetric(rng, count, scale=1.0):
    a = rng.normal(size=(count, 3, 3)) * scale
    return 0.5 * (a + np.swapaxes(a, -1, -2))


def random_rotations(rng, count):
    q, r = np.linalg.qr(rng.normal(size=(count, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=-2, axis2=-1))[:, None, :]
    q[np.linalg.det(q) < 0, :, 0] *= -1.0
    return q


def random_deviatoric(rng, count, scale):
    return deviatoric(random_symmetric(rng, count, scale))


# ------------------------------------------------------------------------------------------------
# 1. Yield onset in the classical load cases
# ------------------------------------------------------------------------------------------------

def test_uniaxial_stress_yields_exactly_at_yield_stress():
    for sign in (1.0, -1.0):
        on = np.diag([sign * Y, 0.0, 0.0])
        assert abs(yield_function(on, Y)) <= 1e-12 * Y
        assert yield_function(on * (1 - 1e-9), Y) < 0
        assert yield_function(on * (1 + 1e-9), Y) > 0
        # the return map agrees: just inside is untouched, just outside comes back to sigma = Y
        below, above = on * (1 - 1e-9), on * (1 + 1e-9)
        _, sigma_below, _, yielded_below = return_map(below, np.zeros((3, 3)), MU, Y)
        assert not yielded_below and np.array_equal(sigma_below, below)
        _, sigma_above, gamma, yielded_above = return_map(above, np.zeros((3, 3)), MU, Y)
        assert yielded_above and gamma > 0
        assert abs(von_mises(sigma_above) - Y) <= 1e-12 * Y


def test_pure_shear_yields_at_yield_stress_over_sqrt3():
    tau = Y / np.sqrt(3.0)
    for i, j in ((0, 1), (1, 2), (0, 2)):
        shear = np.zeros((3, 3))
        shear[i, j] = shear[j, i] = tau
        assert abs(yield_function(shear, Y)) <= 1e-12 * Y
        assert yield_function(shear * (1 - 1e-9), Y) < 0
        assert yield_function(shear * (1 + 1e-9), Y) > 0


def test_hydrostatic_stress_of_any_magnitude_never_yields():
    pressure = np.concatenate([np.logspace(3, 12, 37), -np.logspace(3, 12, 37)])
    sigma = pressure[:, None, None] * np.eye(3)
    assert np.all(yield_function(sigma, Y) < 0)
    assert np.all(von_mises(sigma) <= 1e-15 * np.abs(pressure) * 10)
    # the return map leaves any pure pressure untouched
    eps_p = np.zeros_like(sigma)
    eps_p_new, sigma_new, gamma, yielded = return_map(sigma, eps_p, MU, Y)
    assert not yielded.any()
    assert np.array_equal(sigma_new, sigma) and np.array_equal(eps_p_new, eps_p)


def test_equibiaxial_stress_yields_at_yield_stress():
    on = np.diag([Y, Y, 0.0])
    assert abs(yield_function(on, Y)) <= 1e-12 * Y
    assert yield_function(on * (1 - 1e-9), Y) < 0
    assert yield_function(on * (1 + 1e-9), Y) > 0
    # a superposed pressure does not move the onset
    assert abs(yield_function(on + 7e9 * np.eye(3), Y)) <= 1e-6 * Y


# ------------------------------------------------------------------------------------------------
# 2. Invariance
# ------------------------------------------------------------------------------------------------

def test_von_mises_matches_principal_stress_formula():
    rng = np.random.default_rng(1)
    sigma = random_symmetric(rng, 500, 1e8)
    s1, s2, s3 = np.moveaxis(np.linalg.eigvalsh(sigma), -1, 0)
    principal = np.sqrt(((s1 - s2) ** 2 + (s2 - s3) ** 2 + (s3 - s1) ** 2) / 2)
    np.testing.assert_allclose(von_mises(sigma), principal, rtol=1e-12)


def test_von_mises_invariant_under_rotation():
    rng = np.random.default_rng(2)
    sigma = random_symmetric(rng, 500, 1e8)
    R = random_rotations(rng, 500)
    rotated = np.einsum('eij,ejk,elk->eil', R, sigma, R)
    np.testing.assert_allclose(von_mises(rotated), von_mises(sigma), rtol=1e-12)


def test_isotropic_stress_is_hookes_law_for_uniaxial_strain_state():
    # uniaxial stress sigma = diag(s,0,0) has strain diag(1, -nu, -nu) s / E
    s = 1e8
    eps = np.diag([1.0, -NU, -NU]) * s / E
    np.testing.assert_allclose(isotropic_stress(eps, MU, LAM), np.diag([s, 0, 0]), atol=1e-6)


# ------------------------------------------------------------------------------------------------
# 3. Return mapping
# ------------------------------------------------------------------------------------------------

def trial_state(rng, count, Y_element):
    """Total strains, old plastic strains and trial stresses, most of them beyond yield."""
    eps_p = random_deviatoric(rng, count, 1e-3)
    eps = eps_p + random_symmetric(rng, count, 1.0)
    # scale the elastic strain so the trial von Mises stress is 0.3..10 times the yield stress
    sigma = elastic_stress(eps, eps_p, MU, LAM)
    target = Y_element * rng.uniform(0.3, 10.0, size=count)
    eps = eps_p + (eps - eps_p) * (target / von_mises(sigma))[:, None, None]
    return eps, eps_p, elastic_stress(eps, eps_p, MU, LAM)


@pytest.mark.parametrize('per_element_yield', [False, True])
def test_return_map_puts_stress_on_yield_surface_with_associative_deviatoric_flow(per_element_yield):
    rng = np.random.default_rng(3)
    count = 400
    Y_element = Y * rng.uniform(0.5, 2.0, size=count) if per_element_yield else Y
    eps, eps_p, sigma_trial = trial_state(rng, count, Y_element)
    eps_p_new, sigma_new, gamma, yielded = return_map(sigma_trial, eps_p, MU, Y_element)
    Yb = np.broadcast_to(Y_element, (count,))

    assert 0 < yielded.sum() < count
    np.testing.assert_array_equal(yielded, yield_function(sigma_trial, Y_element) > 0)
    # on the surface after the update
    assert np.all(np.abs(yield_function(sigma_new[yielded], Yb[yielded])) < 1e-10 * Yb[yielded])
    # associative: the increment is along dev(sigma_trial), with length gamma
    d_eps_p = eps_p_new - eps_p
    direction = d_eps_p[yielded] / np.linalg.norm(d_eps_p[yielded], axis=(1, 2))[:, None, None]
    dev = deviatoric(sigma_trial[yielded])
    np.testing.assert_allclose(direction, dev / np.linalg.norm(dev, axis=(1, 2))[:, None, None],
                               atol=1e-10)
    np.testing.assert_allclose(np.linalg.norm(d_eps_p, axis=(1, 2)), gamma, rtol=1e-10, atol=0)
    assert np.all(gamma[yielded] > 0) and np.all(gamma[~yielded] == 0)
    # radial return: the deviatoric stress keeps its direction
    np.testing.assert_allclose(deviatoric(sigma_new[yielded]) / dev,
                               (np.sqrt(2 / 3) * Yb[yielded] / np.linalg.norm(dev, axis=(1, 2)))
                               [:, None, None] * np.ones((1, 3, 3)), rtol=1e-8)
    # plastic strain stays deviatoric, pressure is untouched
    assert np.all(np.abs(np.trace(eps_p_new, axis1=1, axis2=2)) < 1e-15)
    np.testing.assert_allclose(np.trace(sigma_new, axis1=1, axis2=2),
                               np.trace(sigma_trial, axis1=1, axis2=2), rtol=1e-12, atol=1e-3)
    # consistent with Hooke's law on the new elastic strain
    np.testing.assert_allclose(sigma_new, elastic_stress(eps, eps_p_new, MU, LAM),
                               rtol=0, atol=1e-9 * np.max(Yb))
    # inside the surface: bitwise unchanged
    assert np.array_equal(sigma_new[~yielded], sigma_trial[~yielded])
    assert np.array_equal(eps_p_new[~yielded], eps_p[~yielded])


def test_plastic_dissipation_is_gamma_times_yield_stress_and_positive():
    rng = np.random.default_rng(4)
    count = 200
    eps, eps_p, sigma_trial = trial_state(rng, count, Y)
    volume = rng.uniform(1e-9, 1e-6, size=count)
    eps_p_new, sigma_new, gamma, yielded = return_map(sigma_trial, eps_p, MU, Y)
    dissipated = plastic_dissipation_increment(sigma_new, eps_p_new - eps_p, volume)
    # sigma : n = |dev sigma|_F = sqrt(2/3) Y on the surface
    expected = np.sum(gamma * np.sqrt(2 / 3) * Y * volume)
    assert dissipated > 0
    assert dissipated == pytest.approx(expected, rel=1e-10)


def test_plastic_strain_cap_bounds_the_increments_by_the_room_left_and_keeps_their_direction():
    """The cap bounds the accumulated equivalent plastic strain (the frames' ``plastic_strain``):
    an increment is scaled to the room the cap leaves, its direction kept; an element at the cap
    (no room) flows no more."""
    rng = np.random.default_rng(5)
    d_eps_p = random_deviatoric(rng, 300, 1e-2)
    room = 0.5 * np.median(equivalent_plastic_strain(d_eps_p)) * np.ones(300)
    room[:20] = -1e-3                       # past the cap already: no flow
    capped = capped_increment(d_eps_p, room)
    assert np.all(equivalent_plastic_strain(capped) <= np.maximum(room, 0.0) * (1 + 1e-12))
    assert np.all(capped[:20] == 0.0)
    over = equivalent_plastic_strain(d_eps_p) > np.maximum(room, 0.0)
    assert 20 < over.sum() < len(d_eps_p)
    np.testing.assert_allclose(equivalent_plastic_strain(capped[over][20:]), room[over][20:], rtol=1e-12)
    np.testing.assert_allclose(capped[over][20:] * equivalent_plastic_strain(d_eps_p[over][20:])[:, None, None],
                               d_eps_p[over][20:] * room[over][20:, None, None], rtol=1e-10)
    assert np.array_equal(capped[~over], d_eps_p[~over])
    # uniaxial plastic flow e diag(1, -1/2, -1/2) has equivalent plastic strain |e|
    assert equivalent_plastic_strain(0.02 * np.diag([1, -0.5, -0.5])) == pytest.approx(0.02)

    # through the return map: the increment stays within the room and the stress is
    # C : (eps - eps_p_new)
    eps, eps_p0, sigma_trial = trial_state(rng, 300, Y)
    eps_p_new, sigma_new, gamma, yielded = return_map(sigma_trial, eps_p0, MU, Y, room=1e-3)
    assert np.all(equivalent_plastic_strain(eps_p_new - eps_p0) <= 1e-3 * (1 + 1e-12))
    np.testing.assert_allclose(sigma_new, elastic_stress(eps, eps_p_new, MU, LAM),
                               rtol=0, atol=1e-9 * Y)


# ------------------------------------------------------------------------------------------------
# 4. Uniaxial load-unload of one material point, and the P1 plastic force
# ------------------------------------------------------------------------------------------------

def uniaxial_stress_point(axial_strain, eps_p, lateral_guess):
    """Return-mapped state at axial strain with lateral strains chosen so lateral stresses vanish.

    Newton on the common lateral strain e (eps = diag(a, e, e); the plastic flow is axisymmetric,
    so sigma_22 = sigma_33) with a central-difference slope.
    """
    def lateral_stress(e):
        eps = np.diag([axial_strain, e, e])
        _, sigma, _, _ = return_map(elastic_stress(eps, eps_p, MU, LAM), eps_p, MU, Y)
        return sigma[1, 1]

    e = lateral_guess
    h = 1e-9
    for _ in range(30):
        residual = lateral_stress(e)
        if abs(residual) < 1e-10 * Y:
            break
        slope = (lateral_stress(e + h) - lateral_stress(e - h)) / (2 * h)
        e -= residual / slope
    eps = np.diag([axial_strain, e, e])
    eps_p_new, sigma, _, _ = return_map(elastic_stress(eps, eps_p, MU, LAM), eps_p, MU, Y)
    assert abs(sigma[1, 1]) < 1e-9 * Y and abs(sigma[2, 2]) < 1e-9 * Y
    return eps_p_new, sigma, e


def test_uniaxial_load_unload_plateaus_at_yield_and_leaves_residual_strain_eps_max_minus_Y_over_E():
    yield_strain = Y / E
    eps_max = 4 * yield_strain
    residual_expected = eps_max - yield_strain
    loading = np.linspace(0, eps_max, 41)[1:]
    unloading = np.linspace(eps_max, residual_expected - 0.5 * yield_strain, 31)[1:]

    eps_p = np.zeros((3, 3))
    lateral = 0.0
    axial_stress = []
    for a in np.concatenate([loading, unloading]):
        eps_p, sigma, lateral = uniaxial_stress_point(a, eps_p, lateral)
        axial_stress.append(sigma[0, 0])
    axial_stress = np.array(axial_stress)
    load_stress, unload_stress = axial_stress[:len(loading)], axial_stress[len(loading):]

    # elastic branch sigma = E eps, then a plateau at exactly Y
    elastic = loading < yield_strain * (1 - 1e-9)
    np.testing.assert_allclose(load_stress[elastic], E * loading[elastic], rtol=1e-8)
    plastic = loading > yield_strain * (1 + 1e-9)
    assert plastic.sum() > 20
    np.testing.assert_allclose(load_stress[plastic], Y, rtol=1e-10)
    # unloading is elastic with slope E (it goes into compression without yielding again)
    assert np.all(np.abs(unload_stress) < Y)
    slope, intercept = np.polyfit(unloading, unload_stress, 1)
    assert slope == pytest.approx(E, rel=1e-6)
    strain_at_zero_stress = -intercept / slope
    assert strain_at_zero_stress == pytest.approx(residual_expected, rel=1e-6)
    # the stored plastic strain is that residual strain, isochoric: diag(1, -1/2, -1/2) eps_res
    np.testing.assert_allclose(eps_p, residual_expected * np.diag([1, -0.5, -0.5]),
                               rtol=1e-6, atol=1e-9 * residual_expected)
    assert equivalent_plastic_strain(eps_p) == pytest.approx(residual_expected, rel=1e-6)


def test_tet_shape_gradients_reproduce_linear_fields_and_volume():
    rng = np.random.default_rng(6)
    points = rng.normal(size=(4 * 50, 3))
    tets = np.arange(4 * 50).reshape(50, 4)
    tets[::2] = tets[::2, [0, 2, 1, 3]]        # mixed orientation
    grad_n, volume = tet_shape_gradients(points, tets)
    x = points[tets]
    # sum_a x_a (x) grad N_a = I and sum_a grad N_a = 0: linear fields are interpolated exactly
    np.testing.assert_allclose(np.einsum('eai,eaj->eij', x, grad_n), np.broadcast_to(np.eye(3),
                               (50, 3, 3)), atol=1e-9)
    np.testing.assert_allclose(grad_n.sum(axis=1), 0, atol=1e-9)
    det = np.linalg.det(np.swapaxes(x[:, 1:] - x[:, :1], 1, 2))
    np.testing.assert_allclose(volume, np.abs(det) / 6)
    unit_grad, unit_volume = tet_shape_gradients(np.vstack([np.zeros(3), np.eye(3)]), [[0, 1, 2, 3]])
    assert unit_volume[0] == pytest.approx(1 / 6)
    np.testing.assert_allclose(unit_grad[0], np.vstack([-np.ones(3), np.eye(3)]))


def test_plastic_nodal_forces_on_one_tet_have_no_net_force_or_torque():
    rng = np.random.default_rng(7)
    points = rng.normal(size=(4, 3))
    tets = np.array([[0, 1, 2, 3]])
    grad_n, volume = tet_shape_gradients(points, tets)
    eps_p = random_deviatoric(rng, 1, 1e-2)
    force = plastic_nodal_forces(grad_n, eps_p, MU, LAM, volume, tets, 4)
    scale = np.abs(force).max()
    assert scale > 0
    np.testing.assert_allclose(force.sum(axis=0), 0, atol=1e-12 * scale)
    np.testing.assert_allclose(np.cross(points, force).sum(axis=0), 0,
                               atol=1e-12 * scale * np.abs(points).max())
    np.testing.assert_allclose(force, plastic_element_forces(grad_n, eps_p, MU, LAM, volume)[0])


def test_plastic_nodal_forces_equal_scikit_fem_stiffness_times_displacement_for_same_strain():
    # if eps_p equals the strain of a displacement u, then f_p = sum V B^T C eps(u) = K u
    skfem = pytest.importorskip('skfem')
    from skfem.models.elasticity import linear_elasticity
    mesh = skfem.MeshTet().refined(1)
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP1()))
    K = skfem.asm(linear_elasticity(LAM, MU), basis)
    rng = np.random.default_rng(8)
    u = rng.normal(size=basis.N) * 1e-3
    points, tets = mesh.p.T, mesh.t.T
    node_displacement = u.reshape(-1, 3)          # node-interleaved dofs, as documented
    np.testing.assert_array_equal(basis.nodal_dofs.T, np.arange(basis.N).reshape(-1, 3))
    grad_n, volume = tet_shape_gradients(points, tets)
    du = np.einsum('eai,eaj->eij', node_displacement[tets], grad_n)
    eps = 0.5 * (du + np.swapaxes(du, 1, 2))
    force = plastic_nodal_forces(grad_n, eps, MU, LAM, volume, tets, len(points))
    Ku = K @ u
    np.testing.assert_allclose(force.ravel(), Ku, rtol=0, atol=1e-10 * np.abs(Ku).max())
