"""Tests of imm_gym.tracking.filters: KF, EKF and UKF (SVD and Cholesky sigma points) updates, the
linear prediction, sigma points."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import random_pd
from scipy.stats import multivariate_normal

from imm_gym import (
    ConfigError,
    ExtendedKalmanFilter,
    KalmanFilter,
    PositionSensor,
    Sonar,
    UnscentedKalmanFilter,
    make_filter,
    paper_bank,
    predict,
)

PI = np.pi
UPDATE_FIELDS = ("x", "P", "z_pred", "nu", "S", "loglik", "nis")


def _random_problem(rng: np.random.Generator, n: int = 4) -> tuple[np.ndarray, np.ndarray]:
    std = np.array([80.0, 120.0, 4.0, 6.0, 0.5, 0.5])[:n]
    x = np.concatenate([rng.uniform(-5000, 5000, 2), rng.normal(0, 15, 2), rng.normal(0, 1, 2)])
    return x[:n], random_pd(rng, std)


def _assert_updates_close(a, b, rtol: float, scale_atol: float = 1e-12) -> None:
    for f in UPDATE_FIELDS:
        va, vb = np.asarray(getattr(a, f)), np.asarray(getattr(b, f))
        assert va.shape == vb.shape, f
        atol = scale_atol * max(1.0, float(np.abs(vb).max()))
        np.testing.assert_allclose(va, vb, rtol=rtol, atol=atol, err_msg=f)


def _textbook_kf(x, P, z, H, R):
    """Plain textbook Kalman update, standard form P = (I - K H) P."""
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    nu = z - H @ x
    x_new = x + K @ nu
    P_new = (np.eye(len(x)) - K @ H) @ P
    loglik = multivariate_normal(mean=np.zeros(len(z)), cov=S).logpdf(nu)
    nis = nu @ np.linalg.solve(S, nu)
    return x_new, P_new, S, nu, loglik, nis


# --------------------------------------------------------------------------- (1)-(3) linear


@pytest.mark.parametrize("square_root", ["svd", "cholesky"])
@pytest.mark.parametrize("sigma_vel", [None, 1.5], ids=["pos", "pos+vel"])
@pytest.mark.parametrize("n", [4, 6])
def test_ukf_equals_kf_on_linear_sensor(sigma_vel: float | None, n: int, square_root: str) -> None:
    sensor = PositionSensor(sigma_pos=25.0, sigma_vel=sigma_vel)
    rng = np.random.default_rng(10 + n)
    for _ in range(10):
        x, P = _random_problem(rng, n)
        z = sensor.h(x) + rng.normal(0.0, 40.0, sensor.dim_z)
        kf = KalmanFilter().update(x, P, z, sensor)
        ukf = UnscentedKalmanFilter(square_root=square_root).update(x, P, z, sensor)
        _assert_updates_close(ukf, kf, rtol=1e-9)


@pytest.mark.parametrize("alpha_kappa", [(1.0, 0.0), (0.5, 1.0), (1e-3, 0.0)])
def test_ukf_equals_kf_any_scaling(alpha_kappa: tuple[float, float]) -> None:
    alpha, kappa = alpha_kappa
    sensor = PositionSensor(sigma_pos=10.0)
    rng = np.random.default_rng(3)
    x, P = _random_problem(rng)
    z = sensor.h(x) + rng.normal(0.0, 20.0, 2)
    ukf = UnscentedKalmanFilter(alpha=alpha, kappa=kappa).update(x, P, z, sensor)
    _assert_updates_close(ukf, KalmanFilter().update(x, P, z, sensor), rtol=1e-7, scale_atol=1e-9)


@pytest.mark.parametrize("sigma_vel", [None, 1.5], ids=["pos", "pos+vel"])
def test_kf_matches_textbook(sigma_vel: float | None) -> None:
    sensor = PositionSensor(sigma_pos=30.0, sigma_vel=sigma_vel)
    rng = np.random.default_rng(21)
    H = np.eye(sensor.dim_z, 4)
    R = np.diag(sensor.sigma**2)
    for _ in range(10):
        x, P = _random_problem(rng)
        z = H @ x + rng.normal(0.0, 50.0, sensor.dim_z)
        u = KalmanFilter().update(x, P, z, sensor)
        x_ref, P_ref, S_ref, nu_ref, ll_ref, nis_ref = _textbook_kf(x, P, z, H, R)
        np.testing.assert_allclose(u.x, x_ref, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(u.P, P_ref, rtol=1e-8, atol=1e-8 * np.abs(P_ref).max())
        np.testing.assert_allclose(u.S, S_ref, rtol=1e-12)
        np.testing.assert_allclose(u.nu, nu_ref, rtol=1e-12)
        np.testing.assert_allclose(u.z_pred, H @ x, rtol=1e-12)
        assert float(u.loglik) == pytest.approx(ll_ref, rel=1e-10)
        assert float(u.nis) == pytest.approx(nis_ref, rel=1e-10)
        np.testing.assert_array_equal(u.P, u.P.T)


def test_ekf_equals_kf_on_linear_sensor() -> None:
    sensor = PositionSensor(sigma_pos=15.0, sigma_vel=2.0)
    rng = np.random.default_rng(5)
    for _ in range(5):
        x, P = _random_problem(rng)
        z = sensor.h(x) + rng.normal(0.0, 10.0, 4)
        _assert_updates_close(
            ExtendedKalmanFilter().update(x, P, z, sensor),
            KalmanFilter().update(x, P, z, sensor),
            rtol=1e-12,
        )


def test_ekf_matches_textbook_with_sonar_jacobian() -> None:
    sonar = Sonar()
    rng = np.random.default_rng(6)
    x, P = _random_problem(rng)
    z = sonar.h(x) + np.array([30.0, 5e-4])
    H = sonar.jacobian(x)
    u = ExtendedKalmanFilter().update(x, P, z, sonar)
    x_ref, P_ref, S_ref, *_ = _textbook_kf(x, P, z - sonar.h(x) + H @ x, H, sonar.R)
    np.testing.assert_allclose(u.x, x_ref, rtol=1e-9)
    np.testing.assert_allclose(u.S, S_ref, rtol=1e-9)
    np.testing.assert_allclose(u.P, P_ref, rtol=1e-6, atol=1e-7 * np.abs(P_ref).max())


def test_kf_rejects_sonar() -> None:
    x, P = _random_problem(np.random.default_rng(0))
    with pytest.raises(ConfigError, match="kf"):
        KalmanFilter().update(x, P, np.array([5000.0, 0.1]), Sonar())


# --------------------------------------------------------------------------- (4) sonar


def test_ukf_close_to_ekf_in_nearly_linear_regime() -> None:
    sonar = Sonar()
    rng = np.random.default_rng(8)
    for _ in range(10):
        x, _ = _random_problem(rng)
        x[:2] = rng.uniform(3000, 8000) * np.array([math.cos(b := rng.uniform(-3, 3)), math.sin(b)])
        P = random_pd(rng, np.array([0.5, 0.5, 0.05, 0.05]))  # tiny: h is linear over P
        z = sonar.h(x) + rng.normal(0.0, 1.0, 2) * sonar.sigma
        z = sonar.wrap(z)
        ukf = UnscentedKalmanFilter().update(x, P, z, sonar)
        ekf = ExtendedKalmanFilter().update(x, P, z, sonar)
        np.testing.assert_allclose(ukf.x, ekf.x, rtol=0, atol=1e-4)
        np.testing.assert_allclose(ukf.P, ekf.P, rtol=1e-4, atol=1e-7)
        np.testing.assert_allclose(ukf.S, ekf.S, rtol=1e-6)
        # in units of the measurement noise: equal up to the UKF's tiny second-order terms
        np.testing.assert_allclose(ukf.nu / sonar.sigma, ekf.nu / sonar.sigma, atol=1e-3)
        assert float(ukf.loglik) == pytest.approx(float(ekf.loglik), abs=1e-5)


def test_ukf_update_with_sonar_second_order_range() -> None:
    """The UKF sees the range's curvature: E[r] = r + (cross-range variance) / (2 r)."""
    sonar = Sonar()
    rng = np.random.default_rng(9)
    x = np.array([3000.0, 4000.0, 20.0, 15.0])
    P = random_pd(rng, np.array([200.0, 200.0, 5.0, 5.0]))
    ukf = UnscentedKalmanFilter().update(x, P, sonar.h(x), sonar)
    ekf = ExtendedKalmanFilter().update(x, P, sonar.h(x), sonar)
    r = 5000.0
    perp = np.array([-0.8, 0.6])  # unit vector across the line of sight
    bias = perp @ P[:2, :2] @ perp / (2 * r)
    assert bias > 0.5
    assert float(ukf.z_pred[0]) - r == pytest.approx(bias, rel=0.05)
    assert float(ekf.z_pred[0]) == pytest.approx(r, rel=1e-14)
    for u in (ukf, ekf):
        assert np.all(np.linalg.eigvalsh(u.P) > 0)
        # the update only removes uncertainty
        assert np.all(np.linalg.eigvalsh(P - u.P) > -1e-6 * np.abs(P).max())
        assert np.trace(u.P[:2, :2]) < 0.2 * np.trace(P[:2, :2])


