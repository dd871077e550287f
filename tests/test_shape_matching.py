"""Batched polar decomposition and best-fit rigid frames (Mueller 2005)."""
import numpy as np

from rigid.quaternion import from_rotation_vector, to_matrix
from rigid.shape_matching import best_fit_frame, polar_decomposition, rotation_of


def test_polar_decomposition_gives_rotation_and_symmetric_stretch():
    rng = np.random.default_rng(3)
    F = rng.standard_normal((1000, 3, 3))
    R, S = polar_decomposition(F)
    np.testing.assert_allclose(R @ S, F, atol=1e-12)
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(S, S.transpose(0, 2, 1), atol=1e-12)
    # S is positive semi-definite where det F > 0
    positive = np.linalg.det(F) > 0
    assert 300 < positive.sum() < 700
    assert np.linalg.eigvalsh(S[positive]).min() >= -1e-12
    # a pure rotation times an SPD stretch is recovered
    Q = to_matrix(from_rotation_vector(rng.standard_normal((50, 3))))
    A = rng.standard_normal((50, 3, 3))
    stretch = A @ A.transpose(0, 2, 1) + 0.1 * np.eye(3)
    R, S = polar_decomposition(Q @ stretch)
    np.testing.assert_allclose(R, Q, atol=1e-9)
    np.testing.assert_allclose(S, stretch, atol=1e-9)


def test_best_fit_frame_recovers_rotation_of_rotated_point_cloud():
    rng = np.random.default_rng(4)
    X = rng.standard_normal((40, 3)) * [1.0, 0.5, 0.2]
    m = rng.uniform(0.5, 2.0, 40)
    Xc = m @ X / m.sum()
    Q = to_matrix(from_rotation_vector(np.array([2.0, -1.0, 0.5])))
    x = (X - Xc) @ Q.T + [3.0, 4.0, 5.0]
    R, c = best_fit_frame(X - Xc, x, m)
    np.testing.assert_allclose(R, Q, atol=1e-12)
    np.testing.assert_allclose(c, [3.0, 4.0, 5.0], atol=1e-12)
    # with noise, close to Q but not equal (the test can fail)
    R_noisy, _ = best_fit_frame(X - Xc, x + 0.01 * rng.standard_normal(x.shape), m)
    assert 1e-6 < np.abs(R_noisy - Q).max() < 0.05


def _assert_rotations(R, atol=1e-12):
    """R (..., 3, 3): orthonormal with det +1."""
    R = R.reshape(-1, 3, 3)
    np.testing.assert_allclose(R.transpose(0, 2, 1) @ R, np.broadcast_to(np.eye(3), R.shape), atol=atol)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=atol)


def _random_rotations(rng, n):
    return to_matrix(from_rotation_vector(2.0 * rng.standard_normal((n, 3))))


def test_rotation_of_matches_svd_polar_factor_for_upright_and_inverted_matrices():
    rng = np.random.default_rng(5)
    F = rng.standard_normal((4000, 3, 3))
    R = rotation_of(F)
    _assert_rotations(R)
    R_svd = polar_decomposition(F)[0]
    inverted = np.linalg.det(F) < 0
    assert 1500 < inverted.sum() < 2500
    np.testing.assert_allclose(R[~inverted], R_svd[~inverted], atol=1e-10)
    # inverted: the least significant singular pair is flipped (U V^T itself would be a reflection)
    np.testing.assert_allclose(R[inverted], R_svd[inverted], atol=1e-10)
    U, _, Vt = np.linalg.svd(F[inverted])
    assert np.abs(R[inverted] - U @ Vt).max() > 0.5


