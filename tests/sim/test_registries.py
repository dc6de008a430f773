"""Extending the simulation is one registration: a feature, a reward term or a named scenario
declared in its registry is accepted by EnvConfig and runs through the env, with no other edit."""

from __future__ import annotations

from collections.abc import Iterator

import gymnasium as gym
import numpy as np
import pytest

import imm_gym  # noqa: F401  (registers the ids)
from imm_gym import ConfigError, EnvConfig, Scenario, Segment
from imm_gym.scenarios import catalog
from imm_gym.sim import features, rewards
from imm_gym.sim.features import Feature, datasheet_table
from imm_gym.sim.rewards import RewardTerm


@pytest.fixture
def max_prob() -> Iterator[str]:
    features.register(
        Feature("max_prob", "largest model probability", lambda M, m: 1, 0.0, 1.0,
                lambda v: v.mu.max(axis=-1, keepdims=True), size_label="1")
    )
    yield "max_prob"
    del features.FEATURES["max_prob"]


@pytest.fixture
def squared_error() -> Iterator[str]:
    rewards.register(RewardTerm("squared_error", lambda step, s: -((step.position_error / s) ** 2)))
    yield "squared_error"
    del rewards.REWARD_TERMS["squared_error"]


@pytest.fixture
def straight() -> Iterator[str]:
    catalog.register(
        "straight", lambda: Scenario((Segment(30),), position=(4000.0, 0.0), velocity=(0.0, 20.0))
    )
    yield "straight"
    del catalog.SCENARIOS["straight"]


def test_a_registered_feature_is_observed(max_prob: str) -> None:
    env = gym.make("imm_gym/TPMAdapt-v0", obs_features=("tpm", max_prob))
    assert env.observation_space.shape == (6 + 9 + 1,)
    assert "``max_prob``" in datasheet_table()
    obs, _ = env.reset(seed=1)
    for _ in range(5):
        obs, _, _, _, info = env.step(env.action_space.sample())
        assert obs[-1] == np.float32(info["mode_probs"].max())


def test_an_unregistered_feature_is_refused() -> None:
    with pytest.raises(ConfigError, match="obs_features"):
        EnvConfig(obs_features=("max_prob",))


def test_a_registered_reward_term_is_rewarded(squared_error: str) -> None:
    env = gym.make("imm_gym/TPMAdapt-v0", reward=squared_error)
    env.reset(seed=2)
    _, reward, _, _, info = env.step(np.zeros(9, dtype=np.float32))
    assert reward == pytest.approx(-((info["position_error"] / 10.0) ** 2), rel=1e-12)
    assert info["reward_squared_error"] == reward
    assert "reward_advantage" in info  # the other terms are still reported


def test_a_registered_scenario_is_a_scenario_name(straight: str) -> None:
    env = gym.make("imm_gym/TPMAdapt-v0", scenario=straight)
    _, info = env.reset(seed=0)
    np.testing.assert_array_equal(info["true_state"], [4000.0, 0.0, 0.0, 20.0])
    steps = 0
    truncated = False
    while not truncated:
        _, _, _, truncated, _ = env.step(np.zeros(9, dtype=np.float32))
        steps += 1
    assert steps == 30
    with pytest.raises(ValueError, match="already"):
        catalog.register(straight, lambda: Scenario((Segment(5),)))


def test_a_feature_name_is_registered_once() -> None:
    # a second "tpm" would silently replace the built-in block of every configuration using it
    builtin = features.FEATURES["tpm"]
    with pytest.raises(ValueError, match="'tpm' is already registered"):
        features.register(
            Feature("tpm", "another", lambda M, m: 1, 0.0, 1.0, lambda v: v.mu[:, :1])
        )
    assert features.FEATURES["tpm"] is builtin


def test_the_datasheet_gives_each_block_its_bounds() -> None:
    """The table's min and max columns are the observation space's bounds of each block (the
    relative log-likelihood ``loglik`` lies in [-1, 0], the turn rate in [-1, 1])."""
    rows = {row.split(" | ")[0][2:]: row for row in datasheet_table().splitlines()}
    assert rows["``loglik``"].endswith(" | -1 | 0 |")
    assert rows["``turn_rate``"].endswith(" | -1 | 1 |")
    for name in features.FEATURES:
        low, high = features.bounds((name,), 3, 2)
        cells = rows[f"``{name}``"].split(" | ")
        assert (float(cells[-2]), float(cells[-1].rstrip(" |"))) == (low[-1], high[-1]), name


def test_the_datasheet_names_what_a_block_needs() -> None:
    # the meaning cell ends with what the block is computed from beyond bank A
    meanings = {row.split(" | ")[0][2:]: row.split(" | ")[1]
                for row in datasheet_table().splitlines() if row.startswith("| ``")}
    needs = {"shadow_probs": " [shadow]", "stay_evidence": " [shadow]", "bank_b": " [parallel]",
             "stay_bank_evidence": " [stay bank]", "tracking_index": " [linear bank]",
             "loglik": " by it (M)"}
    for name, end in needs.items():
        assert meanings[f"``{name}``"].endswith(end), name


def test_the_shadow_features_are_those_computed_from_the_shadow() -> None:
    assert features.shadow_features() == (
        "shadow_probs", "shadow_turn_rate", "shadow_turn_rate_ema", "turn_magnitude_ema",
        "shadow_turn_rate_bank", "turn_magnitude_bank_ema", "shadow_evidence", "stay_evidence",
    )
