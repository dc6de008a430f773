"""Tests of imm_gym.tracking.imm: the IMM cycle against independent implementations, batching,
errors."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import random_pd
from scipy.special import softmax
from scipy.stats import multivariate_normal

from imm_gym import (
    IMM,
    ConfigError,
    IMMState,
    MotionModel,
    PositionSensor,
    RandomFamily,
    Sonar,
    combine,
    draw_batch,
    mix,
    paper_bank,
    paper_scenario,
    predict,
    stay_tpm,
    update_mode_probs,
)
from imm_gym.tracking.kernels.imm import TRACKER_BLOCK


def _random_tpm(rng: np.random.Generator, M: int, shape: tuple[int, ...] = ()) -> np.ndarray:
    a = rng.uniform(0.05, 1.0, (*shape, M, M))
    return a / a.sum(axis=-1, keepdims=True)


def _random_posterior(rng: np.random.Generator, N: int, M: int, n: int = 4):
    base = np.array([3000.0, 4000.0, 20.0, 15.0, 0.0, 0.0])[:n]
    spread = np.array([100.0, 100.0, 5.0, 5.0, 1.0, 1.0])[:n]
    x = base + spread * rng.standard_normal((N, M, n))
    P = np.stack([[random_pd(rng, spread) for _ in range(M)] for _ in range(N)])
    mu = rng.dirichlet(np.ones(M), size=N)
    return x, P, mu


@pytest.fixture(scope="module")
def paper_batch():
    return draw_batch(paper_scenario(), Sonar(), 8, 123)


# --------------------------------------------------------------------------- (1)


@pytest.mark.parametrize("filter_name", ["ukf", "ukf-cholesky", "ekf"])
def test_identical_models_equal_single_filter(paper_batch, make_imm, filter_name: str) -> None:
    sonar = Sonar()
    cv = MotionModel("cv")
    imm = make_imm((cv, cv, cv), sonar, filter_name)
    rng = np.random.default_rng(0)
    tpm = _random_tpm(rng, 3)
    mu0 = np.array([0.6, 0.3, 0.1])
    z = paper_batch.measurements.z[:, 1:]
    res = imm.run(z, tpm, paper_batch.x0, paper_batch.P0, mode_probs=mu0)

    flt = imm.filter
    F, Q = cv.transition_matrix(1.0, 4), cv.noise_covariance(4)
    x, P = paper_batch.x0.copy(), paper_batch.P0.copy()
    mu = np.broadcast_to(mu0, (z.shape[0], 3))
    for k in range(z.shape[1]):
        x, P = predict(x, P, F, Q)
        u = flt.update(x, P, z[:, k], sonar)
        x, P = u.x, u.P
        mu = mu @ tpm  # equal likelihoods: mode probabilities follow the Markov chain
        np.testing.assert_allclose(res.x[:, k], x, rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(res.P[:, k], P, rtol=1e-8, atol=1e-8 * np.abs(P).max())
        np.testing.assert_allclose(res.mode_probs[:, k], mu, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(res.loglik[:, k], u.loglik[:, None].repeat(3, 1), rtol=1e-8)
        np.testing.assert_allclose(res.model_nis[:, k], u.nis[:, None].repeat(3, 1), rtol=1e-6)
        np.testing.assert_allclose(res.nis[:, k], u.nis, rtol=1e-6)


# --------------------------------------------------------------------------- (2)


def _hand_imm_cycle(mu, xs, Ps, tpm, z, models, R):
    """One IMM cycle for one tracker, written out with loops (SPEC §1) and a plain KF."""
    M, n = len(models), xs.shape[-1]
    H = np.eye(2, n)
    # 1. mixing
    cbar = np.zeros(M)
    for j in range(M):
        for i in range(M):
            cbar[j] += tpm[i, j] * mu[i]
    w = np.zeros((M, M))
    for i in range(M):
        for j in range(M):
            w[i, j] = tpm[i, j] * mu[i] / cbar[j]
    x0 = np.zeros((M, n))
    P0 = np.zeros((M, n, n))
    for j in range(M):
        for i in range(M):
            x0[j] += w[i, j] * xs[i]
        for i in range(M):
            d = xs[i] - x0[j]
            P0[j] += w[i, j] * (Ps[i] + np.outer(d, d))
    # 2. model-matched KF
    x_new, P_new, lik, nis, zp, S_all = [], [], [], [], [], []
    for j, m in enumerate(models):
        F, Q = m.transition_matrix(1.0, n), m.noise_covariance(n)
        xp = F @ x0[j]
        Pp = F @ P0[j] @ F.T + Q
        S = H @ Pp @ H.T + R
        K = Pp @ H.T @ np.linalg.inv(S)
        nu = z - H @ xp
        x_new.append(xp + K @ nu)
        P_new.append((np.eye(n) - K @ H) @ Pp)
        lik.append(multivariate_normal(np.zeros(2), S).pdf(nu))
        nis.append(nu @ np.linalg.inv(S) @ nu)
        zp.append(H @ xp)
        S_all.append(S)
    # 3. mode probabilities
    c = np.array(lik) * cbar
    mu_new = c / c.sum()
    # 4. combination with the spread term
    x_hat = sum(mu_new[j] * x_new[j] for j in range(M))
    P_hat = sum(
        mu_new[j] * (P_new[j] + np.outer(x_new[j] - x_hat, x_new[j] - x_hat)) for j in range(M)
    )
    # NIS of the moment-matched predicted measurement mixture
    z_mix = sum(cbar[j] * zp[j] for j in range(M))
    S_mix = sum(cbar[j] * (S_all[j] + np.outer(zp[j] - z_mix, zp[j] - z_mix)) for j in range(M))
    nis_mix = (z - z_mix) @ np.linalg.inv(S_mix) @ (z - z_mix)
    return {
        "cbar": cbar,
        "x_models": np.array(x_new),
        "P_models": np.array(P_new),
        "loglik": np.log(lik),
        "model_nis": np.array(nis),
        "mu": mu_new,
        "x": x_hat,
        "P": P_hat,
        "nis": nis_mix,
    }


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_model_cycle_by_hand(make_imm, seed: int) -> None:
    rng = np.random.default_rng(seed)
    models = (MotionModel("cv"), MotionModel("ct", 4.0, (0.05, 0.05, 0.06, 0.06)))
    sensor = PositionSensor(sigma_pos=20.0)
    imm = make_imm(models, sensor, "kf")
    N = 3
    x, P, mu = _random_posterior(rng, N, 2)
    tpm = np.array([[0.9, 0.1], [0.3, 0.7]])
    z = x[:, 0, :2] + rng.normal(0.0, 60.0, (N, 2))
    state, out = imm.step(IMMState(x, P, mu), tpm, z)
    for t in range(N):
        ref = _hand_imm_cycle(mu[t], x[t], P[t], tpm, z[t], models, sensor.R)
        np.testing.assert_allclose(out.cbar[t], ref["cbar"], rtol=1e-12)
        np.testing.assert_allclose(out.loglik[t], ref["loglik"], rtol=1e-10)
        np.testing.assert_allclose(out.model_nis[t], ref["model_nis"], rtol=1e-9)
        np.testing.assert_allclose(out.mode_probs[t], ref["mu"], rtol=1e-9, atol=1e-14)
        np.testing.assert_allclose(state.mu[t], ref["mu"], rtol=1e-9, atol=1e-14)
        np.testing.assert_allclose(state.x[t], ref["x_models"], rtol=1e-10)
        np.testing.assert_allclose(state.P[t], ref["P_models"], rtol=1e-7, atol=1e-7)
        np.testing.assert_allclose(out.x[t], ref["x"], rtol=1e-10)
        np.testing.assert_allclose(out.P[t], ref["P"], rtol=1e-7, atol=1e-7)
        np.testing.assert_allclose(out.nis[t], ref["nis"], rtol=1e-8)
    assert out.detected.all()


# --------------------------------------------------------------------------- (3)


@pytest.mark.parametrize("per_tracker_tpm", [False, True])
def test_mix_against_loops(per_tracker_tpm: bool) -> None:
    rng = np.random.default_rng(31)
    N, M, n = 4, 3, 4
    x, P, mu = _random_posterior(rng, N, M, n)
    tpm = _random_tpm(rng, M, (N,) if per_tracker_tpm else ())
    cbar, x0, P0 = mix(mu, x, P, tpm)
    assert cbar.shape == (N, M) and x0.shape == (N, M, n) and P0.shape == (N, M, n, n)
    for t in range(N):
        pi = tpm[t] if per_tracker_tpm else tpm
        for j in range(M):
            c = sum(pi[i, j] * mu[t, i] for i in range(M))
            assert cbar[t, j] == pytest.approx(c, rel=1e-13)
            w = [pi[i, j] * mu[t, i] / c for i in range(M)]
            xj = sum(w[i] * x[t, i] for i in range(M))
            Pj = sum(w[i] * (P[t, i] + np.outer(x[t, i] - xj, x[t, i] - xj)) for i in range(M))
            np.testing.assert_allclose(x0[t, j], xj, rtol=1e-12)
            np.testing.assert_allclose(P0[t, j], Pj, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(cbar.sum(axis=1), 1.0, rtol=1e-13)


def test_mix_unreachable_model_stays_defined() -> None:
    rng = np.random.default_rng(32)
    x, P, _ = _random_posterior(rng, 1, 3)
    mu = np.array([[1.0, 0.0, 0.0]])
    tpm = np.array([[0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.0, 0.0, 1.0]])
    cbar, x0, P0 = mix(mu, x, P, tpm)
    np.testing.assert_allclose(cbar, [[0.5, 0.5, 0.0]])
    assert np.all(np.isfinite(x0)) and np.all(np.isfinite(P0))
    np.testing.assert_allclose(x0[0, 2], x[0, 0])  # falls back to mu
    np.testing.assert_allclose(x0[0, 0], x[0, 0])
    np.testing.assert_allclose(x0[0, 1], x[0, 0])


def test_update_mode_probs_against_loops() -> None:
    rng = np.random.default_rng(33)
    ll = rng.normal(-10.0, 3.0, (5, 3))
    cbar = rng.dirichlet(np.ones(3), size=5)
    mu = update_mode_probs(ll, cbar)
    for t in range(5):
        c = [np.exp(ll[t, j]) * cbar[t, j] for j in range(3)]
        np.testing.assert_allclose(mu[t], np.array(c) / sum(c), rtol=1e-12)


def test_combine_against_loops() -> None:
    rng = np.random.default_rng(34)
    x, P, mu = _random_posterior(rng, 4, 3)
    xh, Ph = combine(mu, x, P)
    assert xh.shape == (4, 4) and Ph.shape == (4, 4, 4)
    for t in range(4):
        xr = sum(mu[t, j] * x[t, j] for j in range(3))
        Pr = sum(mu[t, j] * (P[t, j] + np.outer(x[t, j] - xr, x[t, j] - xr)) for j in range(3))
        np.testing.assert_allclose(xh[t], xr, rtol=1e-13)
        np.testing.assert_allclose(Ph[t], Pr, rtol=1e-11, atol=1e-9)
        # the spread term makes the combined covariance at least the weighted mean covariance
        Pmean = sum(mu[t, j] * P[t, j] for j in range(3))
        assert np.linalg.eigvalsh(Ph[t] - Pmean).min() > -1e-9
    np.testing.assert_array_equal(Ph, np.swapaxes(Ph, -1, -2))


# --------------------------------------------------------------------------- (4)


@pytest.mark.parametrize(
    "loglik",
    [
        [-1e4, -1e4 - 2.0, -1e4 - 5.0],
        [-1e4, -2e4, -3e4],
        [-1e4, -1e4, -1e4],
        [-5000.0, -1e4, -800.0],
    ],
)
def test_log_domain_update_survives_tiny_likelihoods(loglik: list[float]) -> None:
    ll = np.array([loglik])
    cbar = np.array([[0.2, 0.5, 0.3]])
    assert np.all(np.exp(ll) == 0.0)  # the linear domain would divide 0 by 0
    mu = update_mode_probs(ll, cbar)
    assert np.all(np.isfinite(mu))
    np.testing.assert_allclose(mu, softmax(ll + np.log(cbar), axis=-1), rtol=1e-12, atol=1e-300)
    assert mu.sum() == pytest.approx(1.0, abs=1e-15)


def test_update_mode_probs_zero_cbar() -> None:
    mu = update_mode_probs(np.array([[-3.0, -1.0, -2.0]]), np.array([[0.5, 0.0, 0.5]]))
    assert mu[0, 1] == 0.0
    np.testing.assert_allclose(mu[0], [np.exp(-1) / (1 + np.exp(-1)), 0.0, 1 / (1 + np.exp(-1))])


def test_imm_step_with_extreme_innovation_stays_finite(make_imm) -> None:
    """A wild outlier: all likelihoods underflow in the linear domain, mu stays a distribution."""
    imm = make_imm(paper_bank(), Sonar())
    state = imm.init(np.array([3000.0, 4000.0, 20.0, 15.0]), np.diag([100.0, 100.0, 4.0, 4.0]))
    state, out = imm.step(state, stay_tpm(3, 0.995), np.array([[9000.0, 2.5]]))
    assert np.all(out.loglik < -1000)
    assert np.all(np.isfinite(out.mode_probs))
    assert out.mode_probs.sum() == pytest.approx(1.0)


# --------------------------------------------------------------------------- (5)


@pytest.mark.parametrize("filter_name", ["ukf", "ukf-cholesky", "ekf"])
def test_missed_detection(make_imm, filter_name: str) -> None:
    rng = np.random.default_rng(40)
    imm = make_imm(paper_bank(), Sonar(), filter_name)
    x, P, mu = _random_posterior(rng, 3, 3)
    tpm = stay_tpm(3, 0.9)
    z = Sonar().h(x[:, 0]) + rng.normal(0.0, 1.0, (3, 2)) * Sonar().sigma
    det = np.array([False, True, False])
    s_det, o_det = imm.step(IMMState(x, P, mu), tpm, z, det)
    _, o_all = imm.step(IMMState(x, P, mu), tpm, z)
    cbar, x0, P0 = mix(mu, x, P, tpm)
    xp, Pp = predict(x0, P0, imm.F, imm.Q)
    x_hat, P_hat = combine(cbar, xp, Pp)
    for t in (0, 2):
        np.testing.assert_allclose(o_det.mode_probs[t], cbar[t], rtol=1e-12)
        np.testing.assert_allclose(o_det.cbar[t], cbar[t], rtol=1e-12)
        np.testing.assert_allclose(s_det.x[t], xp[t], rtol=1e-13)
        np.testing.assert_allclose(s_det.P[t], Pp[t], rtol=1e-13)
        np.testing.assert_allclose(o_det.x[t], x_hat[t], rtol=1e-12)
        np.testing.assert_allclose(o_det.P[t], P_hat[t], rtol=1e-10)
        np.testing.assert_array_equal(o_det.loglik[t], 0.0)
        np.testing.assert_array_equal(o_det.model_nis[t], 0.0)
        assert o_det.nis[t] == 0.0
    np.testing.assert_array_equal(o_det.detected, det)
    # the detected tracker is unaffected by its neighbours' misses
    for f in ("x", "P", "mode_probs", "loglik", "model_nis", "nis"):
        np.testing.assert_allclose(getattr(o_det, f)[1], getattr(o_all, f)[1], rtol=1e-13)
    # and a real update differs from a prediction
    assert not np.allclose(o_all.mode_probs[0], cbar[0])


def test_run_with_missed_detections(paper_batch, make_imm) -> None:
    imm = make_imm(paper_bank(), Sonar())
    z = paper_batch.measurements.z[:3, 1:40]
    det = np.random.default_rng(41).random(z.shape[:2]) < 0.7
    res = imm.run(z, stay_tpm(3, 0.995), paper_batch.x0[:3], paper_batch.P0[:3], detected=det)
    np.testing.assert_array_equal(res.nis[~det], 0.0)
    assert np.all(res.nis[det] > 0)
    single = imm.run(
        z[1], stay_tpm(3, 0.995), paper_batch.x0[1], paper_batch.P0[1], detected=det[1]
    )
    np.testing.assert_allclose(single.x, res.x[1], rtol=1e-12)
    with pytest.raises(ConfigError, match="detected"):
        imm.run(z, stay_tpm(3, 0.995), paper_batch.x0[:3], paper_batch.P0[:3], detected=det[:2])


# --------------------------------------------------------------------------- (6), (7)


def test_run_single_equals_batched_rows(paper_batch, make_imm) -> None:
    imm = make_imm(paper_bank(), Sonar())
    z = paper_batch.measurements.z[:, 1:]
    tpm = stay_tpm(3, 0.995)
    batched = imm.run(z, tpm, paper_batch.x0, paper_batch.P0)
    assert batched.x.shape == (8, 150, 4)
    assert batched.P.shape == (8, 150, 4, 4)
    assert batched.mode_probs.shape == batched.loglik.shape == (8, 150, 3)
    assert batched.nis.shape == (8, 150)
    for r in (0, 3, 7):
        single = imm.run(z[r], tpm, paper_batch.x0[r], paper_batch.P0[r])
        assert single.x.shape == (150, 4)
        for f in ("x", "P", "mode_probs", "loglik", "model_nis", "nis"):
            # equal to rounding: batched BLAS products may round differently from N = 1
            a, b = getattr(single, f), getattr(batched, f)[r]
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * np.abs(b).max(), err_msg=f)


def test_run_per_tracker_tpm(paper_batch, make_imm) -> None:
    imm = make_imm(paper_bank(), Sonar())
    z = paper_batch.measurements.z[:2, 1:30]
    tpms = np.stack([stay_tpm(3, 0.995), stay_tpm(3, 0.6)])
    res = imm.run(z, tpms, paper_batch.x0[:2], paper_batch.P0[:2])
    for r in range(2):
        ref = imm.run(z[r], tpms[r], paper_batch.x0[r], paper_batch.P0[r])
        np.testing.assert_allclose(res.x[r], ref.x, rtol=1e-12)


def _draw_and_run(make_imm, seed: int):
    batch = draw_batch(RandomFamily(), Sonar(), 4, seed)
    res = make_imm(paper_bank(), Sonar()).run(
        batch.measurements.z[:, 1:], stay_tpm(3, 0.995), batch.x0, batch.P0
    )
    return batch, res


def test_reproducible_with_seed(make_imm) -> None:
    b1, r1 = _draw_and_run(make_imm, 5)
    b2, r2 = _draw_and_run(make_imm, 5)
    np.testing.assert_array_equal(b1.truth.states, b2.truth.states)
    np.testing.assert_array_equal(b1.measurements.z, b2.measurements.z)
    for f in ("x", "P", "mode_probs", "loglik", "model_nis", "nis"):
        assert np.array_equal(getattr(r1, f), getattr(r2, f)), f
    b3, r3 = _draw_and_run(make_imm, 6)
    assert not np.array_equal(b1.measurements.z, b3.measurements.z)
    assert not np.array_equal(r1.x, r3.x)
    # run r of seed s is run 0 of seed s + r
    b4, _ = _draw_and_run(make_imm, 6)
    np.testing.assert_array_equal(b1.truth.states[1], b4.truth.states[0])
    np.testing.assert_array_equal(b1.measurements.z[1], b4.measurements.z[0])


# --------------------------------------------------------------------------- engines


@pytest.mark.parametrize(
    ("bank", "sensor", "filter_name"),
    [
        (paper_bank(), Sonar(), "ukf"),
        (paper_bank(), Sonar(), "ekf"),
        (paper_bank(), Sonar(position=(500.0, -300.0)), "ukf"),
        (paper_bank(), PositionSensor(sigma_pos=30.0), "kf"),
        (paper_bank(), PositionSensor(sigma_pos=30.0, sigma_vel=2.0), "ukf"),
        (
            (MotionModel("cv"), MotionModel("ct", 3.0), MotionModel("ca", q=(0.1,) * 6)),
            PositionSensor(sigma_pos=30.0),
            "kf",
        ),
    ],
    ids=["sonar-ukf", "sonar-ekf", "sonar-offset", "pos-kf", "posvel-ukf", "ca-bank-kf"],
)
def test_engines_agree(bank, sensor, filter_name: str) -> None:
    batch = draw_batch(RandomFamily(), sensor, 6, 77)
    z = batch.measurements.z[:, 1:]
    rng = np.random.default_rng(78)
    det = rng.random(z.shape[:2]) < 0.9
    tpm = _random_tpm(rng, len(bank), (6,))
    imms = [IMM(bank, sensor, filter_name, engine=e) for e in ("numpy", "compiled")]
    assert [imm.engine for imm in imms] == ["numpy", "compiled"]
    results = [imm.run(z, tpm, batch.x0, batch.P0, detected=det) for imm in imms]
    for f in ("x", "P", "mode_probs", "loglik", "model_nis", "nis"):
        a, b = getattr(results[0], f), getattr(results[1], f)
        np.testing.assert_allclose(
            a, b, rtol=1e-7, atol=1e-9 * max(1.0, np.abs(a).max()), err_msg=f
        )


@pytest.mark.parametrize("filter_name", ["ukf", "ukf-cholesky", "ekf"])
def test_compiled_tracker_does_not_depend_on_its_batch(filter_name: str) -> None:
    # The kernel runs trackers in blocks (TRACKER_BLOCK) and diagonalizes a block's covariances
    # together: a tracker's numbers must not depend on its block, its position or N.
    N = 2 * TRACKER_BLOCK + 5
    rng = np.random.default_rng(21)
    imm = IMM(paper_bank(), Sonar(), filter_name, engine="compiled")
    x, P, mu = _random_posterior(rng, N, 3)
    P[::9] = np.diag([2500.0, 2500.0, 25.0, 25.0])  # degenerate: converges in one sweep
    tpm = _random_tpm(rng, 3, (N,))
    z = Sonar().h(x[:, 0])
    det = rng.random(N) < 0.8

    def step(rows: np.ndarray | slice) -> list[np.ndarray]:
        state, out = imm.step(IMMState(x[rows], P[rows], mu[rows]), tpm[rows], z[rows], det[rows])
        fields = ("x", "P", "mode_probs", "loglik", "model_nis", "innovation", "nis")
        return [state.x, state.P, *(getattr(out, f) for f in fields)]

    batched = step(slice(None))
    order = rng.permutation(N)
    for a, b in zip(step(order), batched, strict=True):
        np.testing.assert_array_equal(a, b[order])
    for t in (0, TRACKER_BLOCK - 1, TRACKER_BLOCK, N - 1):
        for a, b in zip(step(slice(t, t + 1)), batched, strict=True):
            np.testing.assert_array_equal(a[0], b[t])


def test_unknown_engine() -> None:
    with pytest.raises(ConfigError, match="engine"):
        IMM(paper_bank(), Sonar(), engine="cuda")


class _CustomSonar:
    """A measurement model the compiled kernel does not know: the sonar behind another type."""

    def __init__(self) -> None:
        self._sonar = Sonar()

    def __getattr__(self, name: str):
        return getattr(self._sonar, name)


def test_auto_engine_compiles_the_built_in_sensors_only() -> None:
    assert IMM(paper_bank(), Sonar()).engine == "compiled"
    assert IMM(paper_bank(), PositionSensor(sigma_pos=30.0), "kf").engine == "compiled"
    assert IMM(paper_bank(), _CustomSonar()).engine == "numpy"
    with pytest.raises(ConfigError, match="engine 'compiled'"):
        IMM(paper_bank(), _CustomSonar(), engine="compiled")


# --------------------------------------------------------------------------- (8)


def test_long_run_stays_finite_and_pd(make_imm) -> None:
    family = RandomFamily(horizon=10_000, n_segments=(50, 200), min_duration=10)
    batch = draw_batch(family, Sonar(), 4, 2024)
    assert batch.horizon == 10_000
    imm = make_imm(paper_bank(), Sonar(), "ukf")
    res = imm.run(batch.measurements.z[:, 1:], stay_tpm(3, 0.995), batch.x0, batch.P0)
    for f in ("x", "P", "mode_probs", "loglik", "model_nis", "nis"):
        assert np.all(np.isfinite(getattr(res, f))), f
    np.testing.assert_allclose(res.mode_probs.sum(-1), 1.0, atol=1e-12)
    P_end = res.P[:, -1]
    np.testing.assert_allclose(P_end, np.swapaxes(P_end, -1, -2), rtol=1e-12, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(P_end) > 0)
    # every step's covariance stays positive definite, not just the last one
    assert np.all(np.linalg.eigvalsh(res.P) > 0)
    # and the filter still tracks: no divergence
    err = np.linalg.norm(res.x[..., :2] - batch.truth.states[:, 1:, :2], axis=-1)
    assert np.sqrt(np.mean(err[:, -1000:] ** 2)) < 60.0


def test_six_dim_bank_with_ca_runs(make_imm) -> None:
    bank = (
        MotionModel("cv"),
        MotionModel("ct", 4.0),
        MotionModel("ca", q=(0.1, 0.1, 0.12, 0.12, 0.05, 0.05)),
    )
    imm = make_imm(bank, PositionSensor(sigma_pos=10.0), "kf")
    assert imm.n == 6
    state = imm.init(np.array([0.0, 0.0, 10.0, 0.0]), np.diag([100.0, 100.0, 25.0, 25.0]))
    assert state.x.shape == (1, 3, 6)
    np.testing.assert_array_equal(state.x[0, :, 4:], 0.0)
    assert np.all(np.diag(state.P[0, 0])[4:] > 0)
    # a target accelerating at 1 m/s^2 along x: the CA model must win
    t = np.arange(1, 61, dtype=float)
    rng = np.random.default_rng(50)
    z = np.stack([10.0 * t + 0.5 * t**2, np.zeros_like(t)], axis=1) + rng.normal(0, 10, (60, 2))
    res = imm.run(z, stay_tpm(3, 0.95), state.x[0, 0, :4], np.diag([100.0, 100.0, 25.0, 25.0]))
    assert res.x.shape == (60, 6)
    assert np.all(np.isfinite(res.P))
    late = res.mode_probs[-30:].mean(axis=0)
    assert np.argmax(late) == 2
    assert late[2] > 0.5
    # combined acceleration: the CA model's ~1 m/s^2 weighted with the others' ~0
    assert 0.4 < res.x[-1, 4] < 1.3
    assert abs(res.x[-1, 5]) < 0.3
    assert res.x[-1, 2] == pytest.approx(70.0, abs=3.0)
    np.testing.assert_allclose(res.x[-1, :2], [10.0 * 60 + 0.5 * 60**2, 0.0], atol=30.0)


# --------------------------------------------------------------------------- (9) errors


def _imm_and_state(make_imm):
    imm = make_imm(paper_bank(), Sonar())
    state = imm.init(np.array([3000.0, 4000.0, 20.0, 15.0]), np.diag([100.0, 100.0, 4.0, 4.0]))
    return imm, state


@pytest.mark.parametrize(
    "tpm",
    [
        np.array([[0.9, 0.05, 0.04], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]]),  # row sum 0.99
        np.array([[1.1, -0.05, -0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]]),  # negative
        np.full((2, 2), 0.5),  # wrong shape
        np.full((3, 4), 0.25),  # not square
        np.full(3, 1 / 3),  # 1-D
        np.array([[np.nan, 0.5, 0.5], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]]),
    ],
    ids=["row-sum", "negative", "2x2", "3x4", "1d", "nan"],
)
def test_bad_tpm(make_imm, tpm: np.ndarray) -> None:
    imm, state = _imm_and_state(make_imm)
    z = np.array([[5000.0, 0.9]])
    with pytest.raises(ConfigError, match="tpm"):
        imm.step(state, tpm, z)
    with pytest.raises(ConfigError, match="tpm"):
        imm.run(z, tpm, state.x[0, 0], state.P[0, 0])


def test_tpm_batch_size_mismatch(make_imm) -> None:
    imm, state = _imm_and_state(make_imm)
    with pytest.raises(ConfigError, match="tpm"):
        imm.step(state, np.stack([stay_tpm(3, 0.9)] * 2), np.array([[5000.0, 0.9]]))


@pytest.mark.parametrize(
    "P0",
    [
        np.diag([100.0, 100.0, -4.0, 4.0]),
        np.diag([100.0, 100.0, 0.0, 4.0]),
        np.array([[1.0, 2.0, 0, 0], [2.0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]),
        np.diag([100.0, 100.0, 4.0]),  # wrong shape
    ],
    ids=["negative", "singular", "indefinite", "shape"],
)
def test_bad_P0(P0: np.ndarray) -> None:
    imm = IMM(paper_bank(), Sonar())
    with pytest.raises(ConfigError, match="P0"):
        imm.init(np.array([3000.0, 4000.0, 20.0, 15.0]), P0)
    with pytest.raises(ConfigError, match="P0"):
        imm.run(np.array([[5000.0, 0.9]]), stay_tpm(3, 0.9), np.zeros(4), P0)


def test_asymmetric_or_nonfinite_P0() -> None:
    imm = IMM(paper_bank(), Sonar())
    P0 = np.diag([100.0, 100.0, 4.0, 4.0])
    P0[0, 1] = 5.0
    with pytest.raises(ConfigError, match="P0"):
        imm.init(np.zeros(4), P0)
    with pytest.raises(ConfigError, match="P0"):
        imm.init(np.zeros(4), np.diag([np.nan, 1.0, 1.0, 1.0]))
    # asymmetric at its own scale (an absolute tolerance let it through: the Cholesky factor
    # read only its lower triangle, the symmetric part indefinite), and rounding that is not
    small = np.eye(4) * 1e-10
    small[0, 1] = 9e-9
    with pytest.raises(ConfigError, match="P0 must be symmetric"):
        imm.init(np.zeros(4), small)
    rounded = np.diag([1e4, 1e4, 25.0, 25.0])
    rounded[0, 1], rounded[1, 0] = 1.0, 1.0 + 1e-12
    imm.init(np.zeros(4), rounded)


@pytest.mark.parametrize(
    "z",
    [
        np.array([5000.0, 0.9]),  # missing the tracker axis
        np.array([[5000.0, 0.9, 1.0]]),
        np.array([[5000.0, 0.9], [5000.0, 0.9]]),  # two z for one tracker
        np.array([[np.nan, 0.9]]),
        np.array([[5000.0, np.inf]]),
    ],
    ids=["1d", "m=3", "N=2", "nan", "inf"],
)
def test_bad_z_step(make_imm, z: np.ndarray) -> None:
    imm, state = _imm_and_state(make_imm)
    with pytest.raises(ConfigError, match="z"):
        imm.step(state, stay_tpm(3, 0.995), z)


@pytest.mark.parametrize(
    "z",
    [
        np.zeros((5, 3)),
        np.zeros(5),
        np.zeros((2, 5, 2, 1)),
        np.array([[5000.0, 0.9], [np.nan, 0.9]]),
    ],
    ids=["m=3", "1d", "4d", "nan"],
)
def test_bad_z_run(make_imm, z: np.ndarray) -> None:
    imm = make_imm(paper_bank(), Sonar())
    with pytest.raises(ConfigError, match="z"):
        imm.run(z, stay_tpm(3, 0.995), np.zeros(4) + 1000.0, np.eye(4))


def test_bad_constructor_and_init() -> None:
    with pytest.raises(ConfigError, match="models"):
        IMM((), Sonar())
    with pytest.raises(ConfigError, match="kf"):
        IMM(paper_bank(), Sonar(), "kf")
    with pytest.raises(ConfigError, match="filter"):
        IMM(paper_bank(), Sonar(), "pf")
    imm = IMM(paper_bank(), Sonar())
    with pytest.raises(ConfigError, match="mode_probs"):
        imm.init(np.zeros(4), np.eye(4), mode_probs=np.array([0.5, 0.6, -0.1]))
    with pytest.raises(ConfigError, match="mode_probs"):
        imm.init(np.zeros(4), np.eye(4), mode_probs=np.array([0.5, 0.2, 0.2]))
    with pytest.raises(ConfigError, match="x0"):
        imm.init(np.zeros(5), np.eye(5))


def test_init_uniform_and_custom_probs() -> None:
    imm = IMM(paper_bank(), Sonar())
    s = imm.init(np.ones((2, 4)), np.eye(4))
    assert s.x.shape == (2, 3, 4) and s.P.shape == (2, 3, 4, 4)
    np.testing.assert_allclose(s.mu, 1.0 / 3.0)
    s = imm.init(np.ones(4), np.eye(4), mode_probs=np.array([0.2, 0.3, 0.5]))
    np.testing.assert_allclose(s.mu, [[0.2, 0.3, 0.5]])
