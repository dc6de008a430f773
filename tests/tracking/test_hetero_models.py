"""Heterogeneous bank (seed 002): conversions, CT/CTRA kinematics, EKF IMM against the KF IMM."""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from imm_gym import (
    IMM,
    ConfigError,
    PositionSensor,
    Sonar,
    draw_batch,
    paper_bank,
    paper_scenario,
    stay_tpm,
)
from imm_gym.tracking.conversions import (
    SPACES,
    conversion,
    convert,
    ct_transition_nl,
    ctra_transition,
    g_integrals,
)
from imm_gym.tracking.hetero import HeteroBank, HeteroIMM, HeteroModel, LinearModel, linear_models
from imm_gym.tracking.imm import IMMState, run
from imm_gym.tracking.models import MotionModel

finite = st.floats(-50.0, 50.0, allow_nan=False)
speed = st.floats(0.5, 30.0)
angle = st.floats(-math.pi, math.pi)
rate = st.floats(-1.0, 1.0)


def random_state(space: str, rng: np.random.Generator) -> np.ndarray:
    x = rng.normal(size=SPACES[space]) * 5.0
    if space in ("ct", "ctra"):
        x[2] = abs(x[2]) + 1.0
        x[3] = rng.uniform(-3.0, 3.0)
        x[4] = rng.uniform(-0.5, 0.5)
    return x


def numeric_jacobian(f, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((f(x + d) - f(x - d)) / (2 * eps))
    return np.stack(cols, axis=-1)


@settings(max_examples=60, deadline=None)
@given(finite, finite, speed, angle)
def test_ncv_ctra_ncv_round_trip(px: float, py: float, v: float, psi: float) -> None:
    x = np.array([px, py, v * math.cos(psi), v * math.sin(psi)])
    ctra, _ = conversion(x, "ncv", "ctra")
    np.testing.assert_allclose(ctra, [px, py, v, psi, 0.0, 0.0], atol=1e-9)
    back, _ = conversion(ctra, "ctra", "ncv")
    np.testing.assert_allclose(back, x, atol=1e-9)
    via_ct, _ = conversion(conversion(x, "ncv", "ct")[0], "ct", "ncv")
    np.testing.assert_allclose(via_ct, x, atol=1e-9)


def test_a_state_at_rest_has_heading_zero_whatever_the_sign_of_its_zeros() -> None:
    """A velocity of (-0, 0) (what CT -> NCV gives at v = 0 heading west) is at rest: heading 0,
    as the Jacobian takes it, not atan2's pi (which flipped the position-velocity
    cross-covariances through a round trip)."""
    P = np.eye(4)
    P[0, 2] = P[2, 0] = 0.5
    for vx in (0.0, -0.0):
        x = np.array([1.0, 2.0, vx, 0.0])
        ct, P_ct = convert(x, P, "ncv", "ct")
        assert ct[3] == 0.0
        _, P_back = convert(ct, P_ct, "ct", "ncv")
        assert P_back[0, 2] > 0.0


@pytest.mark.parametrize("src", sorted(SPACES))
@pytest.mark.parametrize("dst", sorted(SPACES))
def test_conversion_jacobians_match_finite_differences(src: str, dst: str) -> None:
    rng = np.random.default_rng(zlib.crc32(f"{src}-{dst}".encode()))  # hash() is salted
    for _ in range(5):
        x = random_state(src, rng)
        _, J = conversion(x, src, dst)
        np.testing.assert_allclose(
            J, numeric_jacobian(lambda y: conversion(y, src, dst)[0], x), atol=1e-6
        )


def test_conversion_jacobian_of_round_trip_is_identity_on_velocity() -> None:
    x = np.array([1.0, 2.0, 3.0, -4.0])
    ctra, J1 = conversion(x, "ncv", "ctra")
    _, J2 = conversion(ctra, "ctra", "ncv")
    np.testing.assert_allclose(J2 @ J1, np.eye(4), atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-3, 3), min_size=16, max_size=16), speed, angle)
def test_converted_covariance_is_symmetric_psd(entries: list[float], v: float, psi: float) -> None:
    A = np.array(entries).reshape(4, 4)
    P = A @ A.T + 1e-3 * np.eye(4)
    x = np.array([0.0, 0.0, v * math.cos(psi), v * math.sin(psi)])
    for dst in ("ct", "ctra"):
        _, Pc = convert(x, P, "ncv", dst)
        np.testing.assert_allclose(Pc, Pc.T, atol=1e-12)
        assert np.linalg.eigvalsh(Pc).min() > -1e-9 * np.abs(Pc).max()


def test_zero_speed_conversion_is_finite() -> None:
    x, P = convert(np.zeros(4), np.eye(4), "ncv", "ctra")
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(P))


def _in_space(x: np.ndarray, P: np.ndarray, src: str) -> tuple[np.ndarray, np.ndarray]:
    """An NCV state ``(..., 4)`` and covariance in ``src``: as given for ``"ncv"``; for
    ``"cart6"`` ``[x, 0, 0]`` and ``blockdiag(P, I_2)`` (a unit-variance acceleration)."""
    if src == "ncv":
        return x, P
    x6 = np.concatenate([x, np.zeros((*x.shape[:-1], 2))], axis=-1)
    P6 = np.zeros((*P.shape[:-2], 6, 6))
    P6[..., :4, :4] = P
    P6[..., 4, 4] = P6[..., 5, 5] = 1.0
    return x6, P6