# --------------------------------------------------------------------------- (5) wrapping


@pytest.mark.parametrize("filter_name", ["ukf", "ukf-cholesky", "ekf"])
@pytest.mark.parametrize("y", [1.0, 0.0, -1.0])
def test_bearing_residual_wrapped(filter_name: str, y: float) -> None:
    """Target on the -x axis just above/below the cut; measured at -pi + 0.001."""
    sonar = Sonar(sigma_theta_deg=0.5)
    flt = make_filter(filter_name)
    x = np.array([-5000.0, y, -10.0, 3.0])
    P = np.diag([50.0**2, 50.0**2, 5.0**2, 5.0**2])  # sigma points straddle the cut
    z = np.array([5000.0, -PI + 0.001])
    u = flt.update(x, P, z, sonar)
    expected_nu = math.remainder(-PI + 0.001 - math.atan2(y, -5000.0), 2 * PI)
    assert abs(expected_nu) < 0.002
    assert float(u.nu[1]) == pytest.approx(expected_nu, abs=1e-5)
    assert abs(float(u.nu[0])) < 1.0
    # predicted bearing: close to +-pi, the innovation covariance stays small
    assert abs(math.remainder(float(u.z_pred[1]) - PI, 2 * PI)) < 1e-3
    # and a bearing itself, wrapped to (-pi, pi] (the UKF's mean of the sigma points' residuals
    # about the centre one can step past pi)
    assert -PI < float(u.z_pred[1]) <= PI
    assert float(u.S[1, 1]) < 1e-3  # R + H P H^T ~ 1.8e-4; an unwrapped spread would be ~pi^2
    # the estimate moves by metres, not kilometres
    assert np.linalg.norm(u.x[:2] - x[:2]) < 15.0
    assert float(u.nis) < 10.0


