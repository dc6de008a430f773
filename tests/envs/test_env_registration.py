"""Registration of the environment ids, the Gymnasium and SB3 checkers over the whole registry,
and ``gymnasium.make_vec`` with the native vector entry point."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import imm_gym
from imm_gym import EnvConfig
from imm_gym.envs import PRESETS, TPMAdaptEnv, TPMAdaptVectorEnv, register_envs

IDS = sorted(env_id for env_id in gym.registry if env_id.startswith("imm_gym/"))


def test_import_registers_every_preset() -> None:
    assert set(PRESETS) == set(IDS)
    for env_id, preset in PRESETS.items():
        spec = gym.spec(env_id)
        assert spec.entry_point == "imm_gym.envs.tpm_adapt:TPMAdaptEnv"
        assert spec.vector_entry_point == "imm_gym.envs.vector:TPMAdaptVectorEnv"
        assert spec.kwargs == {"preset": preset}
        env = gym.make(env_id)
        assert isinstance(env.unwrapped, TPMAdaptEnv)
        assert env.unwrapped.config == EnvConfig.build(preset)
        env.close()


def test_a_config_mapping_updates_the_ids_preset_and_an_envconfig_replaces_it() -> None:
    """``config={...}`` through ``gym.make`` and ``make_vec`` updates the id's preset, as keyword
    arguments and the SB3 adapter's ``env_id`` do (it replaced it: the paper id with one field
    given trained on the randomized family, the parallel id lost its bank B)."""
    paper = gym.make("imm_gym/TPMAdaptPaper-v0", config={"p_min": 0.02}).unwrapped.config
    assert paper.scenario == "paper" and paper.p_min == 0.02
    venv = gym.make_vec("imm_gym/TPMAdaptParallel-v0", num_envs=2,
                        vectorization_mode="vector_entry_point", config={"p_min": 0.1})
    assert venv.unwrapped.config.parallel and venv.unwrapped.config.p_min == 0.1
    assert "bank_b" in venv.unwrapped.config.obs_features
    venv.close()
    whole = EnvConfig(scenario="random", p_min=0.02)
    assert gym.make("imm_gym/TPMAdaptPaper-v0", config=whole).unwrapped.config == whole
    assert TPMAdaptEnv(config={"p_min": 0.02}).config == EnvConfig(p_min=0.02)


def test_a_numpy_integer_is_a_number_of_envs() -> None:
    venv = TPMAdaptVectorEnv(np.int64(2), config={"scenario": "paper"})
    assert venv.num_envs == 2 and type(venv.num_envs) is int
    with pytest.raises(ValueError, match="num_envs"):
        TPMAdaptVectorEnv(np.True_)


def test_presets_configure_what_they_claim() -> None:
    paper = gym.make("imm_gym/TPMAdaptPaper-v0").unwrapped.config
    assert paper.scenario == "paper" and paper.source.horizon == 150
    parallel = gym.make("imm_gym/TPMAdaptParallel-v0").unwrapped.config
    assert parallel.parallel and parallel.p_min == 0.05 and "bank_b" in parallel.obs_features
    random = gym.make("imm_gym/TPMAdapt-v0").unwrapped.config
    assert random.scenario == "random" and not random.parallel


def test_register_envs_twice_is_harmless() -> None:
    before = {env_id: gym.spec(env_id) for env_id in IDS}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        register_envs()
        register_envs()
        imm_gym.envs.register_envs()
    assert [str(w.message) for w in caught] == []
    after = sorted(env_id for env_id in gym.registry if env_id.startswith("imm_gym/"))
    assert after == IDS
    for env_id in IDS:
        assert gym.spec(env_id) == before[env_id]


def test_module_prefixed_id_works() -> None:
    env = gym.make("imm_gym:imm_gym/TPMAdapt-v0")
    assert env.spec is not None and env.spec.id == "imm_gym/TPMAdapt-v0"
    assert isinstance(env.unwrapped, TPMAdaptEnv)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_checker_passes_without_warnings(env_id: str) -> None:
    env = gym.make(env_id)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(env.unwrapped)
    assert [f"{w.category.__name__}: {w.message}" for w in caught] == []


@pytest.mark.parametrize("env_id", IDS)
def test_sb3_checker_passes_without_warnings(env_id: str) -> None:
    env = gym.make(env_id)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sb3_check_env(env.unwrapped, warn=True)
    assert [f"{w.category.__name__}: {w.message}" for w in caught] == []


@pytest.mark.parametrize("env_id", IDS)
def test_make_with_the_passive_checker_runs_an_episode_start(env_id: str) -> None:
    """``gym.make`` wraps with the passive env checker; it must not warn either."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make(env_id)
        obs, _ = env.reset(seed=1)
        for _ in range(3):
            obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
    assert [str(w.message) for w in caught] == []
    assert env.observation_space.contains(obs)
    assert isinstance(reward, float) and not terminated and not truncated


