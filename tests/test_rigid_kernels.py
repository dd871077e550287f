"""The compiled kernels of the rigid step against the numpy code they replaced, on random inputs:
the same numbers up to round-off (numpy's einsum sums in an order of its own)."""
import numpy as np
import pytest

from rigid import quaternion as quat
from rigid.integrate import rotate_by, rotate_free
from rigid.solver import arms, normal_velocity
from rigid.step_kernels import body_frames, contact_targets, drift_bodies, impact_kinematics


def _bodies(rng, n):
    q = quat.normalize(rng.normal(size=(n, 4)))
    inertia = rng.uniform(0.1, 2.0, (n, 3))
    return q, inertia, 1.0 / inertia, rng.normal(size=(n, 3))


def _world(R, diagonal):
    """R diag(d) R^T, as rigid.model.world_inverse_inertia computes it."""
    return np.einsum("bij,bj,bkj->bik", R, diagonal, R)


def _contacts(rng, n, c):
    ia = rng.integers(0, n, c)
    ib = rng.integers(-1, n, c)                         # -1: a plane or the static world
    normal = rng.normal(size=(c, 3))
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    return ia, ib, rng.normal(size=(c, 3)), rng.normal(size=(c, 3)), normal


def test_body_frames_match_the_world_inertia_of_numpy():
    rng = np.random.default_rng(0)
    q, _, inv_inertia, L = _bodies(rng, 200)
    R, invI, w = body_frames(q, inv_inertia, L)
    R_ref = quat.to_matrix(q)
    invI_ref = _world(R_ref, inv_inertia)
    np.testing.assert_array_equal(R, R_ref)
    np.testing.assert_allclose(invI, invI_ref, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(w, np.einsum("bij,bj->bi", invI_ref, L), rtol=1e-13, atol=1e-14)


def test_drift_matches_the_numpy_drift():
    """Positions, angular momenta and orientations after a step, as rigid.step.drift computed
    them with numpy (fixed bodies keep their momentum; the impact and recovery rotations are
    small, and some zero)."""
    rng = np.random.default_rng(1)
    n, h = 300, 1.0 / 240.0
    q, inertia, inv_inertia, L = _bodies(rng, n)
    position = rng.normal(size=(n, 3))
    fixed = rng.random(n) < 0.2
    v, w, shift, pseudo_v, fix = (rng.normal(size=(n, 3)) for _ in range(5))
    shift_rotation = 1e-3 * rng.normal(size=(n, 3))
    pseudo_w = 1e-2 * rng.normal(size=(n, 3))
    shift_rotation[::3] = 0.0
    pseudo_w[::3] = 0.0
    new_p, new_L, new_q = drift_bodies(position, q, L, fixed, inertia, inv_inertia, h, v, w, shift,
                                       shift_rotation, pseudo_v, pseudo_w, fix)

    R = quat.to_matrix(q)
    w0 = np.einsum("bij,bj->bi", _world(R, inv_inertia), L)
    L_ref = L + np.where(~fixed[:, None],
                         np.einsum("bij,bj->bi", _world(R, inertia), w - w0) + fix, 0.0)
    p_ref = position + h * v + shift + h * pseudo_v
    q_ref = rotate_by(rotate_free(q, L_ref, inv_inertia, h), shift_rotation + h * pseudo_w)
    np.testing.assert_allclose(new_L, L_ref, rtol=1e-13, atol=1e-13)
    np.testing.assert_array_equal(new_p, p_ref)
    np.testing.assert_allclose(new_q, q_ref, rtol=0, atol=1e-15)


def test_contact_targets_match_numpy():
    rng = np.random.default_rng(2)
    n, c, h = 50, 400, 1.0 / 240.0
    ia, ib, ra, rb, normal = _contacts(rng, n, c)
    gap = rng.normal(scale=1e-3, size=c)
    shift, shift_rotation = 1e-3 * rng.normal(size=(n, 3)), 1e-2 * rng.normal(size=(n, 3))
    target = contact_targets(ia, ib, ra, rb, normal, gap, shift, shift_rotation, h)

    ib0 = np.maximum(ib, 0)
    moved = shift[ia] + np.cross(shift_rotation[ia], ra)
    moved_b = np.where((ib >= 0)[:, None], shift[ib0] + np.cross(shift_rotation[ib0], rb), 0.0)
    shift_n = np.einsum("ck,ck->c", moved - moved_b, normal)
    np.testing.assert_allclose(target, -(np.maximum(gap, 0.0) + shift_n) / h, rtol=1e-13, atol=1e-13)


def _time_of_impact(gap, vn, an, h):
    """The numpy form: first time in [0, inf) at which gap + vn t + an t^2 / 2 reaches 0."""
    g = np.maximum(gap, 0.0)
    disc = vn * vn - 2.0 * an * g
    den = np.sqrt(np.maximum(disc, 0.0)) - vn
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.where((disc >= 0) & (den > 0), 2.0 * g / den, np.inf)
    return np.where(gap <= 0, 0.0, tau)


def test_impact_kinematics_match_numpy():
    """Times of impact of closing, opening, touching and accelerating contacts, and the approach
    speed at that time, as rigid.resolve computed them with numpy."""
    rng = np.random.default_rng(3)
    n, c, h = 40, 500, 1.0 / 240.0
    ia, ib, ra, rb, normal = _contacts(rng, n, c)
    gap = rng.normal(scale=1e-2, size=c)
    gap[::7] = 0.0
    v, w, accel = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(scale=10, size=(n, 3))
    tau, approach = impact_kinematics(ia, ib, ra, rb, normal, gap, v, w, accel, h)

    ib0 = np.maximum(ib, 0)
    vn = normal_velocity(ia, ib, ra, rb, normal, v, w)
    accel_b = np.where((ib >= 0)[:, None], accel[ib0], 0.0)
    an = np.einsum("ck,ck->c", accel[ia] - accel_b, normal)
    tau_ref = _time_of_impact(gap, vn, an, h)
    assert np.isinf(tau_ref).any() and (tau_ref == 0).any() and ((tau_ref > 0) & (tau_ref < h)).any()
    np.testing.assert_array_equal(np.isinf(tau), np.isinf(tau_ref))
    np.testing.assert_array_equal(tau == 0, tau_ref == 0)
    np.testing.assert_allclose(tau, tau_ref, rtol=1e-13, atol=0)
    np.testing.assert_allclose(approach, -(vn + an * np.minimum(tau_ref, h)), rtol=1e-13,
                               atol=1e-13)


def test_arms_and_normal_velocity_match_numpy():
    rng = np.random.default_rng(4)
    n, c = 30, 200
    ia, ib, _, _, normal = _contacts(rng, n, c)
    point, x, v, w = (rng.normal(size=(m, 3)) for m in (c, n, n, n))
    ra, rb = arms(ia, ib, point, x)
    np.testing.assert_array_equal(ra, point - x[ia])
    np.testing.assert_array_equal(rb, np.where((ib >= 0)[:, None], point - x[np.maximum(ib, 0)], 0.0))
    vel = lambda i, r: np.where((i >= 0)[:, None], v[np.maximum(i, 0)] + np.cross(w[np.maximum(i, 0)], r), 0.0)
    vn = normal_velocity(ia, ib, ra, rb, normal, v, w)
    np.testing.assert_allclose(vn, np.einsum("ck,ck->c", vel(ia, ra) - vel(ib, rb), normal),
                               rtol=1e-14, atol=1e-14)


def test_rigid_only_solve_matches_the_solve_with_particle_branches():
    """pgs compiles its sweeps twice, with the particle branches pruned when no solver body is a
    particle: both give the same impulses and velocities, bit for bit, on a rigid problem."""
    from rigid.particle_kernels import with_place_rows
    from rigid.solver import _pgs
    rng = np.random.default_rng(5)
    n, c = 20, 120
    ia, ib, _, _, normal = _contacts(rng, n, c)
    ib = np.where(ib == ia, -1, ib)
    ra, rb = 0.1 * rng.normal(size=(c, 3)), 0.1 * rng.normal(size=(c, 3))
    inv_mass = rng.uniform(0.5, 2.0, n)
    q, _, inv_inertia, _ = _bodies(rng, n)
    invI = _world(quat.to_matrix(q), inv_inertia)
    target, mu = rng.normal(size=c), rng.uniform(0.0, 1.0, c)
    scale_a, scale_b = (rng.random(c) < 0.8).astype(float), np.ones(c)
    active = rng.random(c) < 0.9
    v0, w0, lam0 = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), np.abs(rng.normal(size=(c, 3)))
    groups = (np.full(n, -1), np.eye(3)[None], np.zeros(n + 1, np.int64), np.zeros(1, np.int64),
              np.zeros((1, 3, 3)), np.full((n, 3), -1), np.zeros((n, 3)))
    results = []
    for g in (None, with_place_rows(ia, ib, groups)):
        v, w, lam = v0.copy(), w0.copy(), lam0.copy()
        out = _pgs(ia, ib, ra, rb, normal, target, mu, scale_a, scale_b, active, lam, inv_mass,
                   invI, v, w, 15, g, True)
        results.append((out, v, w, lam))
    assert np.isfinite(results[0][0][active]).all() and np.abs(results[0][1] - v0).max() > 1e-3
    for a, b in zip(*results):
        np.testing.assert_array_equal(a, b)