@pytest.mark.parametrize("filter_name", ["ukf", "ukf-cholesky"])
def test_ukf_predicted_bearing_past_pi_is_wrapped(filter_name: str) -> None:
    """A target on the -x axis (bearing pi) with x and y correlated: the sigma points' bearings
    average to pi + Pxy * d2(atan2)/dxdy = pi - Pxy / r^2 (second order; 9e-5 rad here), past the
    cut. The predicted measurement is a bearing, -pi + 9e-5; left unwrapped it is pi + 9e-5
    (the innovation is still wrapped, so nothing else shows it)."""
    sonar = Sonar(sigma_theta_deg=0.5)
    x = np.array([-5000.0, 0.0, -10.0, 3.0])
    P = np.diag([50.0**2, 50.0**2, 5.0**2, 5.0**2])
    P[0, 1] = P[1, 0] = -0.9 * 50.0**2
    u = make_filter(filter_name).update(x, P, np.array([5000.0, -PI + 0.001]), sonar)
    bias = -P[0, 1] / 5000.0**2
    assert bias == pytest.approx(9e-5)
    assert -PI < float(u.z_pred[1]) <= PI
    assert float(u.z_pred[1]) == pytest.approx(-PI + bias, abs=1e-7)
    assert float(u.nu[1]) == pytest.approx(0.001 - bias, abs=1e-7)


# --------------------------------------------------------------------------- (6) predict


def test_predict_formula() -> None:
    rng = np.random.default_rng(12)
    bank = paper_bank()
    F = np.stack([m.transition_matrix(1.0, 4) for m in bank])
    Q = np.stack([m.noise_covariance(4) for m in bank])
    x = rng.normal(0, 100, (5, 3, 4))
    P = np.stack([[random_pd(rng, np.full(4, 10.0)) for _ in range(3)] for _ in range(5)])
    xp, Pp = predict(x, P, F, Q)
    assert xp.shape == (5, 3, 4) and Pp.shape == (5, 3, 4, 4)
    for i in range(5):
        for j in range(3):
            np.testing.assert_allclose(xp[i, j], F[j] @ x[i, j], rtol=1e-13)
            np.testing.assert_allclose(Pp[i, j], F[j] @ P[i, j] @ F[j].T + Q[j], rtol=1e-12)


# --------------------------------------------------------------------------- (7) sigma points


