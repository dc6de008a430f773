"""Tests of imm_gym.tracking.models: CV / CT / CA transition matrices, process noise, validation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym import ConfigError, MotionModel, ct_transition, paper_bank
from imm_gym.tracking.models import PAPER_Q, bank_dim

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
    ],
)
def test_invalid_model_config(kwargs: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        MotionModel(**kwargs)
