"""Tests of imm_gym.evaluation.clairvoyant: where the clairvoyant filter runs, and when its errors
are a bound or only a reference."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import MotionModel, Scenario, Segment, Sonar, generate_truth, paper_bank
from imm_gym.evaluation.clairvoyant import (
    BOUNDED_KEYS,
    clairvoyant_filter,
    clairvoyant_role,
    hold_diverged,
    unsupported,
)
from imm_gym.tracking.hetero import SONAR_HETERO_BANK, HeteroBank
from imm_gym.validation import ConfigError


def _errors(value: float) -> dict[str, float]:
    return dict.fromkeys(BOUNDED_KEYS, value)


def test_a_bound_while_no_policy_beats_it() -> None:
    policies = {"fixed": {**_errors(18.0), "mode_accuracy": 0.6}, "tip-imm": _errors(15.0)}
    role = clairvoyant_role(_errors(15.0), policies)  # a tie does not beat it
    assert role["role"] == "bound" and role["beaten_by"] == {}
    assert role["note"].startswith("bound: ")


def test_a_reference_once_a_policy_beats_it_on_any_error() -> None:
    lucky = {**_errors(16.0), "armse_vel_y": 0.5}
    policies = {"fixed": _errors(18.0), "lucky": lucky, "window": _errors(14.0)}
    role = clairvoyant_role(_errors(15.0), policies)
    assert role["role"] == "reference"
    assert role["note"] == "reference: beaten by lucky, window"
    assert role["beaten_by"] == {"lucky": ["armse_vel_y"], "window": list(BOUNDED_KEYS)}


def _scenario(*segments: Segment) -> Scenario:
    return Scenario(segments, position=(3000.0, 4000.0), velocity=(10.0, 5.0))


def test_unsupported_names_acceleration_and_missing_models() -> None:
    straight_turn = generate_truth([_scenario(Segment(5), Segment(5, 2.0), Segment(5, -1.0))])
    assert unsupported(straight_turn, paper_bank()) is None
    accel = _scenario(Segment(5), Segment(5, accel=0.5))
    truth = generate_truth([_scenario(Segment(10)), accel, accel])
    reason = unsupported(truth, paper_bank())
    assert reason is not None and "2 of 3 runs have acceleration segments" in reason
    z = np.zeros((3, 10, 2))
    x0, P0 = truth.states[:, 0], np.broadcast_to(np.eye(4), (3, 4, 4))
    with pytest.raises(ConfigError, match="2 of 3 runs have acceleration"):
        clairvoyant_filter(truth, z, Sonar(), paper_bank(), x0, P0)
    no_right = (MotionModel("cv"), MotionModel("ct", 4.0))
    assert "right-turn CT" in str(unsupported(straight_turn, no_right))
    hetero = HeteroBank(**SONAR_HETERO_BANK)
    assert "NCV/CT/CTRA" in str(unsupported(straight_turn, hetero))


def test_a_decelerating_run_is_unsupported_as_an_accelerating_one() -> None:
    """A tangential deceleration (a negative ``accel``: 11.2 m/s slowed by 0.5 m/s² for 5 s) is
    motion the CV/CT transitions cannot follow, as a positive one: 1 of 2 runs named."""
    slowing = _scenario(Segment(5), Segment(5, accel=-0.5))
    truth = generate_truth([_scenario(Segment(10)), slowing])
    assert (truth.accel < 0).any() and not (truth.accel > 0).any()
    reason = unsupported(truth, paper_bank())
    assert reason is not None and "1 of 2 runs have acceleration segments" in reason


def _ct_by_hand(omega: float, T: float) -> np.ndarray:
    """The exact transition of a turn at ``omega`` rad/s over ``T`` (CV at 0)."""
    if omega == 0.0:
        return np.array([[1, 0, T, 0], [0, 1, 0, T], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
    s, c = np.sin(omega * T), np.cos(omega * T)
    return np.array(
        [
            [1, 0, s / omega, -(1 - c) / omega],
            [0, 1, (1 - c) / omega, s / omega],
            [0, 0, c, -s],
            [0, 0, s, c],
        ]
    )


@pytest.mark.parametrize("noise", ["discrete", "continuous"])
def test_the_clairvoyant_filter_predicts_each_step_with_its_own_true_motion(noise: str) -> None:
    """Step k is predicted with the exact transition at that step's true turn rate (the one that
    moved the truth into measurement k) and the ``Q`` of the bank's model of that motion: the
    CV model's on straight steps, the left-turn CT model's on left turns, the right-turn one's on
    right turns (three different ``Q`` here); checked against a hand-written EKF loop. The turn
    rate of the step before, or the CV model's ``Q`` on turns, gives other estimates. A
    continuous-noise bank's ``Q`` is the one of the truth's sampling period (T = 2 s here)."""
    T = 2.0
    scenarios = [
        Scenario((Segment(4), Segment(4, 3.0), Segment(4, -2.0)), (3000.0, 4000.0), (10.0, 5.0),
                 T=T),
        Scenario((Segment(3, -2.5), Segment(5), Segment(4, 1.5)), (-2000.0, 3500.0), (8.0, -6.0),
                 T=T),
    ]
    truth = generate_truth(scenarios)
    R, K = truth.turn_rate.shape
    assert (R, K) == (2, 12)
    # the truth's convention: turn_rate[:, k] moves states[:, k] to states[:, k + 1]
    for r in range(R):
        for k in range(K):
            moved = _ct_by_hand(truth.turn_rate[r, k], T) @ truth.states[r, k]
            np.testing.assert_allclose(truth.states[r, k + 1], moved, rtol=1e-12, atol=1e-9)
    if noise == "discrete":
        q = {0: (9.0, 9.0, 1.0, 1.0), 1: (2.0, 3.0, 0.3, 0.4), -1: (4.0, 1.0, 0.6, 0.2)}
        bank = (MotionModel("cv", q=q[0]), MotionModel("ct", 4.0, q[1]),
                MotionModel("ct", -4.0, q[-1]))
        Q = {sign: np.diag(q[sign]) for sign in q}
    else:
        bank = tuple(
            MotionModel(kind, rate, noise="continuous", intensity=intensity)
            for kind, rate, intensity in (("cv", 0.0, 0.5), ("ct", 4.0, 0.1), ("ct", -4.0, 0.2))
        )
        # the white-acceleration Q of each axis over T (Bar-Shalom et al. 2001, §6.2.2): at the
        # models' small turn rates the CT models' is within 2e-3 of it, far from T = 1 s's
        cv_q = np.array([[T**3 / 3, T**2 / 2], [T**2 / 2, T]])
        Q = {s: m.noise_covariance(4, T) for s, m in zip((0, 1, -1), bank, strict=True)}
        np.testing.assert_allclose(Q[0][np.ix_([0, 2], [0, 2])], 0.5 * cv_q, rtol=1e-12)
        np.testing.assert_allclose(Q[1][np.ix_([0, 2], [0, 2])], 0.1 * cv_q, rtol=2e-3)
    sonar = Sonar(position=(500.0, -300.0))
    sigma = np.array([sonar.sigma_r, np.radians(sonar.sigma_theta_deg)])
    rng = np.random.default_rng(4)

    def h(x: np.ndarray) -> np.ndarray:
        dx, dy = x[0] - 500.0, x[1] + 300.0
        return np.array([np.hypot(dx, dy), np.arctan2(dy, dx)])

    z = np.array([[h(s) for s in run[1:]] for run in truth.states])
    z += rng.normal(size=z.shape) * sigma
    detected = np.ones((R, K), dtype=bool)
    detected[1, 6] = False  # a step predicted only
    x0 = truth.states[:, 0] + np.array([30.0, -20.0, 1.0, -1.0])
    P0 = np.broadcast_to(np.diag([100.0**2, 100.0**2, 5.0**2, 5.0**2]), (R, 4, 4)).copy()
    xs, Ps = clairvoyant_filter(truth, z, sonar, bank, x0, P0, filter="ekf", detected=detected)
    Rz = np.diag(sigma**2)
    for r in range(R):
        x, P = x0[r].copy(), P0[r].copy()
        for k in range(K):
            omega = truth.turn_rate[r, k]
            F = _ct_by_hand(omega, T)
            x, P = F @ x, F @ P @ F.T + Q[int(np.sign(omega))]
            if detected[r, k]:
                dx, dy = x[0] - 500.0, x[1] + 300.0
                r2 = dx * dx + dy * dy
                r1 = np.sqrt(r2)
                H = np.array([[dx / r1, dy / r1, 0, 0], [-dy / r2, dx / r2, 0, 0]])
                nu = z[r, k] - h(x)
                nu[1] = (nu[1] + np.pi) % (2 * np.pi) - np.pi
                S = H @ P @ H.T + Rz
                G = P @ H.T @ np.linalg.inv(S)
                x = x + G @ nu
                P = (np.eye(4) - G @ H) @ P @ (np.eye(4) - G @ H).T + G @ Rz @ G.T
            np.testing.assert_allclose(xs[r, k], x, rtol=1e-9, atol=1e-9, err_msg=f"{r}, {k}")
            np.testing.assert_allclose(Ps[r, k], P, rtol=1e-9, atol=1e-9, err_msg=f"{r}, {k}")
    # the motion of each kind is there to be told apart
    assert {int(np.sign(w)) for w in truth.turn_rate[0]} == {-1, 0, 1}


def test_measurements_of_steps_0_to_k_are_refused_not_taken_one_step_late() -> None:
    """``z`` is measurements 1..K: the batch's ``z`` with its step-0 column would update every
    step with the measurement before; shapes that do not fit the truth name the input."""
    truth = generate_truth([_scenario(Segment(4), Segment(4, 3.0), Segment(4, -2.0))] * 2)
    x0, P0 = truth.states[:, 0], np.broadcast_to(np.eye(4) * 100.0, (2, 4, 4))
    z = np.zeros((2, 12, 2))
    clairvoyant_filter(truth, z, Sonar(), paper_bank(), x0, P0, filter="ekf")
    with pytest.raises(ConfigError, match=r"z must have shape \(2, 12, 2\).*got \(2, 13, 2\)"):
        clairvoyant_filter(truth, np.zeros((2, 13, 2)), Sonar(), paper_bank(), x0, P0)
    with pytest.raises(ConfigError, match=r"detected must have shape \(2, 12\)"):
        clairvoyant_filter(truth, z, Sonar(), paper_bank(), x0, P0,
                           detected=np.ones((2, 13), dtype=bool))
    with pytest.raises(ConfigError, match=r"P0 must have shape \(2, 4, 4\)"):
        clairvoyant_filter(truth, z, Sonar(), paper_bank(), x0, P0[0])


def test_a_run_is_held_from_the_step_it_diverges_at_as_the_policies_are() -> None:
    """Three runs of four steps: run 0 keeps within the caps, run 1's position error passes
    ``divergence_error`` at step 1, run 2's ``P_xx + P_yy`` passes ``divergence_cov`` at step 2
    with an infinite velocity there (its held velocity error is the truth's negative)."""
    truth = np.arange(3 * 4 * 4, dtype=float).reshape(3, 4, 4)
    xs = truth + 1.0
    Ps = np.broadcast_to(np.eye(4), (3, 4, 4, 4)).copy()
    xs[1, 1, 0] += 100.0
    xs[1, 1, 2] = truth[1, 1, 2] + 7.0
    xs[1, 2:, 0] = np.nan  # what comes after is not read
    Ps[2, 2, 1, 1] = 1e3
    xs[2, 2, 3] = np.inf
    held, diverged = hold_diverged(xs, Ps, truth, divergence_error=50.0, divergence_cov=100.0)
    assert diverged.tolist() == [False, True, True]
    np.testing.assert_array_equal(held[0], xs[0])
    np.testing.assert_array_equal(held[1, 0], xs[1, 0])
    np.testing.assert_array_equal(held[2, :2], xs[2, :2])
    cap = 50.0 / np.sqrt(2.0)
    for r, k, velocity_error in ((1, 1, (7.0, 1.0)), (2, 2, (1.0, -truth[2, 2, 3]))):
        for later in range(k, 4):
            expected = truth[r, later] + np.array([cap, cap, *velocity_error])
            np.testing.assert_allclose(held[r, later], expected, rtol=1e-15)


def _held_by_hand(xs: np.ndarray, truth: np.ndarray, k: int, cap: float) -> np.ndarray:
    """Run ``xs`` held from step ``k``: the position ``cap / sqrt(2)`` off the truth on x and on
    y (``cap`` from the truth in all), the velocity error step ``k``'s."""
    held = xs.copy()
    off = cap / np.sqrt(2.0)
    assert np.hypot(off, off) == pytest.approx(cap)
    velocity_error = xs[k, 2:] - truth[k, 2:]
    for later in range(k, len(xs)):
        held[later] = [truth[later, 0] + off, truth[later, 1] + off,
                       *(truth[later, 2:] + velocity_error)]
    return held


def test_a_position_error_above_the_cap_diverges_and_one_at_the_cap_does_not() -> None:
    """A run diverges where its position error exceeds ``divergence_error`` (50 m here), however
    little: 75 m off diverges, 50.5 m off diverges, exactly 50 m off (30 m, 40 m) does not."""
    truth = np.arange(4 * 3 * 4, dtype=float).reshape(4, 3, 4)
    xs = truth.copy()
    Ps = np.broadcast_to(np.eye(4), (4, 3, 4, 4)).copy()
    xs[0, 1, 0] += 75.0
    xs[0, 1, 2] += 3.0  # its velocity error at the step it diverges at
    xs[1, 2, :2] += (30.0, 40.0)  # exactly at the cap
    xs[2, 1, 1] -= 50.5
    xs[3, 0, :2] += (30.0, 40.5)  # just above it, at the first step
    assert np.hypot(30.0, 40.0) == 50.0
    held, diverged = hold_diverged(xs, Ps, truth, divergence_error=50.0, divergence_cov=100.0)
    assert diverged.tolist() == [True, False, True, True]
    np.testing.assert_allclose(held[0], _held_by_hand(xs[0], truth[0], 1, 50.0), rtol=1e-15)
    np.testing.assert_array_equal(held[1], xs[1])
    np.testing.assert_allclose(held[2], _held_by_hand(xs[2], truth[2], 1, 50.0), rtol=1e-15)
    np.testing.assert_allclose(held[3], _held_by_hand(xs[3], truth[3], 0, 50.0), rtol=1e-15)


def test_the_position_covariance_diverges_by_the_sum_of_its_diagonal() -> None:
    """A finite estimate 1 m off the truth diverges where ``P_xx + P_yy`` exceeds
    ``divergence_cov`` (100 m² here): ``P_yy`` alone above it; ``P_xx`` and ``P_yy`` each below
    it (60 m²) with a sum above; not at a sum of exactly 100 m², nor by the velocity's
    covariance."""
    truth = np.arange(5 * 3 * 4, dtype=float).reshape(5, 3, 4)
    xs = truth + 1.0
    Ps = np.broadcast_to(np.eye(4), (5, 3, 4, 4)).copy()
    Ps[0, 1, 1, 1] = 150.0  # P_yy only
    Ps[1, 2, 0, 0] = Ps[1, 2, 1, 1] = 60.0  # each below the cap, their sum above
    Ps[2, 1, 0, 0] = Ps[2, 1, 1, 1] = 50.0  # the sum at the cap
    Ps[3, :, 2, 2] = Ps[3, :, 3, 3] = 1e6  # the velocity's
    Ps[4, 0, 0, 0] = 150.0  # P_xx only, at the first step
    held, diverged = hold_diverged(xs, Ps, truth, divergence_error=50.0, divergence_cov=100.0)
    assert diverged.tolist() == [True, True, False, False, True]
    for r, k in ((0, 1), (1, 2), (4, 0)):
        np.testing.assert_allclose(held[r], _held_by_hand(xs[r], truth[r], k, 50.0), rtol=1e-15)
    np.testing.assert_array_equal(held[2:4], xs[2:4])


def test_a_velocity_that_is_not_finite_diverges_with_a_finite_position() -> None:
    """An estimate whose vx is NaN at step 1 diverges there even with its position on the truth
    and its covariance ``I`` (the policies' rule: an estimate not finite): held from step 1,
    its velocity error that of vx = 0 and of its vy (2 m/s off), not NaN in every later error;
    the other run, finite throughout, is kept."""
    truth = np.arange(2 * 3 * 4, dtype=float).reshape(2, 3, 4) + 1.0
    xs = truth.copy()
    xs[0, 1, 2] = np.nan
    xs[0, 1, 3] += 2.0
    Ps = np.broadcast_to(np.eye(4), (2, 3, 4, 4)).copy()
    held, diverged = hold_diverged(xs, Ps, truth, divergence_error=50.0, divergence_cov=100.0)
    assert diverged.tolist() == [True, False]
    off = 50.0 / np.sqrt(2.0)
    np.testing.assert_array_equal(held[0, 0], xs[0, 0])
    for later in (1, 2):
        expected = truth[0, later] + np.array([off, off, -truth[0, 1, 2], 2.0])
        np.testing.assert_allclose(held[0, later], expected, rtol=1e-15)
    np.testing.assert_array_equal(held[1], xs[1])