@pytest.mark.parametrize("square_root", ["svd", "cholesky"])
@pytest.mark.parametrize(
    ("alpha", "beta", "kappa"), [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0), (0.1, 0.0, 3.0)]
)
@pytest.mark.parametrize("n", [4, 6])
def test_sigma_points_moments(
    alpha: float, beta: float, kappa: float, n: int, square_root: str
) -> None:
    ukf = UnscentedKalmanFilter(alpha, beta, kappa, square_root)
    rng = np.random.default_rng(n)
    x, P = _random_problem(rng, n)
    X = ukf.sigma_points(x, P)
    assert X.shape == (2 * n + 1, n)
    wm, wc, gamma = ukf.weights(n)
    assert wm.sum() == pytest.approx(1.0, abs=1e-12)
    lam = alpha**2 * (n + kappa) - n
    assert gamma == pytest.approx(math.sqrt(n + lam))
    assert wc[0] == pytest.approx(lam / (n + lam) + 1 - alpha**2 + beta)
    np.testing.assert_allclose(wm @ X, x, rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(X[0], x)
    dX = X - x
    cov = (dX * wc[:, None]).T @ dX
    np.testing.assert_allclose(cov, P, rtol=1e-9, atol=1e-10 * np.abs(P).max())
    # symmetric set about x
    np.testing.assert_allclose(X[1 : n + 1] - x, -(X[n + 1 :] - x), rtol=1e-14)


def test_sigma_points_batched() -> None:
    ukf = UnscentedKalmanFilter()
    rng = np.random.default_rng(4)
    probs = [_random_problem(rng) for _ in range(6)]
    x = np.stack([p[0] for p in probs]).reshape(2, 3, 4)
    P = np.stack([p[1] for p in probs]).reshape(2, 3, 4, 4)
    X = ukf.sigma_points(x, P)
    assert X.shape == (2, 3, 9, 4)
    np.testing.assert_array_equal(X[1, 0], ukf.sigma_points(x[1, 0], P[1, 0]))


def test_sigma_points_degenerate_covariance() -> None:
    ukf = UnscentedKalmanFilter()
    x = np.array([100.0, 200.0, 3.0, 4.0])
    P = np.diag([2500.0, 2500.0, 25.0, 25.0])
    X = ukf.sigma_points(x, P)
    dX = X - x
    _, wc, _ = ukf.weights(4)
    np.testing.assert_allclose((dX * wc[:, None]).T @ dX, P, atol=1e-9)
    # rank-deficient P: sigma points still defined, the missing direction collapses to x
    P_singular = np.diag([100.0, 0.0, 1.0, 1.0])
    X = ukf.sigma_points(x, P_singular)
    assert np.all(np.isfinite(X))
    np.testing.assert_allclose((X - x)[:, 1], 0.0, atol=1e-12)


def test_svd_sigma_points_are_the_symmetric_square_root() -> None:
    """``a_i`` are the columns of ``U sqrt(S) U^T``: symmetric, squaring to ``P``."""
    rng = np.random.default_rng(5)
    _, P = _random_problem(rng)
    ukf = UnscentedKalmanFilter()
    _, _, gamma = ukf.weights(4)
    A = ukf.sigma_offsets(P)[1:5] / gamma  # rows a_i
    np.testing.assert_allclose(A, A.T, atol=1e-12 * np.abs(A).max())
    np.testing.assert_allclose(A @ A, P, rtol=1e-10, atol=1e-10 * np.abs(P).max())


def test_svd_ukf_is_continuous_where_eigenvalues_repeat() -> None:
    """The track start's ``P`` has the velocity block ``25 I`` (and here the position block
    ``400 I``): a rounding-level change of ``P`` made the columns of ``U sqrt(S)`` any basis of
    those eigenspaces, and on a target 63 m from the sonar the update moved by 3.1 m. The
    symmetric root moves it by about the change itself."""
    x, z = np.array([60.0, 20.0, 10.0, -5.0]), np.array([55.0, 0.4])
    P = np.diag([400.0, 400.0, 25.0, 25.0])
    E = np.random.default_rng(0).normal(size=(4, 4))
    ukf = UnscentedKalmanFilter()
    base = ukf.update(x, P, z, Sonar())
    moved = ukf.update(x, P + 4e-12 * (E + E.T), z, Sonar())
    assert np.abs(moved.x - base.x).max() < 1e-9
    assert abs(moved.loglik - base.loglik) < 1e-9


# --------------------------------------------------------------------------- (8) robustness


@pytest.mark.parametrize("square_root", ["svd", "cholesky"])
@pytest.mark.parametrize("sensor", [Sonar(), PositionSensor()], ids=["sonar", "position"])
def test_ukf_finite_when_p_loses_definiteness(sensor, square_root: str) -> None:
    rng = np.random.default_rng(13)
    Qm, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    P = Qm @ np.diag([400.0, 100.0, 4.0, -1e-9]) @ Qm.T
    P = 0.5 * (P + P.T)
    assert np.linalg.eigvalsh(P).min() < 0
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(P)
    x = np.array([3000.0, 4000.0, 20.0, 15.0])
    z = sensor.h(x) + np.array([10.0, 1e-4])[: sensor.dim_z]
    u = UnscentedKalmanFilter(square_root=square_root).update(x, P, z, sensor)
    for f in UPDATE_FIELDS:
        assert np.all(np.isfinite(getattr(u, f))), f
    np.testing.assert_array_equal(u.P, u.P.T)
    assert np.linalg.eigvalsh(u.P).min() > -1e-6


def test_cholesky_and_svd_sigma_points_differ_by_a_rotation() -> None:
    # Both square roots A of P (A A^T = P) are related by an orthogonal Q (A_svd = A_chol Q): the
    # same mean and covariance, the same update for a linear sensor, a higher-order difference
    # for the sonar
    rng = np.random.default_rng(21)
    _, P = _random_problem(rng)
    svd, chol = UnscentedKalmanFilter(), UnscentedKalmanFilter(square_root="cholesky")
    D_svd, D_chol = (f.sigma_offsets(P)[1:5].T for f in (svd, chol))
    Q = np.linalg.solve(D_chol, D_svd)
    np.testing.assert_allclose(Q @ Q.T, np.eye(4), atol=1e-9)
    assert not np.allclose(D_svd, D_chol)
    x_far = np.array([8000.0, 3000.0, 10.0, -5.0])
    z = Sonar().h(x_far) + np.array([5.0, 2e-4])
    a, b = (f.update(x_far, P, z, Sonar()) for f in (svd, chol))
    assert 0.0 < np.abs(a.x - b.x).max() < 1e-3 * np.sqrt(P[0, 0])


# --------------------------------------------------------------------------- batching, config


@pytest.mark.parametrize("filter_name", ["ukf", "ukf-cholesky", "ekf"])
def test_update_batched_matches_loop(filter_name: str) -> None:
    sonar = Sonar()
    flt = make_filter(filter_name)
    rng = np.random.default_rng(14)
    probs = [_random_problem(rng) for _ in range(6)]
    x = np.stack([p[0] for p in probs]).reshape(2, 3, 4)
    P = np.stack([p[1] for p in probs]).reshape(2, 3, 4, 4)
    z = sonar.wrap(sonar.h(x[:, 0]) + rng.normal(0, 1, (2, 2)) * sonar.sigma)  # one z per row
    u = flt.update(x, P, z[:, None, :], sonar)
    for i in range(2):
        for j in range(3):
            ref = flt.update(x[i, j], P[i, j], z[i], sonar)
            for f in UPDATE_FIELDS:
                np.testing.assert_allclose(
                    getattr(u, f)[i, j], getattr(ref, f), rtol=1e-12, atol=1e-12, err_msg=f
                )


def test_make_filter() -> None:
    assert isinstance(make_filter("ukf"), UnscentedKalmanFilter)
    assert isinstance(make_filter("ekf"), ExtendedKalmanFilter)
    assert isinstance(make_filter("kf"), KalmanFilter)
    assert make_filter("ukf", 0.5, 2.0, 1.0) == UnscentedKalmanFilter(0.5, 2.0, 1.0)
    cholesky = make_filter("ukf-cholesky", 0.5)
    assert cholesky == UnscentedKalmanFilter(0.5, square_root="cholesky")
    assert (make_filter("ukf").name, cholesky.name) == ("ukf", "ukf-cholesky")
    with pytest.raises(ConfigError, match="filter"):
        make_filter("pf")


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"alpha": 0.0}, r"ukf\.alpha"),
        ({"alpha": 1.5}, r"ukf\.alpha"),
        ({"beta": -1.0}, r"ukf\.beta"),
        ({"kappa": -1.0}, r"ukf\.kappa"),
        ({"square_root": "qr"}, r"ukf\.square_root must be one of \['svd', 'cholesky'\]"),
    ],
)
def test_ukf_invalid_config(kwargs: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        UnscentedKalmanFilter(**kwargs)
