"""Filter updates (:mod:`imm_gym.tracking.filters`) where the textbook comparisons of
test_filters.py do not look: the UKF's square root of a covariance that lost definiteness, the
whitened innovation."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from helpers import random_pd

from imm_gym import PositionSensor, Sonar, UnscentedKalmanFilter, make_filter


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


@pytest.mark.parametrize("filter_name", ["ukf", "ukf-cholesky", "ekf", "kf"])
def test_whitened_innovation_is_the_lower_cholesky_factor_solved_against_nu(
    filter_name: str,
) -> None:
    """``innovation = L^-1 nu`` with ``S = L L^T``, ``L`` lower triangular (scipy's Cholesky and
    triangular solve): its squared norm is the NIS, and its first component is
    ``nu_1 / sqrt(S_11)``. ``L^-T nu`` has neither property for a correlated ``S``."""
    rng = np.random.default_rng(23)
    sensor = Sonar() if filter_name != "kf" else PositionSensor(sigma_pos=20.0, sigma_vel=2.0)
    flt = make_filter(filter_name)
    for _ in range(5):
        x = np.array([3000.0, 4000.0, 20.0, 15.0]) + rng.normal(size=4) * [300, 300, 5, 5]
        P = random_pd(rng, np.array([150.0, 80.0, 6.0, 4.0]))
        z = sensor.h(x) + rng.normal(size=sensor.dim_z) * sensor.sigma * 3.0
        u = flt.update(x, P, z, sensor)
        L = scipy.linalg.cholesky(u.S, lower=True)
        expected = scipy.linalg.solve_triangular(L, u.nu, lower=True)
        np.testing.assert_allclose(u.innovation, expected, rtol=1e-10, atol=1e-12)
        assert float(u.innovation @ u.innovation) == pytest.approx(float(u.nis), rel=1e-10)
        assert float(u.innovation[0]) == pytest.approx(u.nu[0] / np.sqrt(u.S[0, 0]), rel=1e-10)