def test_rotation_of_near_and_exact_rotations():
    rng = np.random.default_rng(6)
    Q = _random_rotations(rng, 1000)
    np.testing.assert_allclose(rotation_of(Q), Q, atol=1e-13)
    np.testing.assert_array_equal(rotation_of(np.eye(3)), np.eye(3))
    F = Q @ (np.eye(3) + 1e-8 * rng.standard_normal((1000, 3, 3)))
    R = rotation_of(F)
    _assert_rotations(R)
    np.testing.assert_allclose(R, polar_decomposition(F)[0], atol=1e-10)
    assert 1e-10 < np.abs(R - Q).max() < 1e-7


def test_rotation_of_large_stretches():
    """F = Q1 diag(1e3, 1, +-1e-3) Q2^T: the rotation is Q1 Q2^T for both signs (inverted: the
    1e-3 pair is flipped)."""
    rng = np.random.default_rng(7)
    Q1, Q2 = _random_rotations(rng, 500), _random_rotations(rng, 500)
    for s3 in (1e-3, -1e-3):
        F = Q1 @ np.diag([1e3, 1.0, s3]) @ Q2.transpose(0, 2, 1)
        R = rotation_of(F)
        _assert_rotations(R)
        np.testing.assert_allclose(R, Q1 @ Q2.transpose(0, 2, 1), atol=1e-10)
        np.testing.assert_allclose(R, polar_decomposition(F)[0], atol=1e-10)
    # the scale of F does not matter (no overflow or underflow inside)
    F = rng.standard_normal((200, 3, 3))
    for scale in (1e-200, 1e200):
        np.testing.assert_allclose(rotation_of(scale * F), rotation_of(F), atol=1e-13)


def test_rotation_of_degenerate_matrices_is_a_rotation_with_symmetric_stretch():
    rng = np.random.default_rng(8)
    a, b = rng.standard_normal((2, 300, 3))
    rank1 = a[:, :, None] * b[:, None, :]
    rank1_column = np.zeros((300, 3, 3))
    rank1_column[:, :, 2] = a
    rank2 = rng.standard_normal((300, 3, 3))
    rank2[:, :, 2] = 0.3 * rank2[:, :, 0] - 2.0 * rank2[:, :, 1]
    rank2_zero_column = rng.standard_normal((300, 3, 3))
    rank2_zero_column[:, :, 1] = 0.0
    zero = np.zeros((3, 3, 3))
    for F in (rank1, rank1_column, rank2, rank2_zero_column, zero):
        R = rotation_of(F)
        assert np.isfinite(R).all()
        _assert_rotations(R)
        M = R.transpose(0, 2, 1) @ F
        scale = np.maximum(np.abs(F).max(axis=(1, 2)), 1.0)[:, None, None]
        np.testing.assert_allclose(M / scale, M.transpose(0, 2, 1) / scale, atol=1e-12)
    np.testing.assert_array_equal(rotation_of(zero), np.broadcast_to(np.eye(3), zero.shape))
    # rank 2: the rotation is still unique (R v3 = u1 x u2)
    for F in (rank2, rank2_zero_column):
        np.testing.assert_allclose(rotation_of(F), polar_decomposition(F)[0], atol=1e-10)


def test_rotation_of_keeps_the_leading_shape_and_accepts_any_layout():
    rng = np.random.default_rng(9)
    F = rng.standard_normal((24, 3, 3))
    R = rotation_of(F)
    assert rotation_of(F[0]).shape == (3, 3)
    np.testing.assert_allclose(rotation_of(F[0]), polar_decomposition(F[0])[0], atol=1e-12)
    np.testing.assert_array_equal(rotation_of(F.reshape(2, 3, 4, 3, 3)), R.reshape(2, 3, 4, 3, 3))
    np.testing.assert_array_equal(rotation_of(F[::3]), R[::3])
    Ft = F.transpose(0, 2, 1)
    np.testing.assert_array_equal(rotation_of(Ft), rotation_of(Ft.copy()))
    np.testing.assert_array_equal(rotation_of(np.eye(3, dtype=int)), np.eye(3))
    assert rotation_of(np.zeros((0, 3, 3))).shape == (0, 3, 3)
