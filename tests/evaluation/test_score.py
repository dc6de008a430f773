"""Tests of imm_gym.evaluation.rollout.score on a hand-made roll-out: the IMM behaviour beside the
ARMSE (mode-probability total variation, peak error, maneuver response), and a diverged run."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from imm_gym.evaluation.metrics import nees
from imm_gym.evaluation.rollout import Rollout, score


def _rollout(true_model: np.ndarray, errors: np.ndarray, mode_probs: np.ndarray) -> Rollout:
    """A roll-out of R runs and K steps whose position errors are ``errors (R, K)`` along x."""
    R, K = errors.shape
    M = mode_probs.shape[-1]
    truth = np.zeros((R, K, 4))
    truth[..., 0] = np.arange(K) * 10.0
    truth[..., 2] = 10.0
    estimate = truth.copy()
    estimate[..., 0] += errors
    return Rollout(
        estimate=estimate,
        covariance=np.broadcast_to(np.eye(4), (R, K, 4, 4)).copy(),
        truth=truth,
        mode_probs=mode_probs,
        tpm=np.broadcast_to(np.full((M, M), 1.0 / M), (R, K, M, M)).copy(),
        nis=np.ones((R, K)),
        detected=np.ones((R, K), dtype=bool),
        true_model=true_model,
        diverged=np.zeros(R, dtype=bool),
        live=np.ones((R, K), dtype=bool),
        measurements=np.zeros((R, K + 1, 2)),
    )


def test_score_reports_the_imm_behaviour() -> None:
    # two runs of 15 steps; run 0 turns at step index 3 and ends its turn at 6, run 1 is straight
    true_model = np.zeros((2, 15), dtype=np.int64)
    true_model[0, 3:6] = 1
    errors = np.ones((2, 15))
    errors[0, 4] = 20.0  # run 0's peak, inside both of its windows (3..12 and 6..15)
    errors[1, 14] = 5.0  # run 1's peak, no maneuver there
    # run 0 follows the truth one step late; run 1 stays at (0.5, 0.5)
    mode_probs = np.full((2, 15, 2), 0.5)
    mode_probs[0] = np.eye(2)[np.concatenate([[0], true_model[0, :-1]])]
    s = score(_rollout(true_model, errors, mode_probs))
    assert s["peak_error"] == pytest.approx((20.0 + 5.0) / 2)
    windows = np.concatenate([errors[0, 3:13], errors[0, 6:15]])  # 10 steps + 9 (episode end)
    assert s["maneuver_response"] == pytest.approx(np.sqrt(np.mean(windows**2)))
    assert s["maneuver_response"] == pytest.approx(np.sqrt((400.0 + 18.0) / 19.0))
    # run 0 switches twice in 14 differences, run 1 never
    assert s["mode_prob_tv"] == pytest.approx(2.0 / 28.0)
    assert s["armse_pos"] > 1.0 and s["diverged"] == 0
    # the straight run alone has no maneuver
    straight = _rollout(true_model[1:], errors[1:], mode_probs[1:])
    assert score(straight)["maneuver_response"] is None


def _diverged(cap: float = 5000.0) -> Rollout:
    """Three runs of 10 steps, errors of 1-3 m; run 2 diverges at step 6: held at ``cap`` from
    there (``rollout``'s record: the error on x and y, covariance ``I``, uniform probabilities)."""
    true_model = np.zeros((3, 10), dtype=np.int64)
    errors = np.tile(np.array([[1.0], [2.0], [3.0]]), (1, 10))
    run = _rollout(true_model, errors, np.full((3, 10, 2), 0.5))
    estimate = run.estimate.copy()
    estimate[2, 6:, :2] = run.truth[2, 6:, :2] + cap / np.sqrt(2.0)
    live = np.ones((3, 10), dtype=bool)
    live[2, 6:] = False
    detected = live.copy()
    nis = np.where(live, 1.0, 0.0)
    diverged = np.array([False, False, True])
    return replace(run, estimate=estimate, live=live, detected=detected, nis=nis,
                   diverged=diverged)


def test_nees_counts_the_live_steps_only() -> None:
    """A diverged run's held steps have no covariance to test: scored against ``I`` their NEES
    is ``cap²`` (25e6 m² at the default cap) and the mean would be meaningless. The NEES test
    is over the live steps, as the NIS test; the divergence is counted in ``diverged``."""
    run = _diverged()
    s = score(run)
    values = nees(run.estimate, run.covariance, run.truth)
    assert values[2, 6:] == pytest.approx(5000.0**2)
    assert s["nees"]["mean"] == pytest.approx(values[run.live].mean())
    assert s["nees"]["mean"] == pytest.approx((10 * 1.0 + 10 * 4.0 + 6 * 9.0) / 26)
    assert s["nees"]["inside"] == 1.0  # 1, 4 and 9: inside chi2(4)'s 9.49, the held ones not
    assert s["diverged"] == 1
    assert s["armse_pos"] > 1000.0  # the position error keeps the cap


def test_a_divergence_does_not_smooth_the_mode_probabilities() -> None:
    """A diverged run's held uniform probabilities are not steps of its IMM: the total variation
    is over the step pairs both live, so a divergence does not lower it; every run diverged at
    its first step leaves no pair: None (null), not 0."""
    run = _diverged()
    mode_probs = run.mode_probs.copy()
    mode_probs[:, :, 0] = np.where(np.arange(10) % 2 == 0, 0.8, 0.2)  # TV 0.6 every step
    mode_probs[:, :, 1] = 1.0 - mode_probs[:, :, 0]
    mode_probs[2, 6:] = 0.5
    s = score(replace(run, mode_probs=mode_probs))
    assert s["mode_prob_tv"] == pytest.approx(0.6)
    lost = replace(run, live=np.zeros((3, 10), dtype=bool), diverged=np.ones(3, dtype=bool))
    assert score(lost)["mode_prob_tv"] is None


def test_no_live_step_leaves_the_consistency_tests_without_values() -> None:
    """Every run diverged at its first step: no NIS or NEES value counts, and the means and
    shares are None (JSON null), not 0 (a NEES mean of 0 would read as a measured one)."""
    run = _diverged()
    none = np.zeros((3, 10), dtype=bool)
    lost = replace(run, live=none, detected=none, nis=np.zeros((3, 10)),
                   diverged=np.ones(3, dtype=bool))
    s = score(lost)
    for test in ("nis", "nees"):
        assert s[test]["mean"] is None and s[test]["inside"] is None
    assert s["nees"]["bound"] == pytest.approx(9.4877, abs=1e-4)
    no_match = replace(run, true_model=np.full((3, 10), -1, dtype=np.int64))
    assert score(no_match)["mode_accuracy"] is None


def test_nis_counts_the_detections_only_against_chi2_of_the_measurement_dimension() -> None:
    """A missed detection of a live run (``detected`` False, ``live`` True) has no innovation:
    its NIS of 0 is not a value of the test. Counting it (the mask dropped) lowers the mean and
    raises the inside share; a NIS of a 2-d measurement is tested against chi2(2), not chi2(4)
    (whose bound 9.49 would take in the 7 and 8 that chi2(2)'s 5.99 leaves out)."""
    run = _rollout(np.zeros((2, 4), dtype=np.int64), np.ones((2, 4)), np.full((2, 4, 2), 0.5))
    nis = np.array([[1.0, 0.0, 7.0, 3.0], [0.5, 8.0, 0.0, 2.5]])
    detected = np.array([[True, False, True, True], [True, True, False, True]])
    s = score(replace(run, nis=nis, detected=detected))
    assert run.live.all()
    counted = [1.0, 7.0, 3.0, 0.5, 8.0, 2.5]
    bound = -2.0 * np.log(0.05)  # chi2(2)'s 95 % quantile: its CDF is 1 - exp(-x / 2)
    assert s["nis"]["dof"] == 2
    assert s["nis"]["bound"] == pytest.approx(bound, rel=1e-12)
    assert s["nis"]["mean"] == pytest.approx(sum(counted) / 6, rel=1e-12)
    assert s["nis"]["inside"] == pytest.approx(4 / 6, rel=1e-12)  # 1, 3, 0.5, 2.5


def test_nees_counts_the_missed_detections_of_a_live_run() -> None:
    """A missed detection leaves no NIS but the estimate and its covariance are still the
    tracker's: its NEES counts (the live steps, not the detections). By hand, with ``P = I``,
    the NEES is the squared position error: 1, 16, 1, 16 m² on run 0 with the 16s missed."""
    errors = np.array([[1.0, 4.0, 1.0, 4.0], [1.0, 1.0, 1.0, 1.0]])
    run = _rollout(np.zeros((2, 4), dtype=np.int64), errors, np.full((2, 4, 2), 0.5))
    detected = np.array([[True, False, True, False], [True, True, True, True]])
    s = score(replace(run, detected=detected, nis=np.where(detected, 1.0, 0.0)))
    assert s["nees"]["mean"] == pytest.approx((1 + 16 + 1 + 16 + 4 * 1) / 8, rel=1e-12)
    assert s["nees"]["inside"] == pytest.approx(6 / 8, rel=1e-12)  # 16 > chi2(4)'s 9.49
