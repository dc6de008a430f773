"""The mode-identification reward terms: the log score of the mode probabilities beyond the
shadow's on the true model, or the identification (argmax) beyond the shadow's."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.rewards import MODE_SCORE_FLOOR, mode_hit, mode_score
from imm_gym.tracking.imm import IMMState
from imm_gym.validation import ConfigError


def test_mode_score_by_hand() -> None:
    mu = np.array([[0.7, 0.2, 0.1], [0.1, 0.1, 0.8], [0.3, 0.3, 0.4]])
    mu_s = np.array([[0.5, 0.25, 0.25], [0.2, 0.4, 0.4], [0.3, 0.3, 0.4]])
    true = np.array([0, 2, -1])
    eps = MODE_SCORE_FLOOR
    expected = [np.log(0.7 + eps) - np.log(0.5 + eps), np.log(0.8 + eps) - np.log(0.4 + eps), 0.0]
    np.testing.assert_allclose(mode_score(mu, mu_s, true), expected, rtol=1e-15)


def test_the_mode_score_is_bounded_by_the_documented_floor() -> None:
    """A confident hit against a confident miss scores ln(1.001 / 0.001) ≈ 6.9 (the floor
    1e-3, as a literal: a test built from the constant cannot see it change)."""
    score = mode_score(np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]), np.array([0]))
    assert score[0] == pytest.approx(np.log(1.001 / 0.001), rel=1e-12)


def test_mode_hit_by_hand() -> None:
    """+1 where only the policy's argmax is the true model, -1 where only the shadow's, 0 where
    both or neither are, or no model matches."""
    mu = np.array([[0.7, 0.2, 0.1], [0.1, 0.1, 0.8], [0.3, 0.3, 0.4], [0.5, 0.4, 0.1],
                   [0.2, 0.5, 0.3], [0.2, 0.2, 0.6]])
    mu_s = np.array([[0.2, 0.5, 0.3], [0.1, 0.1, 0.8], [0.3, 0.3, 0.4], [0.1, 0.8, 0.1],
                     [0.2, 0.3, 0.5], [0.2, 0.2, 0.6]])
    true = np.array([0, 2, 1, 1, 0, -1])
    np.testing.assert_array_equal(mode_hit(mu, mu_s, true), [1.0, 0.0, 0.0, -1.0, 0.0, 0.0])


@pytest.mark.parametrize(("kind", "score_of"), [("log", mode_score), ("hit", mode_hit)])
def test_the_reward_adds_the_weighted_mode_score(kind: str, score_of) -> None:
    """Same episodes and actions with and without the term: the rewards differ by exactly
    ``mode_reward * info["mode_score"]``, the chosen score of the step's probabilities."""
    plain = TrackingCore(EnvConfig(), 6)
    paid = TrackingCore(EnvConfig(mode_reward=0.5, mode_score=kind), 6)
    for core in (plain, paid):
        core.reset(np.arange(6), list(range(6)))
    rng = np.random.default_rng(0)
    paid_steps = 0
    for _ in range(20):
        action = rng.uniform(-1, 1, (6, 9))
        a, b = plain.step(action), paid.step(action)
        score = score_of(b.info["mode_probs"], paid.mu_s, b.info["true_model"])
        np.testing.assert_array_equal(b.info["mode_score"], score)
        np.testing.assert_allclose(b.reward, a.reward + 0.5 * score, rtol=1e-12, atol=1e-12)
        paid_steps += int(np.count_nonzero(score))
    assert paid_steps > 0
    assert "mode_score" not in a.info


def test_mode_reward_is_checked() -> None:
    with pytest.raises(ConfigError, match="mode_reward"):
        EnvConfig(mode_reward=-1.0)
    with pytest.raises(ConfigError, match="mode_reward > 0 needs shadow"):
        EnvConfig(mode_reward=1.0, shadow="none", reward="error")
    with pytest.raises(ConfigError, match=r"mode_score.*'log', 'hit'"):
        EnvConfig(mode_score="brier")


def test_the_tpm_change_cost_is_the_divergence_from_the_previous_tpm() -> None:
    from imm_gym.tracking.tpm import row_divergence

    plain = TrackingCore(EnvConfig(action_mode="set"), 4)
    paid = TrackingCore(EnvConfig(action_mode="set", tpm_change_cost=0.3), 4)
    for core in (plain, paid):
        core.reset(np.arange(4), [9, 8, 7, 6])
    rng = np.random.default_rng(1)
    for _ in range(10):
        previous = paid.tpm
        action = rng.uniform(-1, 1, (4, 9))
        a, b = plain.step(action), paid.step(action)
        change = row_divergence(b.info["tpm"], previous)
        np.testing.assert_array_equal(b.info["tpm_change"], change)
        np.testing.assert_allclose(b.reward, a.reward - 0.3 * change, rtol=1e-12, atol=1e-12)
    assert np.all(change > 0.0)
    with pytest.raises(ConfigError, match="tpm_change_cost"):
        EnvConfig(tpm_change_cost=-0.1)


def test_a_failed_trackers_probabilities_score_lowest_and_identify_nothing() -> None:
    """A failed tracker's probabilities are NaN: the log score takes them as 0 on the true model
    (the lowest score, finite) and the identification as no model, even where ``argmax`` of the
    NaN row would point at the true model 0."""
    nan = np.full(3, np.nan)
    mu = np.array([nan, [0.7, 0.2, 0.1]])
    mu_s = np.array([[0.5, 0.25, 0.25], nan])
    true = np.array([0, 0])
    eps = MODE_SCORE_FLOOR
    expected = [np.log(eps) - np.log(0.5 + eps), np.log(0.7 + eps) - np.log(eps)]
    np.testing.assert_allclose(mode_score(mu, mu_s, true), expected, rtol=1e-15)
    np.testing.assert_array_equal(mode_hit(mu, mu_s, true), [-1.0, 1.0])


@pytest.mark.parametrize("kind", ["log", "hit"])
def test_a_failed_tracker_gets_a_finite_reward_with_the_mode_term(kind: str) -> None:
    """A covariance that overflows the EKF's innovation covariance fails slot 0's tracker (NaN
    outputs, terminated): its reward stays finite, the divergence penalty plus the mode term,
    and the other slot's is untouched."""
    plain = TrackingCore(EnvConfig(filter="ekf"), 2)
    paid = TrackingCore(EnvConfig(filter="ekf", mode_reward=0.05, mode_score=kind), 2)
    for core in (plain, paid):
        core.reset(np.arange(2), [0, 1])
        for _ in range(5):
            core.step(np.zeros((2, 9)))
        P = core.state_a.P.copy()
        P[0] = 1e307 * np.eye(4)
        core.state_a = IMMState(core.state_a.x, P, core.state_a.mu)
    a, b = plain.step(np.zeros((2, 9))), paid.step(np.zeros((2, 9)))
    assert b.terminated[0] and not b.terminated[1]
    assert np.all(np.isfinite(b.reward))
    assert b.reward[0] <= a.reward[0]
