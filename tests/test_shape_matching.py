"""Batched polar decomposition and best-fit rigid frames (Mueller 2005)."""
import numpy as np

from rigid.quaternion import from_rotation_vector, to_matrix
from rigid.shape_matching import best_fit_frame, polar_decomposition


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
