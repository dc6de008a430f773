"""Tests of imm_gym.evaluation.metrics: RMSE/ARMSE, NIS/NEES consistency, model identification,
mode-probability total variation, peak error and maneuver response."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from imm_gym import MotionModel, Scenario, Segment, generate_truth, paper_bank, paper_scenario
from imm_gym.evaluation.metrics import (
    consistency,
    maneuver_response,
    maneuver_starts,
    mode_accuracy,
    mode_prob_tv,
    nees,
    peak_error,
    rmse_over_time,
    tracking_errors,
)
from imm_gym.scenarios.profiles import maneuver_truth
from imm_gym.scenarios.segments import true_model_index


def _truth_array(R: int = 7, K: int = 20) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.normal(0.0, 1000.0, (R, K, 4))


def test_constant_error() -> None:
    truth = _truth_array()
    est = truth + np.array([3.0, 4.0, 0.3, -0.4])
    np.testing.assert_allclose(rmse_over_time(est[..., :2] - truth[..., :2]), 5.0)
    e = tracking_errors(est, truth)
    assert e["armse_pos"] == pytest.approx(5.0)
    assert e["armse_pos_x"] == pytest.approx(3.0)
    assert e["armse_pos_y"] == pytest.approx(4.0)
    assert e["armse_vel"] == pytest.approx(0.5)
    assert e["armse_vel_x"] == pytest.approx(0.3)
    assert e["armse_vel_y"] == pytest.approx(0.4)


def test_rmse_is_over_runs_then_mean_over_time() -> None:
    # two runs, two steps: errors chosen so that the order of the means matters
    err = np.zeros((2, 2, 2))
    err[0, 0] = [3.0, 4.0]  # |e| = 5
    err[1, 0] = [0.0, 0.0]
    err[0, 1] = [6.0, 8.0]  # |e| = 10
    err[1, 1] = [0.0, 10.0]  # |e| = 10
    rmse = rmse_over_time(err)
    np.testing.assert_allclose(rmse, [np.sqrt(25.0 / 2.0), 10.0])
    truth = np.zeros((2, 2, 4))
    est = np.concatenate([err, np.zeros((2, 2, 2))], axis=-1)
    e = tracking_errors(est, truth)
    assert e["armse_pos"] == pytest.approx((np.sqrt(12.5) + 10.0) / 2)
    assert e["armse_pos_x"] == pytest.approx((np.sqrt(9.0 / 2) + np.sqrt(36.0 / 2)) / 2)
    assert e["armse_vel"] == 0.0


def test_tracking_errors_ignores_extra_state() -> None:
    truth = _truth_array()
    shift = np.array([1.0, 0.0, 0.0, 0.0])
    est = np.concatenate([truth + shift, np.full((7, 20, 2), 99.0)], axis=-1)
    assert tracking_errors(est, truth)["armse_pos"] == pytest.approx(1.0)


def test_consistency_chi2() -> None:
    rng = np.random.default_rng(1)
    v = stats.chi2(2).rvs(size=40_000, random_state=rng)
    c = consistency(v, 2)
    assert c["bound"] == pytest.approx(5.991464547, rel=1e-8)
    assert c["inside"] == pytest.approx(0.95, abs=0.005)
    assert c["mean"] == pytest.approx(2.0, rel=0.03)
    assert c["dof"] == 2
    # an over-confident filter (values 2x too large) fails the test
    c_bad = consistency(2.0 * v, 2)
    assert c_bad["inside"] < 0.85
    assert c_bad["mean"] == pytest.approx(4.0, rel=0.03)


def test_consistency_mask_and_empty() -> None:
    v = np.array([1.0, 100.0, 2.0, 3.0])
    c = consistency(v, 2, mask=np.array([True, False, True, True]))
    assert c["mean"] == pytest.approx(2.0)
    assert c["inside"] == 1.0
    c = consistency(v, 4, mask=np.zeros(4, dtype=bool))
    assert c["inside"] is None and c["mean"] is None  # no value: no mean of 0 to read as one
    assert c["bound"] == pytest.approx(stats.chi2.ppf(0.95, 4))


def test_nees_calibrated_gaussian() -> None:
    rng = np.random.default_rng(2)
    R, K = 200, 50
    A = rng.standard_normal((R, K, 4, 4))
    P = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(4)
    D = np.sqrt([100.0, 100.0, 1.0, 1.0])  # metre-scale positions, m/s-scale velocities
    P = D[:, None] * P * D[None, :]
    L = np.linalg.cholesky(P)
    truth = rng.normal(0.0, 1000.0, (R, K, 4))
    est = truth + (L @ rng.standard_normal((R, K, 4, 1)))[..., 0]
    v = nees(est, P, truth)
    assert v.shape == (R, K)
    assert v.mean() == pytest.approx(4.0, rel=0.03)
    c = consistency(v, 4)
    assert c["inside"] == pytest.approx(0.95, abs=0.01)
    # check one value by hand
    e = truth[3, 7] - est[3, 7]
    assert v[3, 7] == pytest.approx(e @ np.linalg.solve(P[3, 7], e), rel=1e-9)
    # a covariance 4x too small is inconsistent
    assert nees(est, P / 4.0, truth).mean() == pytest.approx(16.0, rel=0.03)


def test_nees_uses_first_four_states() -> None:
    truth = np.zeros((1, 1, 4))
    est = np.array([[[1.0, 2.0, 0.0, 0.0, 5.0, 5.0]]])
    P = np.eye(6)[None, None]
    assert nees(est, P, truth)[0, 0] == pytest.approx(5.0)


def test_true_model_index_paper() -> None:
    truth = generate_truth([paper_scenario()] * 2)
    idx = true_model_index(truth, paper_bank())
    assert idx.shape == (2, 150)
    expected = np.zeros(150, dtype=np.int64)
    expected[40:70] = 2  # -1.2 deg/s: clockwise, the CT(-4) model
    expected[90:115] = 1  # +1.8 deg/s: counter-clockwise, the CT(+4) model
    np.testing.assert_array_equal(idx[0], expected)
    np.testing.assert_array_equal(idx[1], expected)


def test_true_model_index_nearest_rate_and_ca() -> None:
    bank = (
        MotionModel("ct", 1.0),
        MotionModel("cv"),
        MotionModel("ct", 5.0),
        MotionModel("ct", -2.0),
        MotionModel("ca", q=(0.1,) * 6),
    )
    sc = Scenario(
        (Segment(2), Segment(2, 1.5), Segment(2, 4.0), Segment(2, -10.0), Segment(2, accel=1.0)),
        velocity=(5.0, 0.0),
    )
    idx = true_model_index(generate_truth([sc]), bank)
    np.testing.assert_array_equal(idx[0], [1, 1, 0, 0, 2, 2, 3, 3, 4, 4])
    # no CT turning right and no CA: -1
    idx = true_model_index(generate_truth([sc]), bank[:3])
    np.testing.assert_array_equal(idx[0], [1, 1, 0, 0, 2, 2, -1, -1, -1, -1])


def test_an_accelerating_turn_is_the_ca_models() -> None:
    """Seed 003's constant Cartesian acceleration (10-14 s, steps 100-139 at T = 0.1 s) records
    a turn rate beside its acceleration: its steps are the CA model's when the bank has one, as
    the docstring says (they were labelled CT), and the turn's CT model without one."""
    truth = maneuver_truth(1)
    cartesian = slice(100, 140)
    assert np.all(truth.turn_rate[0, cartesian] > 0) and np.all(truth.accel[0, cartesian] != 0)
    bank = (MotionModel("cv"), MotionModel("ca", q=(0.1,) * 6), MotionModel("ct", 3.0))
    np.testing.assert_array_equal(true_model_index(truth, bank)[0, cartesian], 1)
    no_ca = (bank[0], bank[2])
    np.testing.assert_array_equal(true_model_index(truth, no_ca)[0, cartesian], 1)
    assert true_model_index(truth, bank)[0, 99] == 0  # straight before it