@pytest.mark.parametrize("src", ["ncv", "cart6"])
@pytest.mark.parametrize("dst", ["ct", "ctra"])
def test_heading_variance_is_capped_where_the_speed_is_within_three_sigma(
    src: str, dst: str
) -> None:
    """Below ``v = 3 sqrt(lambda_max(P_v))`` the heading's variance is at most a uniform
    heading's, ``pi^2 / 3``, and uncorrelated; above it the conversion is ``J P J^T`` (``J`` of
    the NCV velocity: a CA source's acceleration does not enter CT/CTRA)."""
    P = np.diag([4.0, 4.0, 9.0, 4.0])
    P[0, 2] = P[2, 0] = 1.0
    for v in (0.0, 1e-3, 1.0, 8.9):
        x = np.array([1.0, 2.0, v * 0.6, v * 0.8])
        _, Pc = convert(*_in_space(x, P, src), src, dst)
        _, J = conversion(x, "ncv", dst)
        raw = J @ P @ J.T
        assert Pc[3, 3] == pytest.approx(min(raw[3, 3], math.pi**2 / 3))
        np.testing.assert_array_equal(np.delete(Pc[3], 3), 0.0)
        np.testing.assert_array_equal(np.delete(Pc[:, 3], 3), 0.0)
        keep = [i for i in range(len(Pc)) if i != 3]
        np.testing.assert_allclose(Pc[np.ix_(keep, keep)], raw[np.ix_(keep, keep)])
    x = np.array([1.0, 2.0, 9.1 * 0.6, 9.1 * 0.8])  # 3 sigma = 9
    _, J = conversion(x, "ncv", dst)
    np.testing.assert_allclose(convert(*_in_space(x, P, src), src, dst)[1], J @ P @ J.T,
                               rtol=1e-14, atol=0.0)
    # a batch: only the slow rows are capped
    xs = np.array([[0.0, 0.0, 1e-4, 0.0], [0.0, 0.0, 30.0, 0.0]])
    _, Pb = convert(*_in_space(xs, np.stack([P, P]), src), src, dst)
    assert Pb[0, 3, 3] == pytest.approx(math.pi**2 / 3)
    assert Pb[1, 3, 3] == pytest.approx(4.0 / 900.0)


def test_a_track_started_at_rest_keeps_a_bounded_velocity_covariance() -> None:
    """A start at (or near) zero speed: the CT/CTRA models' heading is capped, so the combined
    velocity variance after one step stays of the order of ``P0``'s (it reached 2e11 m²/s²)."""
    sensor = Sonar()
    imm = HeteroIMM(HeteroBank(), sensor, T=1.0)
    P0 = np.diag([400.0, 400.0, 900.0, 900.0])
    truth = np.array([[3020.0, 4515.0, 20.0, 15.0]])
    for v0 in (0.0, 1e-3, 1.0):
        state = imm.init(np.array([[3000.0, 4500.0, v0, 0.0]]), P0)
        assert np.all(state.P[0, 1:, 3, 3] <= math.pi**2 / 3)
        _, out = imm.step(state, stay_tpm(3, 0.95), sensor.h(truth))
        assert np.all(np.linalg.eigvalsh(out.P[0, 2:, 2:]) < 1e4)


@pytest.mark.parametrize(
    ("x", "src", "dst"),
    [(np.zeros(4), "ct", "ncv"), (np.zeros(5), "ctra", "ncv"), (np.zeros(4), "ncv", "polar")],
)
def test_incompatible_conversion_raises(x: np.ndarray, src: str, dst: str) -> None:
    with pytest.raises(ConfigError, match="state space"):
        conversion(x, src, dst)


@pytest.mark.parametrize("theta", [0.0, 1e-9, 1e-4, 0.3, 0.4999, 0.5, 0.7, 2.0, -1.5])
def test_g_integrals_match_quadrature(theta: float) -> None:
    tau = np.linspace(0.0, 1.0, 20001)
    for n, g in enumerate(g_integrals(np.array(theta))):
        f = tau**n * np.exp(1j * theta * tau)
        ref = np.sum((f[1:] + f[:-1]) / 2) * (tau[1] - tau[0])
        assert abs(g - ref) < 1e-8


@settings(max_examples=40, deadline=None)
@given(finite, finite, speed, angle, st.floats(0.01, 1.0), st.sampled_from([-1.0, 1.0]))
def test_ct_matches_circular_motion(
    px: float, py: float, v: float, psi: float, w: float, sign: float
) -> None:
    w *= sign
    T = 0.7
    out, _ = ct_transition_nl(np.array([px, py, v, psi, w]), T)
    r = v / w
    cx, cy = px - r * math.sin(psi), py + r * math.cos(psi)
    expect = [cx + r * math.sin(psi + w * T), cy - r * math.cos(psi + w * T), v, psi + w * T, w]
    np.testing.assert_allclose(out, expect, atol=1e-9 * max(1.0, abs(r)))


