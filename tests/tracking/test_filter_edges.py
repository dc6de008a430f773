"""Filter updates (:mod:`imm_gym.tracking.filters`) where the textbook comparisons of
test_filters.py do not look: the UKF's square root of a covariance that lost definiteness, the
whitened innovation."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import UnscentedKalmanFilter


@pytest.mark.parametrize("neg", [-1.0, -25.0])
def test_svd_sigma_points_take_the_absolute_eigenvalues_of_an_indefinite_covariance(
    neg: float,
) -> None:
    """A covariance with a negative eigenvalue (rounding gone wrong): the ``a_i`` are the columns
    of ``U sqrt(|S|) U^T`` (SPEC §2, module docstring), so they square to ``U |S| U^T``, computed
    here from ``numpy.linalg.eigh``; the negative direction keeps its spread ``sqrt(|neg|)``
    instead of collapsing onto ``x``."""
    rng = np.random.default_rng(17)
    U, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    P = U @ np.diag([400.0, 100.0, 4.0, neg]) @ U.T
    P = 0.5 * (P + P.T)
    ukf = UnscentedKalmanFilter()
    _, _, gamma = ukf.weights(4)
    A = ukf.sigma_offsets(P)[1:5] / gamma  # rows a_i (the root is symmetric)
    s, V = np.linalg.eigh(P)
    np.testing.assert_allclose(A @ A, V @ np.diag(np.abs(s)) @ V.T, atol=1e-9)
    spread = np.linalg.norm(A @ U[:, 3])  # along the negative eigenvector
    assert spread == pytest.approx(np.sqrt(-neg), rel=1e-9)