def test_combined_coefficients_match_numpy():
    """Friction and restitution of contacts with bodies and planes, combined in one pass as
    combine_friction / combine_restitution do."""
    from rigid.contacts import _combined, combine_friction, combine_restitution
    rng = np.random.default_rng(6)
    body_mu, body_e, plane_mu, plane_e = (rng.random(m) for m in (8, 8, 3, 3))
    b = rng.integers(-3, 8, 300)
    mu_a, e_a = rng.random(300), rng.random(300)
    mu, e = _combined(b, mu_a, e_a, body_mu, body_e, plane_mu, plane_e)
    plane = np.maximum(-1 - b, 0)
    mu_b = np.where(b < 0, plane_mu[plane], body_mu[np.maximum(b, 0)])
    e_b = np.where(b < 0, plane_e[plane], body_e[np.maximum(b, 0)])
    np.testing.assert_array_equal(mu, combine_friction(mu_a, mu_b))
    np.testing.assert_array_equal(e, combine_restitution(e_a, e_b))


def test_place_rows_push_as_their_corners_rows_do():
    """An impulse on a place through its merged row (rigid.particle_kernels.with_place_rows) moves
    every particle of its group as the place's corners' weighted shares pushed through their own
    rows do (numpy, dense), to round-off; a place no contact touches gets an empty row."""
    from rigid.particle_kernels import _apply_particle, with_place_rows
    rng = np.random.default_rng(11)
    n_part, n_place = 12, 5
    n = n_part + n_place
    group_of = np.r_[np.zeros(6, np.int64), np.ones(6, np.int64), [0, 0, 1, 1, 0]]
    R = quat.to_matrix(quat.normalize(rng.normal(size=(2, 4))))
    # block-sparse symmetric W over each group's particles, some blocks dropped
    dense = np.zeros((n_part, n_part, 3, 3))
    for g in (0, 1):
        members = np.flatnonzero(group_of[:n_part] == g)
        A = rng.normal(size=(3 * len(members), 3 * len(members)))
        S = (A @ A.T).reshape(len(members), 3, len(members), 3).transpose(0, 2, 1, 3)
        keep = rng.random((len(members), len(members))) < 0.6
        keep = keep | keep.T | np.eye(len(members), dtype=bool)
        for a, i in enumerate(members):
            for b, l in enumerate(members):
                if keep[a, b]:
                    dense[i, l] = S[a, b]
    w_ptr, w_col, W = [0], [], []
    for i in range(n):
        cols = [i] + [l for l in range(n_part) if l != i and dense[i, l].any()] if i < n_part else []
        w_col += cols
        W += [dense[i, l] for l in cols]
        w_ptr.append(len(w_col))
    corner = np.full((n, 3), -1)
    corner_w = np.zeros((n, 3))
    for i in range(n_part, n):
        corner[i] = rng.choice(np.flatnonzero(group_of[:n_part] == group_of[i]), 3, replace=False)
        corner_w[i] = rng.dirichlet(np.ones(3))
    corner_w[n - 1, 1] = 0.0                            # a place on an edge: one weight zero
    groups = (group_of, R, np.array(w_ptr), np.array(w_col), np.array(W), corner, corner_w)
    ia = np.array([0, 7, 9, 2])
    ib = np.array([12, 13, 16, 15])                         # place 14 is touched by no contact
    extended = with_place_rows(ia, ib, groups)
    ptr = extended[7]
    assert ptr[15] - ptr[14] == 0 and ptr[13] - ptr[12] > 0
    for i in (12, 13, 15, 16):
        J = rng.normal(size=3)
        v = rng.normal(size=(n, 3))
        expected = v.copy()
        j = R[group_of[i]].T @ J                         # the impulse in the group's frame
        for c, f in zip(corner[i], corner_w[i]):
            for p in range(w_ptr[c], w_ptr[c + 1]):
                expected[w_col[p]] += W[p].T @ (f * j)
        _apply_particle(i, J[0], J[1], J[2], v, extended)
        np.testing.assert_allclose(v, expected, rtol=1e-13, atol=1e-13)