@pytest.mark.parametrize("w", [0.0, 1e-7, 0.3, -0.8, 2.5])
@pytest.mark.parametrize("a", [0.0, 1.5, -2.0])
def test_ctra_matches_accelerating_motion(w: float, a: float) -> None:
    x = np.array([3.0, -1.0, 8.0, 0.4, w, a])
    T = 0.5
    out, _ = ctra_transition(x, T)
    t = np.linspace(0.0, T, 40001)
    vel = (8.0 + a * t) * np.exp(1j * (0.4 + w * t))
    dp = np.sum((vel[1:] + vel[:-1]) / 2) * (t[1] - t[0])
    np.testing.assert_allclose(out[:2], [3.0 + dp.real, -1.0 + dp.imag], atol=1e-8)
    np.testing.assert_allclose(out[2:], [8.0 + a * T, 0.4 + w * T, w, a], atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(finite, finite, speed, angle, st.floats(-3.0, 3.0))
def test_zero_turn_rate_is_the_straight_line_limit(
    px: float, py: float, v: float, psi: float, a: float
) -> None:
    T = 0.1
    u = np.array([math.cos(psi), math.sin(psi)])
    ct, _ = ct_transition_nl(np.array([px, py, v, psi, 0.0]), T)
    np.testing.assert_allclose(ct[:2], np.array([px, py]) + v * T * u, atol=1e-12)
    ctra, _ = ctra_transition(np.array([px, py, v, psi, 0.0, a]), T)
    np.testing.assert_allclose(
        ctra[:2], np.array([px, py]) + (v * T + a * T * T / 2) * u, atol=1e-12
    )
    near, _ = ctra_transition(np.array([px, py, v, psi, 1e-10, a]), T)
    np.testing.assert_allclose(near, ctra, atol=1e-9)


@pytest.mark.parametrize("w", [0.0, 1e-8, 0.1, 4.99, 5.01, -3.0])
def test_transition_jacobians_match_finite_differences(w: float) -> None:
    T = 0.1
    x = np.array([1.0, 2.0, 7.0, -2.0, w, 0.8])
    _, F = ctra_transition(x, T)
    np.testing.assert_allclose(
        F, numeric_jacobian(lambda y: ctra_transition(y, T)[0], x), atol=1e-7
    )
    _, F5 = ct_transition_nl(x[:5], T)
    np.testing.assert_allclose(
        F5, numeric_jacobian(lambda y: ct_transition_nl(y, T)[0], x[:5]), atol=1e-7
    )


ASYMMETRIC_TPM = np.array([[0.97, 0.02, 0.01], [0.30, 0.60, 0.10], [0.05, 0.45, 0.50]])


@pytest.mark.parametrize("tpm", [stay_tpm(3, 0.9), ASYMMETRIC_TPM], ids=["stay", "asymmetric"])
def test_ekf_engine_equals_kalman_imm_on_linear_bank(tpm: np.ndarray) -> None:
    """The heterogeneous engine with the linear CV/CT(±4°/s) bank is the classical KF-IMM, also
    with an asymmetric TPM (``pi_ij`` = P(i -> j): a transposed TPM in the mixing differs)."""
    rng = np.random.default_rng(3)
    sensor = PositionSensor(sigma_pos=20.0, sigma_vel=2.0)
    N, K = 4, 30
    z = rng.normal(size=(N, K, 4)) * [50, 50, 3, 3] + [3000, 4000, 20, 15]
    x0 = np.tile([3000.0, 4000.0, 20.0, 15.0], (N, 1))
    P0 = np.diag([400.0, 400.0, 25.0, 25.0])
    ref = IMM(paper_bank(), sensor, filter="kf", engine="numpy").run(z, tpm, x0, P0)
    imm = HeteroIMM(linear_models(paper_bank()), sensor, T=1.0)
    state = imm.init(x0, P0, np.full(3, 1 / 3))
    for k in range(K):
        state, out = imm.step(state, tpm, z[:, k])
        np.testing.assert_allclose(out.x, ref.x[:, k], rtol=1e-10, atol=1e-8)
        np.testing.assert_allclose(out.P, ref.P[:, k], rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(out.mode_probs, ref.mode_probs[:, k], atol=1e-10)
        np.testing.assert_allclose(out.nis, ref.nis[:, k], rtol=1e-8)


def test_ncv_ekf_step_is_the_kalman_formula() -> None:
    sensor = PositionSensor(sigma_pos=1.0, sigma_vel=0.5)
    model = HeteroModel("ncv", (0.6,))
    imm = HeteroIMM([model], sensor, T=0.1)
    x0, P0 = np.array([1.0, 2.0, 3.0, 4.0]), np.diag([1.0, 2.0, 0.5, 0.5])
    z = np.array([[1.5, 2.2, 2.9, 4.2]])
    _, out = imm.step(imm.init(x0, P0), np.eye(1), z)
    _, F = model.transition(x0[None], 0.1)
    Q = model.noise(x0[None], 0.1)[0]
    x_pred, P_pred = F[0] @ x0, F[0] @ P0 @ F[0].T + Q
    S = P_pred + sensor.R
    K = P_pred @ np.linalg.inv(S)
    np.testing.assert_allclose(out.x[0], x_pred + K @ (z[0] - x_pred), atol=1e-12)
    np.testing.assert_allclose(out.P[0], (np.eye(4) - K) @ P_pred, atol=1e-12)


def test_mixing_averages_headings_across_the_branch_cut() -> None:
    sensor = PositionSensor(sigma_pos=1.0, sigma_vel=0.5)
    imm = HeteroIMM(HeteroBank(models=("ct", "ctra")), sensor, T=0.1)
    state = imm.init(np.array([0.0, 0.0, -10.0, 0.01]), np.eye(4), np.array([0.5, 0.5]))
    state.x[0, 1, 3] = -math.pi + 0.01  # model 2 heading just across the cut
    state.x[0, 0, 3] = math.pi - 0.01
    _, x0s, _ = imm.mix(state, np.full((2, 2), 0.5))
    for x0 in x0s:
        assert abs(abs(x0[0, 3]) - math.pi) < 0.02


def test_heterogeneous_bank_validation() -> None:
    with pytest.raises(ConfigError, match="q_scale"):
        HeteroBank(q_scale=(1.0, -1.0, 1.0))
    with pytest.raises(ConfigError, match="sigma"):
        HeteroBank(sigma_ct=(-1.0, 0.5))
    with pytest.raises(ConfigError, match="models"):
        HeteroBank(models=("ncv", "ca"))
    with pytest.raises(ConfigError, match="q_scale"):
        HeteroModel("ncv", (0.6,), q_scale=0.0)
    with pytest.raises(ConfigError, match="ekf"):
        HeteroIMM(HeteroBank(), PositionSensor(), filter="ukf")


def test_failed_tracker_is_flagged_not_raised() -> None:
    sensor = PositionSensor(sigma_pos=0.5, sigma_vel=0.5)
    imm = HeteroIMM(HeteroBank(), sensor, T=0.1)
    state = imm.init(np.tile([0.0, 0.0, 5.0, 0.0], (2, 1)), np.eye(4))
    state.P[1] = np.nan
    _, out = imm.step(state, stay_tpm(3, 0.9), np.zeros((2, 4)), allow_failure=True)
    assert out.failed.tolist() == [False, True]
    assert np.all(np.isfinite(out.x[0]))
    with pytest.raises(np.linalg.LinAlgError):
        imm.step(state, stay_tpm(3, 0.9), np.zeros((2, 4)))


@pytest.mark.parametrize("sensor", [Sonar(), PositionSensor(sigma_pos=0.5, sigma_vel=0.5)])
def test_a_failed_tracker_stays_flagged_and_the_others_run_on(sensor) -> None:
    """Steps after a failure: the failed tracker's NaN probabilities do not stop the batch,
    and the other tracker's numbers are those it gets alone."""
    imm = HeteroIMM(HeteroBank(), sensor, T=1.0)
    x0 = np.tile([3000.0, 4500.0, 20.0, 15.0], (2, 1))
    state = imm.init(x0, np.diag([100.0, 100.0, 25.0, 25.0]))
    alone = IMMState(state.x[:1], state.P[:1], state.mu[:1])
    state.P[1] = np.nan
    tpm = stay_tpm(3, 0.95)
    for k in range(1, 4):
        truth = x0[:1] + np.array([20.0 * k, 15.0 * k, 0.0, 0.0])
        z = np.repeat(sensor.h(truth), 2, axis=0)
        state, out = imm.step(state, tpm, z, allow_failure=True)
        alone, out_alone = imm.step(alone, tpm, z[:1])
        assert out.failed.tolist() == [False, True]
        assert np.isnan(out.x[1]).all() and np.isnan(state.mu[1]).all()
        np.testing.assert_allclose(out.x[0], out_alone.x[0], rtol=1e-12)


def test_a_factorization_that_fails_past_the_checks_flags_its_tracker() -> None:
    """A process noise so large that the update's factorization fails although the innovation
    covariance passed the pre-check: that tracker is flagged, the run goes on."""
    sensor = Sonar()
    imm = HeteroIMM(HeteroBank(), sensor, T=1.0)
    truth = np.array([3000.0, 4500.0, 20.0, 15.0])
    K = 20
    path = truth + np.arange(1, K + 1)[:, None] * np.array([20.0, 15.0, 0.0, 0.0])
    z = np.broadcast_to(sensor.h(path), (2, K, 2)).copy()
    q = np.ones((2, 3))
    q[1] = 1e20
    out = run(imm, z, stay_tpm(3, 0.95), np.broadcast_to(truth, (2, 4)),
              np.diag([100.0, 100.0, 25.0, 25.0]), allow_failure=True, q_scale=q)
    assert out.failed.tolist() == [False, True]
    assert np.isfinite(out.x[0]).all()


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-3, 3), min_size=36, max_size=36), speed, angle, rate, finite)
def test_covariance_round_trips_through_ctra(
    entries: list[float], v: float, psi: float, w: float, p: float
) -> None:
    """NCV -> CTRA -> NCV and CT -> CTRA -> CT give back (x, P): the Jacobians compose to I
    (where the speed is 4 standard deviations from 0, outside the heading cap)."""
    A = np.array(entries).reshape(6, 6)
    x_ncv = np.array([p, -p, v * math.cos(psi), v * math.sin(psi)])
    P_ncv = A[:4, :4] @ A[:4, :4].T + 1e-3 * np.eye(4)
    d = np.array([1.0, 1.0, 1.0, 1.0])
    d[2:] = v / (4.0 * math.sqrt(np.linalg.eigvalsh(P_ncv[2:, 2:])[-1]))
    P_ncv = d[:, None] * P_ncv * d[None, :]
    x, P = convert(*convert(x_ncv, P_ncv, "ncv", "ctra"), "ctra", "ncv")
    np.testing.assert_allclose(x, x_ncv, atol=1e-9)
    np.testing.assert_allclose(P, P_ncv, rtol=1e-9, atol=1e-9 * np.abs(P_ncv).max())
    x_ct = np.array([p, -p, v, psi, w])
    P_ct = A[:5, :5] @ A[:5, :5].T + 1e-3 * np.eye(5)
    x, P = convert(*convert(x_ct, P_ct, "ct", "ctra"), "ctra", "ct")
    np.testing.assert_array_equal(x, x_ct)
    np.testing.assert_array_equal(P, P_ct)


