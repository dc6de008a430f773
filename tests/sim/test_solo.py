"""The scalar env's compiled single-slot step (imm_gym.sim.solo) against the core's own step:
the same observation, reward, ends and info entries bit for bit, and the same core state, over
whole episodes, resets and divergences; which configurations it takes; its errors."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from imm_gym.envs import TPMAdaptEnv
from imm_gym.sim import rewards
from imm_gym.sim.actions import ActionError
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.presets import CONTINUOUS_BANK
from imm_gym.sim.solo import SoloStep
from imm_gym.tracking.hetero import SONAR_HETERO_BANK

SHORT = {"scenario": "random", "family": {"horizon": 20, "n_segments": (1, 2), "min_duration": 10}}

CONFIGS = {
    "default": {},
    "parallel_floor": {**SHORT, "parallel": True, "p_min": 0.05},
    "diverging": {**SHORT, "divergence_error": 40.0},
    "set_outliers_missed": {
        **SHORT,
        "action_mode": "set",
        "sensor": {"outlier_prob": 0.1, "outlier_scale": 20.0, "detection_prob": 0.7},
    },
    "paper_error_no_shadow": {"scenario": "paper", "reward": "error", "shadow": "none"},
    "squared_advantage_odd_scale": {**SHORT, "reward": "squared_advantage", "reward_scale": 7.3},
    "stay_measurement_scale": {**SHORT, "action_mode": "stay", "reward_scale": "measurement"},
    "stay_step_parallel": {**SHORT, "action_mode": "stay_step", "parallel": True},
    "ukf_cholesky": {**SHORT, "filter": "ukf-cholesky"},
    "varied_conditions": {
        **SHORT,
        "bank": CONTINUOUS_BANK,
        "sojourn": (20.0, 8.0, 8.0),
        "vary": {"T": (0.5, 5.0), "sigma_r": (10.0, 100.0), "speed": (5.0, 300.0)},
    },
}

#: every attribute of the core a step writes
CORE_ARRAYS = TrackingCore._SLOT_ARRAYS


def assert_core_equal(core: TrackingCore, reference: TrackingCore) -> None:
    for name in CORE_ARRAYS:
        np.testing.assert_array_equal(getattr(core, name), getattr(reference, name), err_msg=name)
    for bank in ("state_a", "state_b", "state_s"):
        for part in ("x", "P", "mu"):
            np.testing.assert_array_equal(
                getattr(getattr(core, bank), part),
                getattr(getattr(reference, bank), part),
                err_msg=f"{bank}.{part}",
            )


def run_against_the_core(
    config: dict, steps: int, seed: int, low: float = -1.5
) -> tuple[int, int]:
    """Step the scalar env (solo step) and a core with N = 1 with the same random actions,
    compare everything after every step, reset both where an episode ends; the episodes seen and
    how many of them ended by divergence."""
    env = TPMAdaptEnv(config=config)
    assert env._solo is not None
    reference = TrackingCore(env.config, 1)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    reference.reset(np.array([0]), [seed])
    np.testing.assert_array_equal(obs, reference.observe()[0])
    episodes = divergences = 0
    for t in range(steps):
        action = rng.uniform(low, -low, env.action_space.shape).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        result = reference.step(action[None])
        assert list(info) == list(result.info)
        for key, value in info.items():
            expected = result.info[key][0]
            assert np.array_equal(value, expected), (t, key, value, expected)
            assert np.shape(value) == np.shape(expected), key
        np.testing.assert_array_equal(obs, result.obs[0])
        assert obs.dtype == np.float32
        assert reward == result.reward[0], (t, reward - result.reward[0])
        assert (terminated, truncated) == (result.terminated[0], result.truncated[0])
        if t % 7 == 0:
            assert_core_equal(env.core, reference)
        if terminated or truncated:
            assert_core_equal(env.core, reference)
            episodes += 1
            divergences += terminated
            assert terminated == info["diverged"]
            obs, _ = env.reset()
            reference.reset(np.array([0]), [None])
            np.testing.assert_array_equal(obs, reference.observe()[0])
    return episodes, divergences


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_the_solo_step_is_the_cores_step(name: str) -> None:
    config = CONFIGS[name]
    long_episodes = config.get("scenario", "random") == "paper" or not config
    episodes, divergences = run_against_the_core(
        config, steps=320 if long_episodes else 160, seed=5
    )
    assert episodes >= 2
    if name == "diverging":
        assert divergences >= 3


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31 - 1),
    mode=st.sampled_from(["scale", "set", "stay", "stay_step"]),
    parallel=st.booleans(),
    p_min=st.sampled_from([0.0, 1e-4, 0.2]),
)
def test_the_solo_step_is_the_cores_step_for_random_settings(seed, mode, parallel, p_min) -> None:
    config = {**SHORT, "action_mode": mode, "parallel": parallel, "p_min": p_min}
    run_against_the_core(config, steps=25, seed=seed, low=-3.0)


@pytest.mark.parametrize(
    ("changes", "render_mode"),
    [
        ({"obs_features": ("tpm",)}, None),
        ({"action_mode": "stay", "stay_base": "evidence"}, None),
        ({"action_mode": "stay", "stay_base": "uniform"}, None),
        ({"action_mode": "stay", "stay_base": "uniform", "detector_share": 0.5,
          "detector": "turn_rate"}, None),
        ({"engine": "numpy"}, None),
        ({"tpm_cost": 0.1}, None),
        ({"tpm_change_cost": 0.1}, None),
        ({"mode_reward": 0.1}, None),
        ({"bank": SONAR_HETERO_BANK, "filter": "ekf"}, None),
        ({}, "rgb_array"),
    ],
)
def test_other_configurations_step_through_the_core(changes: dict, render_mode) -> None:
    env = TPMAdaptEnv(config=changes, render_mode=render_mode)
    assert env._solo is None
    assert not SoloStep.fits(TrackingCore(env.config, 1)) or render_mode is not None
    env.reset(seed=0)
    *_, info = env.step(np.zeros(env.action_space.shape))
    assert isinstance(info["step"], int) and isinstance(info["diverged"], bool)
    assert isinstance(info["position_error"], float) and info["estimate"].shape == (4,)
    env.close()


def test_the_uniform_base_steps_from_the_uniform_tpm() -> None:
    """The scalar env's zero action on the ``uniform`` base is the uniform TPM, as the core's
    (the compiled single-slot step moves from the tracker's TPM only, so it does not take it)."""
    config = {"action_mode": "stay", "stay_base": "uniform"}
    env = TPMAdaptEnv(config=config)
    env.reset(seed=3)
    reference = TrackingCore(EnvConfig(**config), 1)
    reference.reset(np.arange(1), [3])
    for _ in range(5):
        *_, info = env.step(np.zeros(3))
        expected = reference.step(np.zeros((1, 3))).info["tpm"][0]
        np.testing.assert_array_equal(info["tpm"], expected)
    np.testing.assert_allclose(info["tpm"], np.full((3, 3), 1.0 / 3.0), rtol=1e-12)
    env.close()


def test_a_core_with_more_slots_does_not_fit() -> None:
    assert SoloStep.fits(TrackingCore(EnvConfig(), 1))
    assert not SoloStep.fits(TrackingCore(EnvConfig(), 2))
    with pytest.raises(ValueError, match="fits"):
        SoloStep(TrackingCore(EnvConfig(), 2))


def test_stepping_before_a_reset_or_after_the_end_is_refused() -> None:
    env = TPMAdaptEnv(config=SHORT)
    action = np.zeros(env.action_space.shape, dtype=np.float32)
    with pytest.raises(RuntimeError, match="call reset before step"):
        env.step(action)
    env.reset(seed=0)
    truncated = False
    while not truncated:
        _, _, _, truncated, _ = env.step(action)
    with pytest.raises(RuntimeError, match="call reset before step"):
        env.step(action)


def test_a_bad_action_is_refused_and_changes_nothing() -> None:
    env = TPMAdaptEnv(config=SHORT)
    reference = TrackingCore(env.config, 1)
    env.reset(seed=4)
    reference.reset(np.array([0]), [4])
    bad = np.zeros(9)
    bad[4] = np.nan
    with pytest.raises(ActionError, match="finite"):
        env.step(bad)
    with pytest.raises(ActionError, match=r"shape \(9,\)"):
        env.step(np.zeros(3))
    assert_core_equal(env.core, reference)
    action = np.full(9, 0.3)
    obs, reward, _, _, info = env.step(action)
    result = reference.step(action[None])
    np.testing.assert_array_equal(obs, result.obs[0])
    assert reward == result.reward[0]
    np.testing.assert_array_equal(info["tpm"], result.info["tpm"][0])


def test_each_step_returns_fresh_objects() -> None:
    env = TPMAdaptEnv()
    env.reset(seed=1)
    obs, _, _, _, info = env.step(np.zeros(9))
    kept_obs, kept = obs.copy(), {key: np.copy(value) for key, value in info.items()}
    for _ in range(3):
        env.step(np.full(9, 0.5))
    np.testing.assert_array_equal(obs, kept_obs)
    for key, value in info.items():
        np.testing.assert_array_equal(value, kept[key], err_msg=key)
    info["mode_probs"][:] = 0.0  # the caller's arrays are theirs
    *_, info2 = env.step(np.zeros(9))
    assert np.isclose(info2["mode_probs"].sum(), 1.0)
    assert isinstance(info2["step"], int) and isinstance(info2["diverged"], bool)
    assert isinstance(info2["true_model"], int) and isinstance(info2["detected"], bool)


def test_infos_kept_over_episodes_stay_as_they_were() -> None:
    env = TPMAdaptEnv(config=SHORT)
    env.reset(seed=2)
    kept, copies = [], []
    for episode in range(2):
        done = False
        while not done:
            *_, terminated, truncated, info = env.step(np.full(9, 0.3 * episode))
            kept.append(info)
            copies.append({key: np.copy(value) for key, value in info.items()})
            done = terminated or truncated
        env.reset()
    env.step(np.zeros(9))
    for info, saved in zip(kept, copies, strict=True):
        for key, value in info.items():
            np.testing.assert_array_equal(value, saved[key], err_msg=key)
    arrays = [value for info in kept for value in info.values() if isinstance(value, np.ndarray)]
    for i, value in enumerate(arrays):  # no two entries share memory
        assert not any(np.shares_memory(value, other) for other in arrays[i + 1 :])


@pytest.mark.parametrize(
    "shape_it",
    [
        lambda a: np.asfortranarray(np.stack([a, a], axis=1))[:, 0],  # a strided column
        lambda a: np.broadcast_to(a[:1], a.shape),  # read-only, stride 0
        lambda a: a[::-1].copy()[::-1],  # reversed twice: negative stride
        lambda a: a.astype(np.float32),
        lambda a: [float(v) for v in a],
    ],
)
def test_any_action_array_layout_steps_as_the_core(shape_it) -> None:
    env = TPMAdaptEnv(config=SHORT)
    reference = TrackingCore(env.config, 1)
    env.reset(seed=6)
    reference.reset(np.array([0]), [6])
    rng = np.random.default_rng(6)
    for _ in range(5):
        action = shape_it(rng.uniform(-1.0, 1.0, 9))
        obs, reward, *_ = env.step(action)
        result = reference.step(np.asarray(action, dtype=np.float64)[None])
        np.testing.assert_array_equal(obs, result.obs[0])
        assert reward == result.reward[0]
    assert_core_equal(env.core, reference)


def test_the_core_is_current_after_every_step() -> None:
    env = TPMAdaptEnv(config=SHORT)
    core = env.core  # held across steps
    reference = TrackingCore(env.config, 1)
    env.reset(seed=8)
    reference.reset(np.array([0]), [8])
    for t in range(6):
        action = np.full(9, 0.1 * t)
        env.step(action)
        reference.step(action[None])
        assert_core_equal(core, reference)
        assert core.k[0] == t + 1


@pytest.mark.parametrize("bypass", ["reset", "step"])
def test_a_core_reset_or_stepped_by_itself_is_loaded_again(bypass: str) -> None:
    env = TPMAdaptEnv(config=SHORT)
    reference = TrackingCore(env.config, 1)
    env.reset(seed=9)
    reference.reset(np.array([0]), [9])
    for core in (env.core, reference):
        core.step(np.full((1, 9), 0.2))
        if bypass == "reset":
            core.reset(np.array([0]), [10])
        else:
            core.step(np.full((1, 9), -0.2))
    obs, reward, _, _, info = env.step(np.full(9, 0.4))
    result = reference.step(np.full((1, 9), 0.4))
    np.testing.assert_array_equal(obs, result.obs[0])
    assert reward == result.reward[0]
    assert info["step"] == result.info["step"][0]
    assert_core_equal(env.core, reference)


@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
@pytest.mark.parametrize("changes", [{}, {"obs_features": ["loglik"]}])
def test_a_copy_taken_mid_episode_steps_as_the_original(how: str, changes: dict) -> None:
    env = TPMAdaptEnv(config={**SHORT, **changes})
    assert (env._solo is not None) == (not changes)
    env.reset(seed=4)
    for _ in range(5):
        env.step(np.full(env.action_space.shape, -0.4))
    twin = pickle.loads(pickle.dumps(env)) if how == "pickle" else copy.deepcopy(env)
    rng = np.random.default_rng(0)
    for t in range(60):  # over episode ends and resets without a seed
        action = rng.uniform(-1, 1, env.action_space.shape)
        obs, reward, terminated, truncated, info = env.step(action)
        obs2, reward2, terminated2, truncated2, info2 = twin.step(action)
        np.testing.assert_array_equal(obs, obs2)
        assert (reward, terminated, truncated) == (reward2, terminated2, truncated2), t
        assert list(info) == list(info2)
        for key, value in info.items():
            np.testing.assert_array_equal(value, info2[key], err_msg=f"{t} {key}")
        if terminated or truncated:
            np.testing.assert_array_equal(env.reset()[0], twin.reset()[0])
    assert_core_equal(twin.core, env.core)


def test_a_copy_where_the_step_no_longer_fits_steps_through_the_core() -> None:
    """Unpickled in a process whose reward registry holds another term, a scalar env steps
    through the core (its compiled step covers the built-in terms only), with the same numbers."""
    env = TPMAdaptEnv(config=SHORT)
    env.reset(seed=2)
    for _ in range(4):
        env.step(np.full(env.action_space.shape, 0.3))
    blob = pickle.dumps(env)
    rewards.register(rewards.RewardTerm("extra_for_the_test", rewards.error))
    try:
        twin = pickle.loads(blob)
    finally:
        del rewards.REWARD_TERMS["extra_for_the_test"]
    assert env._solo is not None and twin._solo is None
    for t in range(40):
        action = np.full(env.action_space.shape, 0.5 if t % 3 else -0.7)
        obs, reward, terminated, truncated, info = env.step(action)
        obs2, reward2, terminated2, truncated2, info2 = twin.step(action)
        np.testing.assert_array_equal(obs, obs2)
        assert (reward, terminated, truncated) == (reward2, terminated2, truncated2), t
        for key, value in info.items():
            np.testing.assert_array_equal(value, info2[key], err_msg=f"{t} {key}")
        if terminated or truncated:
            np.testing.assert_array_equal(env.reset()[0], twin.reset()[0])