def test_world_inverse_inertia_gives_einsums_numbers_bit_for_bit():
    """The sums written out give the numbers of the einsum they replaced exactly (the auto
    bodies' switches and the fracture fragments' spins depend on them to the last bit)."""
    from types import SimpleNamespace
    from rigid.model import world_inverse_inertia
    rng = np.random.default_rng(5)
    for n in (1, 7, 1000):
        q, _, inv_inertia, _ = _bodies(rng, n)
        got = world_inverse_inertia(SimpleNamespace(body_inv_inertia=inv_inertia), q)
        np.testing.assert_array_equal(got, _world(quat.to_matrix(q), inv_inertia))


def test_shared_loads_keep_the_patch_total_and_moment_and_push_only():
    """rigid.patches.share_loads: on random flat patches (tilted, points scattered on them) the
    shared normal impulses have the same total and moment about the patch as the loads given,
    none below zero, and where none would pull they are the least-squares (linear) split."""
    from rigid.patches import share_loads
    rng = np.random.default_rng(3)
    for trial in range(50):
        k = rng.integers(3, 40)
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        t1 = np.cross(n, rng.normal(size=3))
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        uv = rng.uniform(-1.0, 1.0, size=(k, 2))
        points = uv[:, :1] * t1 + uv[:, 1:] * t2 + 5.0
        load = np.zeros(k)
        load[rng.integers(k)] = 2.0          # the sweeps' answer: all on one point
        if trial % 2:
            load += rng.uniform(0.0, 1.0, k)
        shared = load.copy()
        share_loads(points, np.tile(n, (k, 1)), np.arange(k), np.array([0, k]), shared)
        assert shared.min() >= 0.0
        for weights in (np.ones(k), uv[:, 0], uv[:, 1]):
            assert weights @ shared == pytest.approx(weights @ load, rel=1e-9, abs=1e-12)
        if shared.min() > 0.0:          # linear in the place on the patch
            basis = np.column_stack([np.ones(k), uv])
            fit = np.linalg.lstsq(basis, shared, rcond=None)[0]
            assert np.abs(basis @ fit - shared).max() < 1e-9