def test_jacobian_entries_derived_by_hand() -> None:
    """Seed 002 eqs. (9) and (13) at a point: d v / d v_x = v_x / v, d psi / d v_x = -v_y / v^2,
    d v_y / d psi = v cos(psi)."""
    _, J = conversion(np.array([0.0, 0.0, 3.0, 4.0]), "ncv", "ctra")
    assert J[2, 2] == pytest.approx(3 / 5) and J[2, 3] == pytest.approx(4 / 5)
    assert J[3, 2] == pytest.approx(-4 / 25) and J[3, 3] == pytest.approx(3 / 25)
    assert np.all(J[4:] == 0.0)
    _, J = conversion(np.array([0.0, 0.0, 5.0, 0.3, 0.1, 2.0]), "ctra", "ncv")
    assert J[3, 3] == pytest.approx(5 * math.cos(0.3))
    assert J[2, 3] == pytest.approx(-5 * math.sin(0.3))
    assert np.all(J[:, 4:] == 0.0)


@pytest.mark.parametrize("v", [0.0, 1e-9, 1e-3])
def test_speed_row_of_the_jacobian_is_the_unit_direction_at_any_speed(v: float) -> None:
    _, J = conversion(np.array([0.0, 0.0, v, 0.0]), "ncv", "ct")
    np.testing.assert_allclose(J[2, 2:], [1.0, 0.0])  # d speed / d velocity, even below V_MIN
    assert np.all(np.isfinite(J)) and J[3, 3] > 0