@pytest.mark.parametrize("env_id", IDS)
def test_make_vec_gives_the_native_vector_env_with_batched_spaces(env_id: str) -> None:
    venv = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point")
    assert isinstance(venv.unwrapped, TPMAdaptVectorEnv)
    assert venv.num_envs == 3
    single = gym.make(env_id)
    assert venv.single_observation_space == single.observation_space
    assert venv.single_action_space == single.action_space
    for batched, one in (
        (venv.observation_space, single.observation_space),
        (venv.action_space, single.action_space),
    ):
        assert isinstance(batched, spaces.Box) and batched.dtype == np.float32
        assert batched.shape == (3, *one.shape)
        np.testing.assert_array_equal(batched.low, np.broadcast_to(one.low, batched.shape))
        np.testing.assert_array_equal(batched.high, np.broadcast_to(one.high, batched.shape))
    assert venv.unwrapped.config == single.unwrapped.config
    obs, _ = venv.reset(seed=0)
    assert obs.dtype == np.float32 and venv.observation_space.contains(obs)
    obs, reward, terminated, truncated, _ = venv.step(venv.action_space.sample())
    assert venv.observation_space.contains(obs)
    assert reward.shape == terminated.shape == truncated.shape == (3,)


def test_make_vec_passes_keyword_overrides_to_the_vector_env() -> None:
    venv = gym.make_vec(
        "imm_gym/TPMAdaptPaper-v0",
        num_envs=2,
        vectorization_mode="vector_entry_point",
        obs_features=("tpm", "time"),
    )
    config = venv.unwrapped.config
    assert config.scenario == "paper" and config.obs_features == ("tpm", "time")
    assert venv.single_observation_space.shape == (6 + 9 + 1,)


def test_spaces_of_a_two_model_bank() -> None:
    env = gym.make(
        "imm_gym/TPMAdapt-v0",
        bank=[{"kind": "cv"}, {"kind": "ct", "turn_rate_deg": 3.0}],
        obs_features=("tpm", "loglik", "nis", "innovation", "time"),
    )
    assert env.action_space.shape == (4,)
    # mu, mu_prev (2 + 2), tpm 4, loglik 2, nis 2, innovation 2 x 2, time 1
    assert env.observation_space.shape == (2 + 2 + 4 + 2 + 2 + 4 + 1,)
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(np.zeros(4, np.float32))
    assert env.observation_space.contains(obs)


def test_each_id_makes_the_configuration_it_stands_for() -> None:
    """What ``gym.make(ID)`` tracks, field for field, written out here (README, "The environments"):
    the default configuration on the randomized family or the paper's scenario; with bank B,
    entropy fusion, TIP-IMM's floor 0.05 and bank B's probabilities observed; with source 002's
    heterogeneous bank, run by the EKF it needs."""
    from imm_gym.tracking.hetero import SONAR_HETERO_BANK

    expected = {
        "imm_gym/TPMAdapt-v0": EnvConfig(scenario="random"),
        "imm_gym/TPMAdaptPaper-v0": EnvConfig(scenario="paper"),
        "imm_gym/TPMAdaptParallel-v0": EnvConfig(
            scenario="random", parallel=True, p_min=0.05, obs_features=("bank_b",)
        ),
        "imm_gym/TPMAdaptHetero-v0": EnvConfig.build(
            {"scenario": "random", "bank": dict(SONAR_HETERO_BANK), "filter": "ekf"}
        ),
    }
    assert IDS == sorted(expected)
    for env_id, config in expected.items():
        env = gym.make(env_id)
        assert env.unwrapped.config == config, env_id
        env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_make_wraps_every_id_in_the_passive_checker(env_id: str) -> None:
    """``gym.make`` by id runs Gymnasium's passive checker (the spec does not disable it), so a
    user's first reset and step are checked."""
    from gymnasium.wrappers import PassiveEnvChecker

    assert gym.spec(env_id).disable_env_checker is False
    env, layers = gym.make(env_id), []
    while isinstance(env, gym.Wrapper):
        layers.append(type(env))
        env = env.env
    assert PassiveEnvChecker in layers
