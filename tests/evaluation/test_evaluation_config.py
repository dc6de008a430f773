"""Tests of imm_gym.evaluation.rollout.evaluation_config: a roll-out reads no reward, so the
reward terms are off whatever the policy was trained with, and the shadow IMM runs only where
what the policy observes or acts with is computed from it."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from imm_gym.evaluation.rollout import evaluation_config, needs_shadow, rollout, score
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig

# what training accepts (its shadow defaults to "fixed") with nothing observed from the shadow
TRAINED_WITH_A_REWARD = [
    {"reward": "squared_advantage"},
    {"reward": "advantage", "mode_reward": 0.05},
    {"reward": "advantage", "tpm_cost": 0.1, "tpm_change_cost": 0.2},
    {"mode_reward": 0.05, "mode_score": "hit"},
    {"reward": "bank_advantage"},
]


@pytest.mark.parametrize("overrides", TRAINED_WITH_A_REWARD)
def test_a_reward_that_needs_the_shadow_is_turned_off_with_it(overrides: dict[str, Any]) -> None:
    config = evaluation_config(EnvConfig(scenario="paper"), overrides)
    assert (config.reward, config.tpm_cost, config.tpm_change_cost, config.mode_reward) == (
        "error", 0.0, 0.0, 0.0
    )
    assert config.shadow == "none"


@pytest.mark.parametrize(
    ("overrides", "shadow"),
    [
        # the shadow detector's belief observed, placing nothing
        ({"obs_features": ("detector_belief",), "mode_reward": 0.05}, "fixed"),
        ({"obs_features": ("detector_belief",), "detector": "shadow"}, "fixed"),
        # ... or placing the jumps
        ({"action_mode": "stay", "detector_share": 0.5, "reward": "squared_advantage"}, "fixed"),
        # a feature computed from the shadow
        ({"obs_features": ("shadow_probs",), "tpm_cost": 0.1}, "fixed"),
        # ... among features that are not (any one of them needs it)
        ({"obs_features": ("nis", "shadow_probs", "tpm")}, "fixed"),
        # another detector's belief needs no shadow
        ({"action_mode": "stay", "detector": "turn_rate", "detector_share": 0.5,
          "obs_features": ("detector_belief",), "mode_reward": 0.05}, "none"),
        # a policy's shadow 'fixed' that nothing reads
        ({"shadow": "fixed", "obs_features": ("nis",)}, "none"),
    ],
)
def test_the_shadow_runs_where_the_policy_reads_it(overrides: dict[str, Any], shadow: str) -> None:
    config = evaluation_config(EnvConfig(scenario="paper"), overrides)
    assert config.shadow == shadow
    assert needs_shadow(config) == (shadow == "fixed")
    assert config.reward == "error" and config.mode_reward == 0.0 and config.tpm_cost == 0.0


def test_a_base_without_a_shadow_gets_one_where_the_policy_reads_it() -> None:
    base = EnvConfig(scenario="paper", shadow="none", reward="error")
    assert evaluation_config(base, {"obs_features": ("shadow_probs",)}).shadow == "fixed"


class Linear:
    """A deterministic policy whose actions depend on every entry of the observation."""

    def __init__(self, obs_dim: int, action_dim: int) -> None:
        self.w = np.random.default_rng(5).normal(size=(obs_dim, action_dim)) / np.sqrt(obs_dim)

    def predict(self, obs: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        return np.tanh(np.asarray(obs, dtype=np.float64) @ self.w), None


@pytest.mark.parametrize(
    "trained",
    [
        {"reward": "squared_advantage", "obs_features": ("nis", "turn_rate", "prob_ema")},
        {"mode_reward": 0.05, "tpm_cost": 0.1, "obs_features": ("loglik", "innovation")},
        {"obs_features": ("detector_belief", "turn_rate_ema")},
        {"action_mode": "stay", "stay_base": "evidence", "reward": "bank_advantage",
         "obs_features": ("stay_evidence",)},
        {"action_mode": "stay", "detector": "turn_rate", "detector_share": 0.5,
         "reward": "advantage", "obs_features": ("detector_belief",)},
    ],
)
def test_the_roll_out_is_the_trained_configurations(trained: dict[str, Any]) -> None:
    """Turning the reward and an unread shadow off changes no record of a roll-out: the same
    numbers as on the configuration the policy was trained on (shadow and reward as trained)."""
    as_trained = EnvConfig(scenario="random", **trained)
    assert as_trained.shadow == "fixed"
    evaluated = evaluation_config(EnvConfig(scenario="random"), trained)
    core = TrackingCore(as_trained)
    policy = Linear(core.obs_dim, core.action_dim)
    a = rollout(policy, as_trained, 4, 3)
    b = rollout(policy, evaluated, 4, 3)
    for f in fields(a):
        np.testing.assert_array_equal(getattr(a, f.name), getattr(b, f.name), f.name)


@pytest.mark.parametrize(
    "env_kwargs",
    [
        {"scenario": "paper", "reward": "squared_advantage"},
        {"scenario": "paper", "mode_reward": 0.05},
        {"scenario": "paper", "obs_features": ["detector_belief"]},
    ],
)
def test_an_agent_trained_with_a_shadow_reward_is_validated_and_evaluated(
    env_kwargs: dict[str, Any], tmp_path: Path
) -> None:
    """Training takes these settings (its shadow defaults to 'fixed'); the validation during
    training and the evaluation of the saved agent took them to shadow 'none' and refused."""
    from stable_baselines3 import PPO

    from agents.policy import load_agent
    from agents.training import (
        build_algorithm,
        make_training_env,
        save_agent,
        validation_armse,
    )

    env = make_training_env("imm_gym/TPMAdapt-v0", 2, 0, env_kwargs, True, 1, 0.9)
    model = build_algorithm(PPO, "MlpPolicy", env, 0, n_steps=8, batch_size=16)
    model.learn(16)
    armse = validation_armse(model, env, "imm_gym/TPMAdapt-v0", env_kwargs, 1, "ppo", 2)
    assert np.isfinite(armse)
    save_agent(tmp_path, model, env, env_kwargs, "ppo", 1)
    policy = load_agent(tmp_path)
    config = evaluation_config(EnvConfig(scenario="paper"), policy.env_overrides)
    assert np.isfinite(score(rollout(policy, config, 2, 0))["armse_pos"])