def test_covariance_of_the_wrong_space_is_rejected() -> None:
    with pytest.raises(ConfigError, match="covariance is 4 x 4"):
        convert(np.zeros(4), np.eye(5), "ncv", "ct")


def test_process_noise_is_table_one() -> None:
    """Q of each model in closed form (seed 002 Table I noise, module docstring of hetero)."""
    T, psi = 0.1, 0.7
    c, s = math.cos(psi), math.sin(psi)
    x = np.array([0.0, 0.0, 5.0, psi, 0.1, 0.5])
    Q = HeteroModel("ncv", (0.6,)).noise(x[:4], T)
    block = 0.36 * np.array([[T**3 / 3, T**2 / 2], [T**2 / 2, T]])
    np.testing.assert_allclose(Q, np.kron(block, np.eye(2)), atol=1e-15)
    Q = HeteroModel("ct", (2.4, 0.6)).noise(x[:5], T)
    g_v = np.array([T**2 / 2 * c, T**2 / 2 * s, T, 0.0, 0.0])
    g_w = np.array([0.0, 0.0, 0.0, T**2 / 2, T])
    np.testing.assert_allclose(Q, 2.4**2 * np.outer(g_v, g_v) + 0.6**2 * np.outer(g_w, g_w))
    Q = HeteroModel("ctra", (20.0, 3.0)).noise(x, T)
    g_j = np.array([T**3 / 6 * c, T**3 / 6 * s, T**2 / 2, 0.0, 0.0, T])
    g_w = np.array([0.0, 0.0, 0.0, T**2 / 2, T, 0.0])
    np.testing.assert_allclose(Q, 400.0 * np.outer(g_j, g_j) + 9.0 * np.outer(g_w, g_w))
    bank = HeteroBank().build()
    assert [m.sigma for m in bank] == [(0.6,), (2.4, 0.6), (20.0, 3.0)]


