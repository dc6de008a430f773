"""The ``bank_advantage`` reward: accuracy beyond the stay bank's IMMs, weighted by evidence."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import stay_core

from imm_gym import ConfigError, EnvConfig, TrackingCore
from imm_gym.sim.features import EVIDENCE_STAYS
from imm_gym.sim.stay_bank import STAY_BANK_FACTOR, STAY_BANK_FLOOR
from imm_gym.tracking.hetero import make_tracker
from imm_gym.tracking.tpm import stay_tpm

M = 3
STAYS = (1.0 / M, *EVIDENCE_STAYS)


def test_the_baseline_is_each_stay_s_imm_weighted_by_the_evidence_before_the_step() -> None:
    # the reference: each stay's IMM alone on the numpy engine, its combined estimate's error
    # from the truth, weighted by the softmax of the discounted evidence before the step
    core = stay_core(2, reward="bank_advantage", reward_scale=25.0)
    reference = make_tracker(core.config.bank, core.config.sensor, "ukf", 1.0, engine="numpy")
    states = [core.state_a for _ in STAYS]
    total = np.zeros((2, len(STAYS)))
    rng = np.random.default_rng(1)
    for _ in range(60):
        k1 = core.k + 1
        z, det = core.z[np.arange(2), k1], core.detected[np.arange(2), k1]
        w = np.exp(total - total.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        e = np.zeros((2, len(STAYS)))
        error = np.zeros((2, len(STAYS)))
        truth = core.truth[np.arange(2), k1, :2]
        for s, stay in enumerate(STAYS):
            states[s], out = reference.step(states[s], stay_tpm(M, stay), z, det)
            e[:, s] = np.where(det, np.log(np.sum(out.cbar * np.exp(out.loglik), axis=1)), 0.0)
            error[:, s] = np.linalg.norm(out.x[:, :2] - truth, axis=1)
        total = STAY_BANK_FACTOR * total + np.maximum(
            e - e.max(axis=1, keepdims=True), -STAY_BANK_FLOOR
        )
        result = core.step(rng.uniform(-1, 1, (2, M)))
        baseline = np.sum(w * error, axis=1)
        info = result.info
        np.testing.assert_allclose(info["stay_bank_position_error"], baseline, rtol=1e-7)
        np.testing.assert_allclose(
            info["reward_bank_advantage"], (baseline - info["position_error"]) / 25.0, rtol=1e-6,
            atol=1e-9,
        )
        np.testing.assert_allclose(result.reward, info["reward_bank_advantage"], rtol=0, atol=0)
    assert np.ptp(w[:, 1:]) > 0.1  # the weights moved away from uniform


@pytest.mark.parametrize(
    "detector",
    [
        {},
        {"detector": "shadow", "detector_share": 0.5},
        {"detector": "learned", "detector_share": 0.5},
    ],
)
def test_no_action_moves_the_baseline(detector: dict) -> None:
    """Neither the stays' evidence nor a detector's priors the stay bank runs move with the
    action (the turn-rate detector, which reads the steered tracker, is refused below)."""
    cores = [stay_core(3, reward="bank_advantage", **detector) for _ in range(2)]
    rngs = [np.random.default_rng(s) for s in (0, 1)]
    differ = False
    for _ in range(40):
        steps = [c.step(r.uniform(-1, 1, (3, M))).info for c, r in zip(cores, rngs, strict=True)]
        np.testing.assert_array_equal(
            steps[0]["stay_bank_position_error"], steps[1]["stay_bank_position_error"]
        )
        differ |= not np.array_equal(steps[0]["position_error"], steps[1]["position_error"])
    assert differ  # the actions did move the tracker


def test_a_baseline_the_turn_rate_detector_would_steer_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"bank_advantage.*turn_rate.*move its baseline"):
        EnvConfig(
            action_mode="stay", reward="bank_advantage", detector="turn_rate", detector_share=0.5
        )
    EnvConfig(action_mode="stay", reward="advantage", detector="turn_rate", detector_share=0.5)


def test_the_reward_runs_the_stay_bank_without_a_shadow() -> None:
    config = EnvConfig(reward="bank_advantage", shadow="none", family={"horizon": 60})
    core = TrackingCore(config, 2)
    assert core.stay_bank is not None
    core.reset(np.arange(2), [5, 6])
    info = core.step(np.zeros((2, core.action_dim))).info
    assert "reward_advantage" not in info
    np.testing.assert_allclose(
        info["reward_bank_advantage"],
        (info["stay_bank_position_error"] - info["position_error"]) / config.reward_scale,
    )
    # other rewards keep the stay bank out unless the features or the base need it
    assert TrackingCore(EnvConfig(family={"horizon": 60}), 1).stay_bank is None


def test_the_critic_sees_the_baseline_s_error() -> None:
    core = stay_core(2, reward="bank_advantage")
    for _ in range(10):
        core.step(np.zeros((2, M)))
    bank = core.stay_bank
    weights = np.exp(bank.evidence - bank.evidence.max(axis=1, keepdims=True))
    weights /= weights.sum(axis=1, keepdims=True)
    x = bank.state.x.reshape(2, len(STAYS), M, -1)
    mu = bank.state.mu.reshape(2, len(STAYS), M)
    estimate = np.einsum("rs,rsm,rsmi->ri", weights, mu, x)
    truth = core.truth[np.arange(2), core.k]
    expected = (estimate - truth) / np.array([50.0, 50.0, 5.0, 5.0])
    np.testing.assert_allclose(core.critic_state()[:, 4:8], expected, rtol=1e-5, atol=1e-6)
