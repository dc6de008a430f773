"""Tests of imm_gym.tracking.models: CV / CT / CA transition matrices, process noise (per step
and continuous-time, discretized), validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad_vec
from scipy.linalg import expm

from imm_gym import (
    IMM,
    ConfigError,
    EnvConfig,
    MotionModel,
    RandomFamily,
    Sonar,
    clairvoyant_filter,
    ct_transition,
    draw_batch,
    paper_bank,
    stay_tpm,
)
from imm_gym.evaluation.metrics import tracking_errors
from imm_gym.sim.presets import BANK_PRESETS, CONTINUOUS_BANK
from imm_gym.tracking.hetero import LinearModel
from imm_gym.tracking.models import (
    PAPER_Q,
    TURN_NOISE_SERIES_BELOW,
    bank_dim,
    turn_noise_ratios,
    white_acceleration_noise,
    white_jerk_noise,
)

CV_F = np.array(
    [
        [1.0, 0.0, 1.0, 0.0],
        [0.0, 1.0, 0.0, 1.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


def _rot(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def _circle(p0: np.ndarray, v0: np.ndarray, omega: float, t: float) -> np.ndarray:
    """Exact coordinated-turn motion: rotation of (p0 - c) and v0 by omega*t about the centre c."""
    c = p0 + np.array([-v0[1], v0[0]]) / omega  # centre, to the left of v for omega > 0
    p = c + _rot(omega * t) @ (p0 - c)
    v = _rot(omega * t) @ v0
    return np.concatenate([p, v])


@pytest.mark.parametrize("turn_deg", [4.0, -4.0, 1.8, -1.2, 30.0])
@pytest.mark.parametrize("T", [1.0, 0.1])
def test_ct_matches_closed_form_circle(turn_deg: float, T: float) -> None:
    omega = math.radians(turn_deg)
    p0, v0 = np.array([3000.0, 4500.0]), np.array([20.0, 15.0])
    F = ct_transition(omega, T)
    assert F.shape == (4, 4)
    x = np.concatenate([p0, v0])
    centre = p0 + np.array([-v0[1], v0[0]]) / omega
    radius = np.linalg.norm(v0) / abs(omega)
    for k in range(1, 201):
        x = F @ x
        np.testing.assert_allclose(x, _circle(p0, v0, omega, k * T), rtol=0, atol=1e-8 * radius)
        assert np.linalg.norm(x[:2] - centre) == pytest.approx(radius, rel=1e-10)
        assert np.linalg.norm(x[2:]) == pytest.approx(25.0, rel=1e-12)
    # the heading turned by omega * K * T
    heading0 = math.atan2(v0[1], v0[0])
    heading = math.atan2(x[3], x[2])
    turned = math.remainder(heading - heading0 - omega * 200 * T, 2 * math.pi)
    assert abs(turned) < 1e-10


def test_ct_batched_shapes_and_values() -> None:
    omegas = np.radians(np.array([[4.0, -4.0, 0.0], [1.0, 2.0, 1e-9]]))
    F = ct_transition(omegas, 1.0)
    assert F.shape == (2, 3, 4, 4)
    for i in range(2):
        for j in range(3):
            np.testing.assert_array_equal(F[i, j], ct_transition(omegas[i, j], 1.0))


@pytest.mark.parametrize("omega", [1e-9, -1e-9, 1e-7, 0.0])
def test_ct_small_rate_tends_to_cv(omega: float) -> None:
    F = ct_transition(omega, 1.0)
    assert np.all(np.isfinite(F))
    np.testing.assert_allclose(F, CV_F, atol=1e-6)
    np.testing.assert_allclose(F, CV_F, atol=abs(omega) * 1.01 + 1e-15)


def test_ct_taylor_branch_is_continuous() -> None:
    # The series branch (|omega T| < 1e-6) and the closed form agree across the switch.
    below = ct_transition(0.999e-6, 1.0)
    above = ct_transition(1.001e-6, 1.0)
    np.testing.assert_allclose(below, above, atol=1e-8)


def test_cv_model_is_ct_limit() -> None:
    cv = MotionModel("cv")
    np.testing.assert_array_equal(cv.transition_matrix(1.0, 4), CV_F)
    np.testing.assert_allclose(ct_transition(1e-9, 1.0), CV_F, atol=1e-9)
    T = 0.1
    expected = np.eye(4)
    expected[0, 2] = expected[1, 3] = T
    np.testing.assert_allclose(cv.transition_matrix(T, 4), expected, atol=1e-15)


@pytest.mark.parametrize(("turn_deg", "ccw"), [(4.0, True), (-4.0, False), (1.8, True)])
def test_turn_direction(turn_deg: float, ccw: bool) -> None:
    """omega > 0 turns counter-clockwise: the cross product v0 x v1 is positive."""
    m = MotionModel("ct", turn_deg)
    F = m.transition_matrix(1.0, 4)
    x0 = np.array([0.0, 0.0, 10.0, 0.0])  # heading +x
    x1 = F @ x0
    cross = x0[2] * x1[3] - x0[3] * x1[2]
    assert (cross > 0) == ccw
    # heading +x, counter-clockwise: the target drifts to +y
    assert (x1[1] > 0) == ccw
    assert math.atan2(x1[3], x1[2]) == pytest.approx(math.radians(turn_deg), rel=1e-12)


@pytest.mark.parametrize("T", [1.0, 0.1, 2.5])
def test_ca_propagates_constant_acceleration_exactly(T: float) -> None:
    ca = MotionModel("ca", q=(0.1,) * 6)
    F = ca.transition_matrix(T, 6)
    p0, v0, a = np.array([100.0, -50.0]), np.array([12.0, 3.0]), np.array([0.7, -1.3])
    x = np.concatenate([p0, v0, a])
    for k in range(1, 51):
        x = F @ x
        t = k * T
        np.testing.assert_allclose(x[:2], p0 + v0 * t + 0.5 * a * t * t, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(x[2:4], v0 + a * t, rtol=1e-12, atol=1e-10)
        np.testing.assert_array_equal(x[4:], a)


def test_ca_needs_six_dim_state() -> None:
    with pytest.raises(ConfigError):
        MotionModel("ca", q=(0.1,) * 6).transition_matrix(1.0, 4)


def test_six_dim_bank_embeds_cv_and_ct() -> None:
    q_acc = 0.03
    cv = MotionModel("cv", q_acc=q_acc)
    ct = MotionModel("ct", 3.0, q=(0.05, 0.05, 0.06, 0.06), q_acc=q_acc)
    ca = MotionModel("ca", q=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0))
    assert bank_dim((cv, ct, ca)) == 6
    assert bank_dim((cv, ct)) == 4
    for m in (cv, ct):
        F6 = m.transition_matrix(1.0, 6)
        assert F6.shape == (6, 6)
        np.testing.assert_array_equal(F6[:4, :4], m.transition_matrix(1.0, 4))
        np.testing.assert_array_equal(F6[4:, :], 0.0)  # acceleration rows zeroed
        np.testing.assert_array_equal(F6[:, 4:], 0.0)  # and no acceleration enters position
        Q6 = m.noise_covariance(6)
        np.testing.assert_array_equal(Q6, np.diag([*m.q, q_acc, q_acc]))
    np.testing.assert_array_equal(ca.noise_covariance(6), np.diag([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))
    with pytest.raises(ConfigError):
        ca.noise_covariance(4)


def test_paper_bank() -> None:
    bank = paper_bank()
    assert [m.kind for m in bank] == ["cv", "ct", "ct"]
    assert [m.turn_rate_deg for m in bank] == [0.0, 4.0, -4.0]
    np.testing.assert_allclose(bank[0].noise_covariance(4), np.diag(PAPER_Q))
    np.testing.assert_allclose(bank[0].noise_covariance(4), np.diag([0.1, 0.1, 0.12, 0.12]))
    for m in bank[1:]:
        np.testing.assert_allclose(m.noise_covariance(4), 0.5 * np.diag(PAPER_Q))
    assert bank[1].omega == pytest.approx(math.radians(4.0))
    assert bank[2].omega == pytest.approx(-math.radians(4.0))


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"kind": "ct", "turn_rate_deg": 0.0}, "model.turn_rate_deg"),
        ({"kind": "cv", "turn_rate_deg": 2.0}, "model.turn_rate_deg"),
        ({"kind": "cv", "q": (0.1, 0.1, 0.1)}, "model.q"),
        ({"kind": "ca", "q": (0.1, 0.1, 0.1, 0.1)}, "model.q"),
        ({"kind": "cv", "q": (0.1, -0.1, 0.1, 0.1)}, "model.q"),
        ({"kind": "cv", "q": (0.1, float("nan"), 0.1, 0.1)}, "model.q"),
        ({"kind": "cv", "q_acc": 0.0}, "model.q_acc"),
        ({"kind": "ct", "turn_rate_deg": float("inf")}, "model.turn_rate_deg"),
        ({"kind": "singer"}, "model.kind"),
        ({"kind": "cv", "noise": "white"}, "model.noise"),
        ({"kind": "cv", "noise": "continuous"}, "model.intensity"),
        ({"kind": "cv", "intensity": 0.1}, "model.intensity"),
        ({"kind": "cv", "noise": "continuous", "intensity": 0.0}, "model.intensity"),
        ({"kind": "cv", "noise": "continuous", "intensity": -0.1}, "model.intensity"),
        ({"kind": "cv", "noise": "continuous", "intensity": float("nan")}, "model.intensity"),
        ({"kind": "cv", "noise": "continuous", "intensity": float("inf")}, "model.intensity"),
        ({"kind": "cv", "noise": "continuous", "intensity": "0.1"}, "model.intensity"),
        ({"kind": "cv", "noise": "continuous", "intensity": True}, "model.intensity"),
        ({"kind": "ca", "noise": "continuous", "intensity": 1.0, "q": (0.1,) * 6}, "model.q"),
        ({"kind": "ca"}, "model.q"),
    ],
)
def test_invalid_model_config(kwargs: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        MotionModel(**kwargs)


# --- process noise given as a continuous-time intensity ---------------------------------------


def _cv_textbook(q: float, T: float) -> np.ndarray:
    """Bar-Shalom et al. 2001 §6.2.2 on [x, y, vx, vy], written out entry by entry."""
    return q * np.array(
        [
            [T**3 / 3, 0.0, T**2 / 2, 0.0],
            [0.0, T**3 / 3, 0.0, T**2 / 2],
            [T**2 / 2, 0.0, T, 0.0],
            [0.0, T**2 / 2, 0.0, T],
        ]
    )


def _ct_integral(omega: float, T: float, q: float) -> np.ndarray:
    """``∫_0^T F(τ) G q G^T F(τ)^T dτ`` numerically, ``F(τ) G`` written out from the turn's
    rotation (``1 - cos`` as ``2 sin²`` so small angles keep their digits)."""

    def integrand(tau: float) -> np.ndarray:
        s, c = math.sin(omega * tau), math.cos(omega * tau)
        one_minus_c = 2.0 * math.sin(0.5 * omega * tau) ** 2
        a = np.array([s / omega, one_minus_c / omega, c, s])  # response to an x kick
        b = np.array([-one_minus_c / omega, s / omega, -s, c])  # response to a y kick
        return q * (np.outer(a, a) + np.outer(b, b))

    value, _ = quad_vec(integrand, 0.0, T, epsabs=0.0, epsrel=1e-13)
    return value


def _continuous(kind: str, turn_deg: float = 0.0, q: float = 0.1) -> MotionModel:
    return MotionModel(kind, turn_deg, noise="continuous", intensity=q)


@pytest.mark.parametrize("T", [1.0, 5.0, 0.1])
@pytest.mark.parametrize("q", [0.12, 3.0])
def test_continuous_cv_noise_is_textbook(T: float, q: float) -> None:
    Q = _continuous("cv", q=q).noise_covariance(4, T)
    np.testing.assert_allclose(Q, _cv_textbook(q, T), rtol=1e-15, atol=0.0)
    if T == 1.0:  # the numbers themselves: q/3, q/2, q
        np.testing.assert_allclose(np.diag(Q), [q / 3, q / 3, q, q], rtol=1e-15)
        assert Q[0, 2] == Q[1, 3] == pytest.approx(q / 2, rel=1e-15)
    if T == 5.0:
        np.testing.assert_allclose(np.diag(Q), q * np.array([125 / 3, 125 / 3, 5, 5]), rtol=1e-15)
        assert Q[0, 2] == pytest.approx(q * 12.5, rel=1e-15)


@pytest.mark.parametrize("turn_deg", [4.0, -4.0, 1.0, -3.0, 30.0, 0.05])
@pytest.mark.parametrize("T", [0.1, 1.0, 5.0])
def test_continuous_ct_noise_is_the_integral(turn_deg: float, T: float) -> None:
    omega = math.radians(turn_deg)
    Q = _continuous("ct", turn_deg, 0.7).noise_covariance(4, T)
    ref = _ct_integral(omega, T, 0.7)
    scale = np.abs(ref).max()
    np.testing.assert_allclose(Q, ref, rtol=1e-9, atol=1e-9 * scale)
    # the closed form's entries as the docstring prints them (where u - sin u keeps its digits)
    wt, q = omega * T, 0.7
    if abs(wt) > 0.05:
        np.testing.assert_allclose(Q[0, 0], q * 2 * (wt - math.sin(wt)) / omega**3, rtol=1e-9)
        np.testing.assert_allclose(Q[0, 2], q * (1 - math.cos(wt)) / omega**2, rtol=1e-9)
        np.testing.assert_allclose(Q[0, 3], q * (wt - math.sin(wt)) / omega**2, rtol=1e-9)
    assert Q[1, 2] == -Q[0, 3] and Q[0, 1] == 0.0 and Q[2, 3] == 0.0


@pytest.mark.parametrize("T", [1.0, 5.0, 0.1])
def test_continuous_ca_noise_is_textbook_and_the_integral(T: float) -> None:
    q = 0.4
    Q = _continuous("ca", q=q).noise_covariance(6, T)
    axis = np.array(
        [[T**5 / 20, T**4 / 8, T**3 / 6], [T**4 / 8, T**3 / 3, T**2 / 2], [T**3 / 6, T**2 / 2, T]]
    )
    for i in range(3):  # per axis, (position, velocity, acceleration) = state entries 2i + axis
        for j in range(3):
            assert Q[2 * i, 2 * j] == Q[2 * i + 1, 2 * j + 1] == pytest.approx(q * axis[i, j])
            assert Q[2 * i, 2 * j + 1] == Q[2 * i + 1, 2 * j] == 0.0
    A = np.zeros((6, 6))
    A[:4, 2:] = np.eye(4)
    G = np.zeros((6, 2))
    G[4:, :] = np.eye(2)
    ref, _ = quad_vec(
        lambda t: expm(A * t) @ G @ (q * G.T) @ expm(A * t).T, 0.0, T, epsabs=0.0, epsrel=1e-13
    )
    np.testing.assert_allclose(Q, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    np.testing.assert_array_equal(Q, white_jerk_noise(T, q))


@pytest.mark.parametrize("T", [1.0, 5.0])
def test_continuous_ct_tends_to_cv(T: float) -> None:
    cv = _cv_textbook(1.0, T)
    np.testing.assert_allclose(white_acceleration_noise(0.0, T, 1.0), cv, rtol=1e-15, atol=0.0)
    previous = math.inf
    for omega in (1e-2, 1e-3, 1e-5, 1e-7, 1e-9, -1e-9):
        gap = np.abs(white_acceleration_noise(omega, T, 1.0) - cv).max()
        # the cross term q T³ ω/6 is the first-order difference
        assert gap == pytest.approx(T**3 * abs(omega) / 6, rel=0.02)
        assert gap <= previous
        previous = gap


def test_turn_noise_series_branch_is_continuous() -> None:
    edge = TURN_NOISE_SERIES_BELOW
    u = np.array([edge * (1 - 1e-12), edge * (1 + 1e-12), -edge * (1 - 1e-12)])
    s1, s2 = turn_noise_ratios(u)
    np.testing.assert_allclose(s1, s1[0], rtol=1e-12)
    np.testing.assert_allclose(s2, s2[0], rtol=1e-12)
    s1, s2 = turn_noise_ratios(0.0)
    assert (s1, s2) == (0.5, 1 / 6)


@settings(max_examples=60, deadline=None)
@given(
    q=st.floats(1e-4, 1e3),
    T=st.floats(0.01, 10.0),
    T2=st.floats(0.01, 10.0),
    omega=st.floats(-0.5, 0.5),
)
def test_continuous_noise_invariants(q: float, T: float, T2: float, omega: float) -> None:
    Q = white_acceleration_noise(omega, T, q)
    np.testing.assert_array_equal(Q, Q.T)
    assert np.linalg.eigvalsh(Q).min() > 0.0
    np.linalg.cholesky(Q)
    np.testing.assert_allclose(Q, q * white_acceleration_noise(omega, T, 1.0), rtol=1e-14)
    # mirroring y (S = diag(1, -1, 1, -1)) turns CT(ω) into CT(-ω)
    S = np.diag([1.0, -1.0, 1.0, -1.0])
    scale = np.abs(Q).max()
    np.testing.assert_allclose(
        S @ Q @ S, white_acceleration_noise(-omega, T, q), atol=1e-13 * scale
    )
    # exact discretization: noise over T + T2 = noise over T carried through T2, plus T2's own
    F2 = ct_transition(omega, T2)
    both = F2 @ Q @ F2.T + white_acceleration_noise(omega, T2, q)
    total = white_acceleration_noise(omega, T + T2, q)
    np.testing.assert_allclose(both, total, rtol=1e-9, atol=1e-9 * np.abs(total).max())
    J = white_jerk_noise(T, q)
    np.testing.assert_array_equal(J, J.T)
    assert np.linalg.eigvalsh(J).min() > 0.0


def test_continuous_cv_ct_in_six_dim_bank() -> None:
    for m in (_continuous("cv", q=0.2), _continuous("ct", -3.0, 0.2)):
        Q6 = m.noise_covariance(6, 2.0)
        np.testing.assert_array_equal(Q6[:4, :4], m.noise_covariance(4, 2.0))
        np.testing.assert_array_equal(Q6[4:, 4:], m.q_acc * np.eye(2))
        np.testing.assert_array_equal(Q6[:4, 4:], 0.0)
    ca = _continuous("ca", q=0.2)
    IMM((_continuous("cv"), ca), Sonar(), T=2.0)  # a mixed bank builds
    with pytest.raises(ConfigError, match="CA does not fit a 4-dimensional"):
        ca.noise_covariance(4, 1.0)
    with pytest.raises(ConfigError, match="5-dimensional"):
        _continuous("cv").noise_covariance(5, 1.0)


def test_continuous_noise_needs_a_sampling_period() -> None:
    m = _continuous("ct", 4.0)
    with pytest.raises(ConfigError, match="sampling period T"):
        m.noise_covariance(4)
    for T in (0.0, -1.0, float("nan"), "1"):
        with pytest.raises(ConfigError, match=r"^T must be"):
            m.noise_covariance(4, T)  # type: ignore[arg-type]


@pytest.mark.parametrize("T", [0.1, 1.0, 5.0])
def test_paper_bank_noise_unchanged_bit_for_bit(T: float) -> None:
    """The per-step Q of the paper bank, whatever T: the literal numbers of the paper."""
    cv = np.diag([0.1, 0.1, 0.12, 0.12])
    ct = np.diag([0.05, 0.05, 0.06, 0.06])
    numpy_imm = IMM(paper_bank(), Sonar(), T=T, engine="numpy")
    compiled = IMM(paper_bank(), Sonar(), T=T, engine="compiled")
    np.testing.assert_array_equal(numpy_imm.Q, np.stack([cv, ct, ct]))
    assert compiled.kernel_args is not None
    np.testing.assert_array_equal(compiled.kernel_args[1][0], np.stack([cv, ct, ct]))
    assert all(m.noise == "discrete" and m.intensity is None for m in paper_bank())
    assert EnvConfig().bank == paper_bank()
    assert BANK_PRESETS["paper"] == {}


def test_continuous_preset_bank() -> None:
    bank = BANK_PRESETS["cv-ct-continuous"]["bank"]
    assert bank == CONTINUOUS_BANK
    assert [m.label for m in bank] == [m.label for m in paper_bank()]
    paper_Q = IMM(paper_bank(), Sonar()).Q
    for T in (0.1, 1.0, 5.0):
        imm = IMM(bank, Sonar(), T=T)
        for m, Q in zip(bank, imm.Q, strict=True):
            np.testing.assert_array_equal(Q, m.noise_covariance(4, T))
            np.testing.assert_array_equal(Q, white_acceleration_noise(m.omega, T, m.intensity))
        if T == 1.0:
            # one second adds the paper bank's velocity variance; the position variance is q/3
            velocity = np.diagonal(imm.Q, axis1=1, axis2=2)[:, 2:]
            np.testing.assert_allclose(velocity, [[0.12, 0.12], [0.06, 0.06], [0.06, 0.06]])
            np.testing.assert_allclose(velocity, np.diagonal(paper_Q, axis1=1, axis2=2)[:, 2:])
    assert EnvConfig(**BANK_PRESETS["cv-ct-continuous"]).bank == CONTINUOUS_BANK


@pytest.mark.parametrize("T", [1.0, 5.0])
def test_continuous_bank_engines_agree(T: float) -> None:
    """The compiled kernel and the numpy reference run the full (non-diagonal) Q alike (the
    tolerance of tests/tracking/test_imm.py::test_engines_agree)."""
    batch = draw_batch(RandomFamily(T=T, horizon=60), Sonar(), 6, 77)
    z = batch.measurements.z[:, 1:]
    imms = [IMM(CONTINUOUS_BANK, Sonar(), T=T, engine=e) for e in ("numpy", "compiled")]
    runs = [imm.run(z, stay_tpm(3, 0.95), batch.x0, batch.P0) for imm in imms]
    for f in ("x", "P", "mode_probs", "loglik"):
        a, b = getattr(runs[0], f), getattr(runs[1], f)
        np.testing.assert_allclose(
            a, b, rtol=1e-7, atol=1e-9 * max(1.0, np.abs(a).max()), err_msg=f
        )


def test_linear_model_noise_uses_the_sampling_period() -> None:
    m = _continuous("ct", 4.0, 0.3)
    x = np.zeros((2, 4))
    np.testing.assert_array_equal(LinearModel(m, 4).noise(x, 5.0)[1], m.noise_covariance(4, 5.0))


def test_scaled_scales_the_noise() -> None:
    for m in (*paper_bank(), MotionModel("ca", q=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0))):
        s = m.scaled(2.5)
        assert s.q == tuple(2.5 * v for v in m.q) and s.q_acc == 2.5 * m.q_acc
    for m in (_continuous("cv"), _continuous("ct", -4.0), _continuous("ca")):
        s = m.scaled(0.5)
        assert s.intensity == 0.5 * m.intensity and s.q_acc == 0.5 * m.q_acc
        np.testing.assert_allclose(
            s.noise_covariance(6, 2.0), 0.5 * m.noise_covariance(6, 2.0), rtol=1e-15
        )
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ConfigError, match="factor"):
            paper_bank()[0].scaled(bad)


def test_bank_entry_errors_name_the_entry() -> None:
    bank = [{"kind": "cv"}, {"kind": "ct", "turn_rate_deg": 4.0, "noise": "continuous"}]
    with pytest.raises(ConfigError, match=r"^bank\[1\]: model\.intensity"):
        EnvConfig(bank=bank)
    bank[1]["intensity"] = -1.0
    with pytest.raises(ConfigError, match=r"^bank\[1\]: model\.intensity must be in"):
        EnvConfig(bank=bank)
    with pytest.raises(ConfigError, match=r"^bank\[0\]: unknown key"):
        EnvConfig(bank=[{"kind": "cv", "nosie": "continuous"}, {"kind": "cv"}])
    bank[1]["intensity"] = 0.06
    config = EnvConfig(bank=bank)
    assert config.bank[1] == MotionModel("ct", 4.0, noise="continuous", intensity=0.06)


def test_clairvoyant_filter_runs_a_continuous_bank() -> None:
    """The clairvoyant filter borrows a continuous bank's Q, discretized at the truth's T."""
    batch = draw_batch(RandomFamily(T=5.0, horizon=60), Sonar(), 20, 3)
    z, truth = batch.measurements.z[:, 1:], batch.truth.states[:, 1:]
    x_cv, _ = clairvoyant_filter(batch.truth, z, Sonar(), CONTINUOUS_BANK, batch.x0, batch.P0)
    imm = IMM(CONTINUOUS_BANK, Sonar(), T=5.0).run(z, stay_tpm(3, 0.995), batch.x0, batch.P0)
    bound = tracking_errors(x_cv, truth)["armse_pos"]
    assert np.isfinite(bound)
    assert bound < tracking_errors(imm.x, truth)["armse_pos"]