def test_ct_ekf_step_and_likelihood_are_the_ekf_formulas() -> None:
    """One CT model: x^- = f(x0), P^- = F P0 F^T + Q, H = H(g(x^-)) J, log N(nu; 0, S)."""
    from scipy.stats import multivariate_normal

    sensor = PositionSensor(sigma_pos=0.5, sigma_vel=0.5)
    model = HeteroModel("ct", (2.4, 0.6))
    imm = HeteroIMM([model], sensor, T=0.1)
    state = imm.init(np.array([1.0, 2.0, 6.0, 3.0]), np.diag([0.5, 0.5, 1.0, 1.0]))
    state.x[0, 0, 4] = 0.3  # turning
    x0, P0 = state.x[0, 0, :5], state.P[0, 0, :5, :5]
    z = np.array([[1.7, 2.2, 5.5, 3.6]])
    post, out = imm.step(state, np.eye(1), z)
    x_pred, F = ct_transition_nl(x0, 0.1)
    P_pred = F @ P0 @ F.T + model.noise(x0, 0.1)
    h, J = conversion(x_pred, "ct", "ncv")
    S = J @ P_pred @ J.T + sensor.R  # position+velocity sensor: H(cart) = I
    K = P_pred @ J.T @ np.linalg.inv(S)
    np.testing.assert_allclose(post.x[0, 0, :5], x_pred + K @ (z[0] - h), atol=1e-12)
    expect = multivariate_normal(h, S).logpdf(z[0])
    assert out.loglik[0, 0] == pytest.approx(expect, rel=1e-12)
    assert out.nis[0] == pytest.approx((z[0] - h) @ np.linalg.solve(S, z[0] - h), rel=1e-10)


def test_mixed_heading_covariance_across_the_branch_cut_stays_small() -> None:
    sensor = PositionSensor(sigma_pos=1.0, sigma_vel=0.5)
    imm = HeteroIMM(HeteroBank(models=("ct", "ctra")), sensor, T=0.1)
    state = imm.init(np.array([0.0, 0.0, -10.0, 0.01]), np.eye(4), np.array([0.5, 0.5]))
    state.x[0, 1, 3] = -math.pi + 0.01
    state.x[0, 0, 3] = math.pi - 0.01
    heading_var = state.P[0, 0, 3, 3]
    _, _, P0s = imm.mix(state, np.full((2, 2), 0.5))
    for P0 in P0s:  # spread of 0.02 rad, not of 2 pi - 0.02
        assert P0[0, 3, 3] < heading_var + 1e-3


def test_per_tracker_noise_scales_are_validated() -> None:
    sensor = PositionSensor(sigma_pos=0.5, sigma_vel=0.5)
    imm = HeteroIMM(HeteroBank(), sensor, T=0.1)
    state = imm.init(np.tile([0.0, 0.0, 5.0, 0.0], (2, 1)), np.eye(4))
    z, tpm = np.zeros((2, 4)), stay_tpm(3, 0.9)
    with pytest.raises(ConfigError, match=r"q_scale must be finite and in \(0, inf\)"):
        imm.step(state, tpm, z, q_scale=np.array([[1.0, -1.0, 1.0], [1.0, 1.0, 1.0]]))
    with pytest.raises(ConfigError, match=r"q_scale must have shape \(2, 3\)"):
        imm.step(state, tpm, z, q_scale=np.ones((2, 2)))
    with pytest.raises(ConfigError, match="r_scale must be finite"):
        imm.step(state, tpm, z, r_scale=np.array([1.0, 0.0]))
    with pytest.raises(ConfigError, match=r"model\.dim must be 4 or 6"):
        LinearModel(paper_bank()[0], dim=5)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31), speed, angle, st.floats(0.05, 5.0))
def test_model_covariances_stay_symmetric_positive_definite(
    seed: int, v: float, psi: float, noise: float
) -> None:
    """Mixing with conversions, EKF prediction and Joseph update keep every model's P PD."""
    rng = np.random.default_rng(seed)
    sensor = PositionSensor(sigma_pos=0.5, sigma_vel=0.5)
    imm = HeteroIMM(HeteroBank(), sensor, T=0.1)
    x = np.array([0.0, 0.0, v * math.cos(psi), v * math.sin(psi)])
    state = imm.init(x, np.diag([0.25, 0.25, 0.25, 0.25]))
    for _ in range(15):
        x = x + 0.1 * np.array([x[2], x[3], 0.0, 0.0])
        z = x + rng.normal(size=4) * noise
        state, out = imm.step(state, stay_tpm(3, 0.9), z[None])
        for j, n in enumerate(imm.dims):
            P = state.P[0, j, :n, :n]
            np.testing.assert_allclose(P, P.T, atol=1e-12 * np.abs(P).max())
            assert np.linalg.eigvalsh(P).min() > 0
        assert np.linalg.eigvalsh(out.P[0]).min() > 0
        assert out.mode_probs.sum() == pytest.approx(1.0)