@pytest.mark.parametrize("seed", range(5))
def test_spinning_patches_kernel_matches_numpy_on_random_contacts(seed):
    """The compiled patch finder (rigid.patches.spinning_patches) gives the patches of its numpy
    reference: random contacts between a few bodies and a plane, some pairs on flat patches
    (shared normal) spinning or still about it, some with scattered normals, some too few, some
    with the other body's points against the first facing back (one patch with them)."""
    from rigid.patches import spinning_patches, spinning_patches_numpy
    rng = np.random.default_rng(seed)
    bodies = 6
    angular = rng.normal(size=(bodies, 3)) * rng.choice([0.0, 1e-4, 3.0], size=(bodies, 1))
    rows_a, rows_b, points, normals = [], [], [], []
    for _ in range(12):
        a = int(rng.integers(bodies))
        b = int(rng.integers(-1, bodies))
        if b == a:
            continue
        k = int(rng.integers(1, 7))
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        flat = rng.random() < 0.7
        back = int(rng.integers(0, 3)) if b >= 0 else 0    # the other side's points, facing back
        for j in range(k + back):
            rows_a.append(a if j < k else b), rows_b.append(b if j < k else a)
            points.append(rng.normal(size=3) * 0.1)
            m = n if flat else n + 1e-3 * rng.normal(size=3)
            normals.append((m if j < k else -m) / np.linalg.norm(m))
    order = rng.permutation(len(rows_a))
    body_a = np.array(rows_a, dtype=np.int64)[order]
    body_b = np.array(rows_b, dtype=np.int64)[order]
    point, normal = np.array(points)[order], np.array(normals)[order]
    rigid_pair = rng.random(len(body_a)) < 0.9
    got = spinning_patches(body_a, body_b, point, normal, rigid_pair, angular)
    want = spinning_patches_numpy(body_a, body_b, point, normal, rigid_pair, angular)
    assert (got is None) == (want is None)
    if want is not None:
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
        assert len(want[1]) > 1