def test_mode_accuracy() -> None:
    truth = generate_truth([paper_scenario()] * 3)
    idx = true_model_index(truth, paper_bank())
    perfect = np.eye(3)[idx]
    assert perfect.shape == (3, 150, 3)
    assert mode_accuracy(perfect, idx) == 1.0
    always_cv = np.zeros_like(perfect)
    always_cv[..., 0] = 1.0
    assert mode_accuracy(always_cv, idx) == pytest.approx(95 / 150)
    wrong = np.eye(3)[(idx + 1) % 3]
    assert mode_accuracy(wrong, idx) == 0.0
    # steps without a matching model are not scored
    idx2 = idx.copy()
    idx2[:, :40] = -1
    always_cv[:, :40] = [0.0, 1.0, 0.0]
    assert mode_accuracy(always_cv, idx2) == pytest.approx(55 / 110)
    assert mode_accuracy(perfect, np.full_like(idx, -1)) is None  # no step to score



def test_a_tie_at_the_top_identifies_no_model() -> None:
    """Uniform probabilities (a diverged run; the uniform TPM after a missed detection) and a
    tie between the true model and another count as misses, whatever the true model's index."""
    uniform = np.full((2, 4, 3), 1.0 / 3)
    for j in range(3):
        assert mode_accuracy(uniform, np.full((2, 4), j)) == 0.0
    tie = np.array([[[0.4, 0.4, 0.2], [0.5, 0.3, 0.2]]])
    assert mode_accuracy(tie, np.array([[0, 0]])) == 0.5
    assert mode_accuracy(tie, np.array([[1, 1]])) == 0.0