def test_headings_mix_around_the_model_that_weighs_most() -> None:
    """A CT model of almost no weight whose heading (0°) is on the far side from the others
    (±170°, i.e. both near 180°) does not pull the mixed heading across: it mixes to ≈ 180°."""
    imm = HeteroIMM(HeteroBank(), PositionSensor(sigma_pos=0.5, sigma_vel=0.5), T=0.1)
    v, rad = 10.0, np.deg2rad
    x, P = np.zeros((1, 3, 6)), np.zeros((1, 3, 6, 6))
    x[0, 0, :4] = [0.0, 0.0, v * np.cos(rad(170.0)), v * np.sin(rad(170.0))]  # NCV
    x[0, 1, :5] = [0.0, 0.0, v, 0.0, 0.0]  # CT, heading 0
    x[0, 2, :5] = [0.0, 0.0, v, rad(-170.0), 0.0]  # CTRA
    P[0, 0, :4, :4], P[0, 1, :5, :5], P[0, 2] = np.eye(4), np.eye(5), np.eye(6)
    state = IMMState(x, 0.1 * P, np.array([[0.5, 1e-6, 0.5 - 1e-6]]))
    _, x0s, _ = imm.mix(state, stay_tpm(3, 0.9))
    heading = np.rad2deg(x0s[1][0, 3])
    assert abs(abs(heading) - 180.0) < 0.5, heading