def test_quaternion_of_a_rotation_matrix_is_the_quaternion_that_made_it():
    """``from_matrix`` inverts ``to_matrix`` (the quaternion with w >= 0): random rotations, turns
    of nearly and exactly 180 degrees (w about 0, where the largest component is x, y or z) and
    the identity; the result is a unit quaternion in any leading shape."""
    rng = np.random.default_rng(7)
    q = quat.normalize(rng.normal(size=(4000, 4)))
    q[:300, 0] = rng.uniform(0.0, 1e-9, 300)             # half-turns, about random axes
    q[300:303] = np.eye(4)[1:]                           # exact half-turns about x, y, z
    q[303] = [1.0, 0.0, 0.0, 0.0]
    q = quat.normalize(q) * np.where(q[:, :1] < 0, -1.0, 1.0)
    back = quat.from_matrix(quat.to_matrix(q))
    exact_half_turn = q[:, 0] == 0.0                     # q and -q are the same turn there
    assert np.abs(back - q)[~exact_half_turn].max() < 1e-14
    assert np.abs(np.abs(np.einsum("bi,bi->b", back, q)) - 1.0).max() < 1e-14
    assert np.all(back[:, 0] >= 0.0)
    assert quat.from_matrix(quat.to_matrix(q[:6]).reshape(2, 3, 3, 3)).shape == (2, 3, 4)


@pytest.mark.parametrize("last_dt", [0.0, 1e-3])
def test_body_report_matches_the_numpy_rows(last_dt):
    """A frame's rows from one compiled pass: the reported velocities, angular velocities,
    kinetic energies and shape-frame orientations that rigid.model and quaternion.from_matrix give
    (fixed bodies with no kinetic energy; supported bodies report no half step of gravity)."""
    from types import SimpleNamespace
    from rigid.model import (FORCE_LIKE, angular_velocity, body_pose_in_shape_frame, kinetic_energy,
                             reported_velocity)
    from rigid.step_kernels import body_report
    rng = np.random.default_rng(3)
    n = 300
    q, _, inv_inertia, L = _bodies(rng, n)
    fixed = rng.random(n) < 0.2
    model = SimpleNamespace(body_fixed=fixed, body_mass=np.where(fixed, np.inf, rng.uniform(0.1, 5, n)),
                            body_inv_inertia=np.where(fixed[:, None], 0.0, inv_inertia),
                            shape_rotation=quat.to_matrix(quat.normalize(rng.normal(size=(n, 4)))),
                            shape_offset=rng.normal(size=(n, 3)))
    state = SimpleNamespace(position=rng.normal(size=(n, 3)), orientation=q,
                            velocity=rng.normal(size=(n, 3)), angular_momentum=L,
                            contact_dv=rng.normal(size=(n, 3)) * rng.choice([0.005, 0.1], size=(n, 1)),
                            last_dt=last_dt)
    g = np.array([0.3, -0.2, -9.81])
    table = body_report(state.position, q, state.velocity, L, state.contact_dv, fixed,
                        model.body_mass, model.body_inv_inertia, model.shape_rotation, g, last_dt,
                        FORCE_LIKE)
    v = reported_velocity(model, state, g)
    w = angular_velocity(model, state)
    R_shape, _ = body_pose_in_shape_frame(model, state)
    np.testing.assert_array_equal(table[:, :3], state.position)
    np.testing.assert_allclose(table[:, 3:7], quat.from_matrix(R_shape), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(table[:, 7:10], v, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(table[:, 10:13], w, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(table[:, 13], kinetic_energy(model, state, v, w), rtol=1e-13, atol=1e-14)
    assert (table[fixed, 13] == 0).all()