def test_mode_prob_tv_constant_is_zero_alternating_one_hots_is_one() -> None:
    rng = np.random.default_rng(3)
    p = rng.dirichlet(np.ones(3), size=4)  # (R=4, M=3), each run its own constant probabilities
    constant = np.repeat(p[:, None, :], 20, axis=1)
    assert mode_prob_tv(constant) == 0.0
    alternating = np.eye(3)[np.tile([0, 2], (4, 10))]  # one-hot, switching every step
    assert alternating.shape == (4, 20, 3)
    assert mode_prob_tv(alternating) == 1.0
    # half of each: every run switches on 9 of its 19 differences (steps 2..10), none after
    half = alternating.copy()
    half[:, 10:] = half[:, 9:10]
    assert mode_prob_tv(half) == pytest.approx(9 / 19)
    assert mode_prob_tv(constant[:, :1]) is None  # one step: no change recorded


def test_mode_prob_tv_by_hand() -> None:
    # one run: (0.5, 0.5) -> (0.9, 0.1) -> (0.9, 0.1) -> (0.2, 0.8): TV 0.4, 0, 0.7
    mu = np.array([[[0.5, 0.5], [0.9, 0.1], [0.9, 0.1], [0.2, 0.8]]])
    assert mode_prob_tv(mu) == pytest.approx((0.4 + 0.0 + 0.7) / 3)
    # two runs are averaged with the steps: the second run never moves
    assert mode_prob_tv(np.concatenate([mu, mu[:, :1].repeat(4, axis=1)])) == pytest.approx(
        (0.4 + 0.7) / 6
    )


def test_mode_prob_tv_counts_the_step_pairs_both_live() -> None:
    """A diverged run's held (uniform) probabilities do not move: counted, its held steps would
    lower the mean and a divergence read as a smooth IMM. With ``live`` the mean is over the
    differences whose two steps are live, None when there is none."""
    mu = np.array([[[0.5, 0.5], [0.9, 0.1], [0.9, 0.1], [0.2, 0.8]]] * 2)
    live = np.ones((2, 4), dtype=bool)
    assert mode_prob_tv(mu, live) == mode_prob_tv(mu)
    mu[1, 2:] = 0.5  # run 1 diverges at its third step: held at uniform from there
    live[1, 2:] = False
    # run 0's three differences, run 1's first (0.4); its difference into the held step is not
    assert mode_prob_tv(mu, live) == pytest.approx((0.4 + 0.0 + 0.7 + 0.4) / 4)
    assert mode_prob_tv(mu, np.zeros((2, 4), dtype=bool)) is None
    assert mode_prob_tv(mu, np.tile([True, False], (2, 2))) is None  # no two live in a row