def test_per_tracker_q_scale_is_each_models_own_factor() -> None:
    """Tracker-wise ``q_scale[:, j]`` multiplies model j's ``Q``: the same as the bank's own
    ``q_scale``, and tracker by tracker."""
    rng = np.random.default_rng(5)
    sensor = PositionSensor(sigma_pos=0.5, sigma_vel=0.5)
    z = rng.normal(size=(2, 40, 4)) * 0.5 + np.array([0.0, 0.0, 5.0, 0.0])
    z[..., 0] += 0.5 * np.arange(40)
    tpm = stay_tpm(3, 0.9)
    x0, P0 = np.tile([0.0, 0.0, 5.0, 0.0], (2, 1)), 0.25 * np.eye(4)
    scales = np.array([[1.0, 5.0, 0.2], [0.3, 1.0, 4.0]])
    batched = run(HeteroIMM(HeteroBank(), sensor, T=0.1), z, tpm, x0, P0, q_scale=scales)
    for i in range(2):
        own = HeteroIMM(HeteroBank(q_scale=tuple(scales[i])), sensor, T=0.1)
        alone = run(own, z[i : i + 1], tpm, x0[i : i + 1], P0)
        np.testing.assert_allclose(batched.x[i], alone.x[0], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(batched.mode_probs[i], alone.mode_probs[0], atol=1e-12)


def test_initial_state_takes_the_banks_variances_and_probabilities() -> None:
    """Seed 002's bank starts at mu = (0.90, 0.08, 0.02); omega and a start at 0 with the bank's
    ``turn_rate_var`` / ``accel_var`` added to the converted ``P0``."""
    sensor = PositionSensor(sigma_pos=0.5, sigma_vel=0.5)
    x0 = np.array([[1.0, 2.0, 3.0, 4.0]])
    P0 = np.diag([0.5, 0.6, 1.0, 1.0])
    state = HeteroIMM(HeteroBank(), sensor, T=0.1).init(x0, P0)
    np.testing.assert_array_equal(state.mu, [[0.90, 0.08, 0.02]])
    bank = HeteroBank(turn_rate_var=0.3, accel_var=2.5)
    state = HeteroIMM(bank, sensor, T=0.1).init(x0, P0)
    np.testing.assert_array_equal(state.mu, [[0.90, 0.08, 0.02]])
    _, P_ct = convert(x0, P0[None], "ncv", "ct")
    _, P_ctra = convert(x0, P0[None], "ncv", "ctra")
    P_ct[0, 4, 4] += 0.3
    P_ctra[0, 4, 4] += 0.3
    P_ctra[0, 5, 5] += 2.5
    np.testing.assert_allclose(state.P[0, 0, :4, :4], P0)
    np.testing.assert_allclose(state.P[0, 1, :5, :5], P_ct[0])
    np.testing.assert_allclose(state.P[0, 2], P_ctra[0])
    assert state.P[0, 1, 4, 4] == pytest.approx(0.3) and state.P[0, 2, 5, 5] == pytest.approx(2.5)
    np.testing.assert_array_equal(state.x[0, 1, 4], 0.0)
    uniform = HeteroIMM(HeteroBank(models=("ncv", "ct")), sensor, T=0.1).init(x0, P0)
    np.testing.assert_array_equal(uniform.mu, [[0.5, 0.5]])


def test_a_ca_model_starts_with_the_default_acceleration_variance_on_both_axes() -> None:
    """A CA model (dim 6) beside a CT model, no :class:`HeteroBank`: the CA block of ``P0`` is
    the Cartesian ``P0`` with the documented default ``accel_var`` = 1.0 on ``ax`` and ``ay``
    and no cross-covariances; the CT model's ``omega`` gets the default ``turn_rate_var`` = 0.2."""
    models = (LinearModel(MotionModel("ca", q=(0.1,) * 6), 6), HeteroModel("ct", (2.4, 0.6)))
    x0 = np.array([[1.0, 2.0, 10.0, 0.0]])
    P0 = np.diag([1.0, 2.0, 4.0, 5.0])
    state = HeteroIMM(models, PositionSensor(sigma_pos=0.5, sigma_vel=0.5), T=1.0).init(x0, P0)
    expected = np.zeros((6, 6))
    expected[:4, :4] = P0
    expected[4, 4] = expected[5, 5] = 1.0
    np.testing.assert_array_equal(state.P[0, 0], expected)
    np.testing.assert_array_equal(state.x[0, 0], [1.0, 2.0, 10.0, 0.0, 0.0, 0.0])
    # the CT block at speed 10 along +x: heading variance P0_vy / v^2, omega 0.2
    np.testing.assert_allclose(np.diag(state.P[0, 1, :5, :5]), [1.0, 2.0, 4.0, 0.05, 0.2])


def test_a_finite_non_positive_definite_innovation_covariance_is_flagged() -> None:
    """A finite ``S`` that is not positive definite (here from a negative-definite ``P``) flags
    its tracker (or raises without ``allow_failure``); the other tracker runs on."""
    sensor = PositionSensor(sigma_pos=0.5, sigma_vel=0.5)
    imm = HeteroIMM(HeteroBank(), sensor, T=0.1)
    state = imm.init(np.tile([0.0, 0.0, 5.0, 0.0], (2, 1)), np.eye(4))
    state.P[1] = -1e3 * np.eye(state.P.shape[-1])
    assert np.all(np.isfinite(state.P))
    _, out = imm.step(state, stay_tpm(3, 0.9), np.zeros((2, 4)), allow_failure=True)
    assert out.failed.tolist() == [False, True]
    assert np.all(np.isfinite(out.x[0]))
    # the engine's own check (numpy's factorization would raise "Matrix is not positive definite")
    with pytest.raises(np.linalg.LinAlgError, match=r"innovation covariance not positive definite"):
        imm.step(state, stay_tpm(3, 0.9), np.zeros((2, 4)))


@pytest.mark.parametrize("case", ["z", "P0"])
def test_a_cycle_whose_outputs_are_not_finite_is_failed(case: str) -> None:
    """A measurement of 1e160 m, or a covariance of 1e160 m², overflows the NIS: every
    likelihood is 0, the mode probabilities 0/0. Flagged (or raised), not NaN outputs with
    ``failed`` False; the other trackers run on."""
    batch = draw_batch(paper_scenario(), Sonar(), 3, 0)
    P0, z = batch.P0.copy(), batch.measurements.z[:, 1].copy()
    if case == "z":
        z[1, 0] = 1e160
    else:
        P0[1] *= 1e156
    imm = HeteroIMM(HeteroBank(), Sonar())
    state = imm.init(batch.x0, P0)
    _, out = imm.step(state, stay_tpm(3, 0.95), z, allow_failure=True)
    assert out.failed.tolist() == [False, True, False]
    assert np.isfinite(out.x[[0, 2]]).all() and np.isnan(out.x[1]).all()
    with pytest.raises(np.linalg.LinAlgError), np.errstate(all="ignore"):
        imm.step(state, stay_tpm(3, 0.95), z)


@pytest.mark.parametrize("models", [("ncv", "ct", "ctra"), ("ct", "ncv", "ctra"),
                                    ("ctra", "ct", "ncv")])
def test_seed_start_probabilities_follow_the_kinds_in_any_order(models: tuple[str, ...]) -> None:
    seed = {"ncv": 0.90, "ct": 0.08, "ctra": 0.02}
    assert HeteroBank(models=models).probs == tuple(seed[kind] for kind in models)


def test_other_heterogeneous_banks_start_uniform() -> None:
    assert HeteroBank(models=("ncv", "ct")).probs == (0.5, 0.5)
    assert HeteroBank(models=("ncv", "ct", "ct")).probs == (1 / 3,) * 3


@pytest.mark.parametrize("mu", [(0.1, 0.1, 0.8), (0.1, 0.8, 0.1)])
def test_the_mixtures_predicted_bearing_is_wrapped_across_pi(mu: tuple[float, ...]) -> None:
    """A target on the sonar's -x axis whose models predict bearings on both sides of +-pi
    (identity TPM: ``cbar = mu``): the mixture's predicted measurement ``z_pred`` is the
    ``cbar``-weighted mean of the models' predictions, the bearings averaged as wrapped
    differences from model 0's, computed here by hand from the EKF's ``h(F_j x)``, and its
    bearing lies in (-pi, pi]."""
    sensor = Sonar()
    bank = paper_bank()
    imm = HeteroIMM(linear_models(bank), sensor, T=1.0)
    x0 = np.array([-5000.0, 0.5, -300.0, 0.0])
    state = imm.init(x0[None], np.diag([100.0, 100.0, 25.0, 25.0]), np.array(mu))
    _, out = imm.step(state, np.eye(3), np.array([[5300.0, math.pi - 1e-4]]))
    pred = [m.transition_matrix(1.0, 4) @ x0 for m in bank]
    r = [math.hypot(p[0], p[1]) for p in pred]
    b = [math.atan2(p[1], p[0]) for p in pred]
    assert max(b) > 3.1 and min(b) < -3.1  # the models straddle +-pi
    w = np.array(mu)
    turn = 2.0 * math.pi
    bearing = math.remainder(b[0] + w @ [math.remainder(bj - b[0], turn) for bj in b], turn)
    assert -math.pi < out.z_pred[0, 1] <= math.pi
    assert out.z_pred[0, 1] == pytest.approx(bearing, abs=1e-12)
    assert out.z_pred[0, 0] == pytest.approx(w @ r, rel=1e-12)
