"""The Gymnasium environments: checkers over the registry, classical IMM as the zero action,
TIP-IMM's step as a scale action, scalar/vector lock-step across autoresets, the SB3 adapter,
configuration errors, and a fuzz test."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import imm_gym
from imm_gym import IMM, ActionError, ConfigError, EnvConfig, Sonar, TrackingCore
from imm_gym.envs import PRESETS, TPMAdaptVectorEnv
from imm_gym.envs.sb3 import TPMAdaptVecEnv
from imm_gym.fusion import entropy, fuse
from imm_gym.models import paper_bank
from imm_gym.montecarlo import draw_batch
from imm_gym.scenarios import paper_scenario
from imm_gym.tip import tip_factors
from imm_gym.tpm import apply_floor, stay_tpm

IDS = sorted(k for k in gym.registry if k.startswith("imm_gym/"))
SHORT = {"scenario": "random", "family": {"horizon": 20, "n_segments": (1, 2)}}


def test_registration_is_idempotent_and_module_syntax_works() -> None:
    assert set(PRESETS) <= set(IDS)
    imm_gym.envs.register_envs()
    assert gym.make("imm_gym:imm_gym/TPMAdapt-v0").spec.id == "imm_gym/TPMAdapt-v0"


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_and_sb3_checkers_pass_without_warnings(env_id: str) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(gym.make(env_id).unwrapped)
        sb3_check_env(gym.make(env_id).unwrapped)
    assert [str(w.message) for w in caught] == []


@pytest.mark.parametrize("env_id", IDS)
def test_make_vec_gives_the_native_vector_env(env_id: str) -> None:
    venv = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point")
    assert isinstance(venv.unwrapped, TPMAdaptVectorEnv)
    obs, _ = venv.reset(seed=0)
    assert obs.shape == (3, *venv.single_observation_space.shape)
    assert venv.observation_space.contains(obs)


def test_zero_action_is_classical_imm_exactly() -> None:
    env = gym.make("imm_gym/TPMAdaptPaper-v0")
    env.reset(seed=5)
    batch = draw_batch(paper_scenario(), Sonar(), 1, 5)
    ref = IMM(paper_bank(), Sonar()).run(
        batch.measurements.z[:, 1:],
        stay_tpm(3, 0.995),
        batch.x0,
        batch.P0,
        detected=batch.measurements.detected[:, 1:],
    )
    for k in range(150):
        _, reward, term, trunc, info = env.step(np.zeros(9, dtype=np.float32))
        np.testing.assert_array_equal(info["estimate"], ref.x[0, k])
        np.testing.assert_array_equal(info["mode_probs"], ref.mode_probs[0, k])
        np.testing.assert_array_equal(info["true_state"], batch.truth.states[0, k + 1])
        assert reward == 0.0 and not term
    assert trunc


def test_tip_step_as_a_scale_action_by_hand() -> None:
    tpm = np.array([[0.8, 0.1, 0.1], [0.2, 0.7, 0.1], [0.1, 0.1, 0.8]])
    mu_prev = np.array([0.5, 0.3, 0.2])
    mu_now = np.array([0.6, 0.25, 0.15])  # main model 0 grows; Delta = (0.1, -0.05, -0.05)
    # eq. (16) for both others: pi_0j * beta, pi_j0 * alpha; pi_00 * alpha
    by_hand = tpm.copy()
    by_hand[0] = [0.8 * 1.1, 0.1 * 0.9, 0.1 * 0.9]
    by_hand[1, 0] *= 1.1
    by_hand[2, 0] *= 1.1
    by_hand /= by_hand.sum(axis=1, keepdims=True)
    f = tip_factors(mu_now[None], mu_prev[None])[0]
    np.testing.assert_allclose(tpm * f / (tpm * f).sum(1, keepdims=True), by_hand, rtol=1e-15)
    core = TrackingCore(EnvConfig(scenario="paper", max_factor=2.0, p_min=1e-3), 1)
    action = (np.log(f) / math.log(2.0)).reshape(1, 9)
    np.testing.assert_allclose(core.tpm_from_action(action, tpm[None])[0], by_hand, rtol=1e-13)


def test_tip_readings_differ_when_the_main_model_decays() -> None:
    mu_prev = np.array([[0.7, 0.2, 0.1]])
    mu_now = np.array([[0.5, 0.45, 0.05]])  # Delta_0 = -0.2, Delta_2 = -0.05 > Delta_0
    lit = tip_factors(mu_now, mu_prev, reading="literal")[0]
    intent = tip_factors(mu_now, mu_prev, reading="intent")[0]
    assert lit[0, 0] == intent[0, 0] == 0.9
    # j = 2 does not decay faster: literal gives (16), intent gives (15)
    assert (lit[0, 2], lit[2, 0]) == (0.9, 1.1)
    assert (intent[0, 2], intent[2, 0]) == (1.1, 0.9)
    changed = tip_factors(np.array([[0.2, 0.7, 0.1]]), mu_prev)  # main model changed
    np.testing.assert_array_equal(changed, np.ones((1, 3, 3)))


def test_floor_keeps_valid_rows_and_bounds_every_entry() -> None:
    tpm = stay_tpm(3, 0.995)[None]
    np.testing.assert_array_equal(apply_floor(tpm, 1e-3), tpm)
    rng = np.random.default_rng(0)
    raw = rng.random((200, 3, 3)) ** 6
    for p_min in (0.0, 0.05, 0.3):
        t = apply_floor(raw, p_min)
        np.testing.assert_allclose(t.sum(-1), 1.0, atol=1e-12)
        assert t.min() >= p_min - 1e-12 and t.max() <= 1 - p_min + 1e-12
    with pytest.raises(ConfigError, match="p_min"):
        apply_floor(raw, 0.34)


def test_entropy_fusion_by_hand() -> None:
    u_a, u_b = np.array([[0.7, 0.2, 0.1]]), np.array([[0.4, 0.3, 0.3]])
    h = lambda u: -sum(p * math.log2(p) for p in u)  # noqa: E731
    ha, hb = h(u_a[0]), h(u_b[0])
    expected = hb / (ha + hb) * u_a + ha / (ha + hb) * u_b
    np.testing.assert_allclose(fuse(u_a, u_b), expected, rtol=1e-14)
    assert entropy(np.array([1.0, 0.0, 0.0])) == 0.0
    np.testing.assert_allclose(fuse(np.eye(3)[:1], np.eye(3)[1:2]), [[0.5, 0.5, 0.0]])


def _rollout_scalar(config, seed, actions):
    env = gym.make("imm_gym/TPMAdapt-v0", config=config)
    obs, _ = env.reset(seed=seed)
    out, done = [obs], False
    for a in actions:
        if done:
            obs, _ = env.reset()
            out.append(obs)
            done = False
            continue
        obs, _r, term, trunc, _ = env.step(a)
        out.append(obs)
        done = term or trunc
    return out


@pytest.mark.parametrize(
    "extra",
    [
        {},
        {
            "parallel": True,
            "obs_features": (
                "tpm",
                "loglik",
                "nis",
                "innovation",
                "time",
                "bank_b",
                "shadow_probs",
            ),
        },
        {"action_mode": "set", "sensor": {"outlier_prob": 0.1, "detection_prob": 0.8}},
        {"divergence_error": 60.0},
    ],
)
def test_vector_env_equals_scalar_envs_across_autoreset(extra) -> None:
    config = {**SHORT, **extra}
    N, steps, seed = 4, 70, 11
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1.5, 1.5, (steps, N, 9)).astype(np.float32)
    venv = TPMAdaptVectorEnv(N, config=config)
    obs, _ = venv.reset(seed=seed)
    vec_obs, autoreset, masks = [obs], np.zeros(N, bool), []
    for t in range(steps):
        obs, reward, term, trunc, info = venv.step(actions[t])
        assert np.all(reward[autoreset] == 0.0) and not np.any((term | trunc)[autoreset])
        masks.append(info["_position_error"].copy())
        np.testing.assert_array_equal(info["_position_error"], ~autoreset)
        autoreset = term | trunc
        vec_obs.append(obs)
    assert any((~m).any() for m in masks)  # autoresets happened
    for i in range(N):
        scalar = _rollout_scalar(config, seed + i, actions[:, i])
        np.testing.assert_array_equal(np.array(vec_obs)[:, i], np.array(scalar))


def test_sb3_adapter_same_step_reset_and_ppo() -> None:
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    venv = TPMAdaptVecEnv(num_envs=3, config=SHORT)
    venv.seed(4)
    obs = venv.reset()
    gym_venv = TPMAdaptVectorEnv(3, config=SHORT)
    g_obs, _ = gym_venv.reset(seed=4)
    np.testing.assert_array_equal(obs, g_obs)
    for _t in range(20):
        obs2, rewards, dones, infos = venv.step(np.zeros((3, 9), dtype=np.float32))
        assert obs2.dtype == np.float32 and rewards.dtype == np.float32 and obs2 is not obs
        assert dones.shape == (3,) and len(infos) == 3
        obs = obs2
    assert dones.all()  # horizon 20
    for info in infos:
        assert info["TimeLimit.truncated"] is True
        assert info["terminal_observation"].shape == obs.shape[1:]
    # the observation after a done is a reset observation: mu(t) = mu(t-1) = uniform
    np.testing.assert_allclose(obs[:, :6], 1 / 3, rtol=1e-6)
    model = PPO(
        "MlpPolicy",
        TPMAdaptVecEnv(num_envs=4, config=SHORT),
        n_steps=64,
        batch_size=64,
        n_epochs=1,
        seed=0,
        device="cpu",
    )
    model.learn(512)
    assert model.num_timesteps >= 512


def test_divergence_terminates_with_flag_and_finite_outputs() -> None:
    env = gym.make("imm_gym/TPMAdaptPaper-v0", divergence_error=1.0)
    env.reset(seed=0)
    obs, reward, term, trunc, info = env.step(np.zeros(9, np.float32))
    assert term and not trunc and info["diverged"]
    assert np.isfinite(reward) and np.all(np.isfinite(obs))


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"bogus": 1}, "bogus"),
        ({"p_min": 0.4}, "p_min"),
        ({"reward_scale": -1.0}, "reward_scale"),
        ({"max_factor": 1.0}, "max_factor"),
        ({"action_mode": "foo"}, "action_mode"),
        ({"obs_features": ("bank_b",)}, "bank_b"),
        ({"shadow": "none"}, "advantage"),
        ({"sensor": {"sigma_rr": 1.0}}, "sigma_rr"),
        ({"sensor": {"sigma_r": -5.0}}, "sonar.sigma_r"),
        ({"family": {"n_segments": (3, 30)}}, "family.n_segments"),
    ],
)
def test_bad_config_names_the_field(kwargs, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        gym.make("imm_gym/TPMAdapt-v0", **kwargs)


def test_config_as_object_dict_or_kwargs() -> None:
    a = EnvConfig.build(EnvConfig(parallel=True, obs_features=("tpm",)))
    b = EnvConfig.build({"parallel": True, "obs_features": ["tpm"]})
    c = EnvConfig.build(None, parallel=True, obs_features=("tpm",))
    assert a == b == c


@pytest.mark.parametrize("bad", [np.full(9, np.nan), np.array([np.inf] + [0.0] * 8), np.zeros(8)])
def test_bad_actions_raise(bad) -> None:
    env = gym.make("imm_gym/TPMAdapt-v0")
    env.reset(seed=0)
    with pytest.raises(ActionError):
        env.step(bad)


def test_out_of_range_actions_are_clipped() -> None:
    runs = []
    for value in (1.0, 5.0):
        env = gym.make("imm_gym/TPMAdapt-v0")
        env.reset(seed=2)
        runs.append(env.step(np.full(9, value, np.float32))[0])
    np.testing.assert_array_equal(*runs)


FUZZ_CONFIGS = [
    {},
    {"action_mode": "set", "p_min": 0.0, "obs_features": ("tpm", "loglik", "nis", "innovation")},
    {"parallel": True, "p_min": 0.3, "obs_features": ("bank_b", "time")},
    {"sensor": {"outlier_prob": 0.2, "outlier_scale": 100.0, "detection_prob": 0.5}},
    {"divergence_error": 30.0, "action_mode": "set"},
]


@pytest.mark.parametrize("config", FUZZ_CONFIGS)
def test_fuzz_no_nan_or_inf(config) -> None:
    """5 configs x 128 envs x 160 steps = 102,400 env steps with random/extreme/boundary actions."""
    N = 128
    venv = TPMAdaptVectorEnv(N, config=config)
    obs, _ = venv.reset(seed=123)
    rng = np.random.default_rng(7)
    specials = np.array([1e6, -1e6, 1.0, -1.0, 0.0, 1e-300, -1e-300, 0.999999, -0.999999])
    for _ in range(160):
        a = rng.uniform(-1, 1, (N, 9))
        pick = rng.random((N, 9)) < 0.3
        a[pick] = rng.choice(specials, pick.sum())
        obs, reward, _term, _trunc, info = venv.step(a.astype(np.float32))
        assert venv.observation_space.contains(obs)
        assert np.all(np.isfinite(reward))
        for key, value in info.items():
            if isinstance(value, np.ndarray) and value.dtype.kind == "f":
                assert np.all(np.isfinite(value)), key


def test_outliers_at_10_sigma_do_not_diverge_on_the_paper_scenario() -> None:
    env = gym.make("imm_gym/TPMAdaptPaper-v0", sensor={"outlier_prob": 0.05, "outlier_scale": 10})
    errors = []
    for seed in range(20):
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, term, trunc, info = env.step(np.zeros(9, np.float32))
            assert not info["diverged"]
            errors.append(info["position_error"])
            done = term or trunc
    # without outliers the classical IMM's mean error is ~16 m; 5 % outliers of 500 m range
    # noise roughly double it, far from the 5 km divergence bound
    assert np.mean(errors) < 40.0