def _positions(errors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Estimates and truth ``(R, K, 4)`` whose position errors have norms ``errors (R, K)``
    (3-4-5 triangles, the velocity 0)."""
    truth = _truth_array(*errors.shape)
    est = truth.copy()
    est[..., 0] += 0.6 * errors
    est[..., 1] -= 0.8 * errors
    return est, truth


def test_peak_error_is_the_mean_of_each_runs_peak() -> None:
    errors = np.array([[1.0, 9.0, 2.0, 1.0], [1.0, 2.0, 3.0, 7.0], [4.0, 1.0, 1.0, 1.0]])
    est, truth = _positions(errors)
    assert peak_error(est, truth) == pytest.approx((9.0 + 7.0 + 4.0) / 3)
    # not the peak of RMSE(t), which averages the runs before taking the maximum
    assert rmse_over_time(est[..., :2] - truth[..., :2]).max() == pytest.approx(
        np.sqrt((81 + 4 + 1) / 3)
    )


def test_maneuver_starts() -> None:
    true_model = np.array([[0, 0, 1, 1, 1, 0, -1, -1, 2], [2, 2, 2, 2, 2, 2, 2, 2, 2]])
    np.testing.assert_array_equal(
        maneuver_starts(true_model),
        [[0, 0, 1, 0, 0, 1, 1, 0, 1], [0] * 9],
    )


def test_maneuver_response_on_hand_made_errors() -> None:
    # run 0: turns at step index 5 (model 0 -> 1) and back at 8 (1 -> 0): windows 5..14 and
    # 8..17 overlap on 8..14, counted twice; run 1: straight only; run 2: a turn at 22 of 25,
    # its window cut to 22..24 by the episode end
    K = 25
    true_model = np.zeros((3, K), dtype=np.int64)
    true_model[0, 5:8] = 1
    true_model[2, 22:] = 2
    errors = np.arange(1.0, 3 * K + 1).reshape(3, K)  # every step its own error
    est, truth = _positions(errors)
    windows = [errors[0, 5:15], errors[0, 8:18], errors[2, 22:25]]
    squares = np.concatenate(windows) ** 2
    expected = np.sqrt(squares.mean())
    assert squares.size == 23
    assert maneuver_response(est, truth, true_model) == pytest.approx(expected, rel=1e-12)
    # a window of 3 steps: 5..7, 8..10, 22..24
    short = np.concatenate([errors[0, 5:8], errors[0, 8:11], errors[2, 22:25]])
    assert maneuver_response(est, truth, true_model, window=3) == pytest.approx(
        np.sqrt(np.mean(short**2)), rel=1e-12
    )
    # straight runs only: no maneuver, no response
    assert maneuver_response(est[1:2], truth[1:2], true_model[1:2]) is None
    with pytest.raises(ValueError, match="window"):
        maneuver_response(est, truth, true_model, window=0)


def test_maneuver_response_matches_a_loop_over_maneuvers() -> None:
    rng = np.random.default_rng(5)
    R, K, window = 6, 40, 10
    true_model = np.repeat(rng.integers(-1, 3, size=(R, K // 4)), 4, axis=1)
    errors = rng.uniform(0.0, 50.0, (R, K))
    est, truth = _positions(errors)
    squares = [
        errors[r, s : s + window] ** 2
        for r in range(R)
        for s in range(1, K)
        if true_model[r, s] != true_model[r, s - 1]
    ]
    expected = np.sqrt(np.concatenate(squares).mean())
    assert maneuver_response(est, truth, true_model, window) == pytest.approx(expected, rel=1e-12)
