"""The scalar environment's step: observation layout, fresh arrays, the zero action as classical
IMM, episode end and divergence, the info contents, and seeding / common random numbers."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from imm_gym import IMM, EnvConfig, Sonar, draw_batch, paper_bank, paper_scenario, stay_tpm
from imm_gym.envs import TPMAdaptEnv, TPMAdaptVectorEnv

PAPER = "imm_gym/TPMAdaptPaper-v0"
SHORT = {
    "scenario": "random",
    "family": {"horizon": 20, "n_segments": (1, 2), "min_duration": 10},
}
SIZES = {
    "tpm": 9,
    "loglik": 3,
    "nis": 3,
    "innovation": 6,
    "bank_b": 3,
    "shadow_probs": 3,
    "time": 1,
    "turn_rate": 1,
    "shadow_turn_rate": 1,
    "turn_rate_ema": 2,
    "prob_ema": 6,
    "shadow_turn_rate_ema": 2,
    "turn_magnitude_ema": 2,
    "speed": 1,
}
LAYOUTS = [
    ((), False),
    (("tpm",), False),
    (("tpm", "loglik", "nis", "time"), False),
    (("time", "nis", "tpm"), False),  # blocks follow the order of obs_features
    (("bank_b",), True),
    (("tpm", "loglik", "nis", "innovation", "bank_b", "shadow_probs", "time"), True),
    (("innovation", "shadow_probs"), False),
    (("turn_rate", "shadow_turn_rate", "tpm"), False),
    (("prob_ema", "turn_rate_ema", "turn_rate"), True),
    (("speed", "shadow_turn_rate", "turn_magnitude_ema", "shadow_turn_rate_ema"), False),
]


def _blocks(obs: np.ndarray, features: tuple[str, ...]) -> dict[str, np.ndarray]:
    out = {"mode_probs": obs[:3], "prev_probs": obs[3:6]}
    i = 6
    for f in features:
        out[f] = obs[i : i + SIZES[f]]
        i += SIZES[f]
    assert i == obs.size
    return out


@pytest.mark.parametrize(("features", "parallel"), LAYOUTS)
def test_observation_layout_dtype_and_bounds(features: tuple[str, ...], parallel: bool) -> None:
    env = TPMAdaptEnv(scenario="paper", obs_features=features, parallel=parallel)
    space = env.observation_space
    assert space.dtype == np.float32
    assert space.shape == (6 + sum(SIZES[f] for f in features),)
    blocks_low = _blocks(space.low, features)
    blocks_high = _blocks(space.high, features)
    bounds = {
        "loglik": (-1.0, 0.0),
        "innovation": (-1.0, 1.0),
        "turn_rate": (-1.0, 1.0),
        "shadow_turn_rate": (-1.0, 1.0),
        "turn_rate_ema": (-1.0, 1.0),
        "shadow_turn_rate_ema": (-1.0, 1.0),
    }
    for name, low in blocks_low.items():
        lo, hi = bounds.get(name, (0.0, 1.0))
        assert np.all(low == lo) and np.all(blocks_high[name] == hi), name

    obs, info = env.reset(seed=4)
    assert obs.dtype == np.float32 and obs.shape == space.shape and space.contains(obs)
    b = _blocks(obs, features)
    np.testing.assert_array_equal(b["mode_probs"], np.float32(1 / 3))
    np.testing.assert_array_equal(b["prev_probs"], np.float32(1 / 3))
    if "tpm" in features:
        np.testing.assert_array_equal(b["tpm"], stay_tpm(3, 0.995).ravel().astype(np.float32))
        np.testing.assert_array_equal(info["tpm"], stay_tpm(3, 0.995))
    for name in ("loglik", "nis", "innovation", "time", "turn_rate", "shadow_turn_rate"):
        if name in features:
            np.testing.assert_array_equal(b[name], 0.0)
    if "turn_rate_ema" in features:
        np.testing.assert_array_equal(b["turn_rate_ema"], 0.0)
    if "prob_ema" in features:
        np.testing.assert_array_equal(b["prob_ema"], np.float32(1 / 3))
    for name in ("turn_magnitude_ema", "shadow_turn_rate_ema"):
        if name in features:
            np.testing.assert_array_equal(b[name], 0.0)
    if "speed" in features:  # the track starts at the scenario's speed, 25 m/s
        np.testing.assert_allclose(b["speed"], 25.0 / 30.0, rtol=1e-6)
    lam = np.array([0.7, 0.9])
    rate_ema, prob_ema = np.zeros(2), np.full((2, 3), 1 / 3)
    lam_magnitude, magnitude_ema = np.array([0.9, 0.97]), np.zeros(2)
    shadow_rate_ema = np.zeros(2)

    rng = np.random.default_rng(0)
    prev = np.full(3, 1 / 3)
    v_prev = np.array([20.0, 15.0])  # the paper scenario's initial velocity starts the track
    for k in range(1, 41):
        obs, _, terminated, truncated, info = env.step(rng.uniform(-1, 1, 9))
        assert obs.dtype == np.float32 and space.contains(obs) and np.all(np.isfinite(obs))
        assert not terminated and not truncated
        b = _blocks(obs, features)
        np.testing.assert_array_equal(b["mode_probs"], info["mode_probs"].astype(np.float32))
        np.testing.assert_array_equal(b["prev_probs"], prev.astype(np.float32))
        prev = info["mode_probs"]
        if "tpm" in features:
            np.testing.assert_array_equal(b["tpm"], info["tpm"].ravel().astype(np.float32))
        if "loglik" in features:
            rel = info["loglik"] - info["loglik"].max()
            expected = np.clip(rel, -20.0, 0.0) / 20.0
            np.testing.assert_allclose(b["loglik"], expected, rtol=1e-6, atol=1e-7)
            assert b["loglik"].max() == 0.0  # the best model
        if "nis" in features:
            nis = info["model_nis"]
            np.testing.assert_allclose(b["nis"], nis / (nis + 2.0), rtol=1e-6, atol=1e-7)
        if "time" in features:
            assert b["time"][0] == np.float32(k / 150)
        for name in ("bank_b", "shadow_probs"):
            if name in features:
                assert abs(float(b[name].sum(dtype=np.float64)) - 1.0) < 1e-5
                assert np.all(b[name] >= 0.0)
        if "innovation" in features:
            assert np.all(np.abs(b["innovation"]) <= 1.0) and np.any(b["innovation"] != 0.0)
        if "turn_rate" in features:
            v = info["estimate"][2:4]
            rate = np.arctan2(v_prev[0] * v[1] - v_prev[1] * v[0], v_prev @ v)
            expected = np.clip(rate / np.deg2rad(10.0), -1.0, 1.0)
            np.testing.assert_allclose(b["turn_rate"], expected, rtol=1e-5, atol=1e-7)
            rate_ema = lam * rate_ema + (1 - lam) * rate / np.deg2rad(10.0)
            if "turn_rate_ema" in features:
                np.testing.assert_allclose(
                    b["turn_rate_ema"], np.clip(rate_ema, -1, 1), rtol=1e-5, atol=1e-7
                )
        if "prob_ema" in features:
            prob_ema = lam[:, None] * prob_ema + (1 - lam[:, None]) * info["mode_probs"]
            np.testing.assert_allclose(b["prob_ema"], prob_ema.ravel(), rtol=1e-5, atol=1e-7)
        if "turn_magnitude_ema" in features:  # of the clipped |shadow_turn_rate|
            magnitude = abs(float(b["shadow_turn_rate"][0]))
            magnitude_ema = lam_magnitude * magnitude_ema + (1 - lam_magnitude) * magnitude
            np.testing.assert_allclose(b["turn_magnitude_ema"], magnitude_ema, rtol=1e-5, atol=1e-7)
        if "shadow_turn_rate_ema" in features:  # of the clipped shadow_turn_rate
            shadow_rate = float(b["shadow_turn_rate"][0])
            shadow_rate_ema = lam * shadow_rate_ema + (1 - lam) * shadow_rate
            np.testing.assert_allclose(
                b["shadow_turn_rate_ema"], shadow_rate_ema, rtol=1e-5, atol=1e-7
            )
        if "speed" in features:
            speed = np.hypot(*info["estimate"][2:4]) / 30.0
            np.testing.assert_allclose(b["speed"], min(speed, 1.0), rtol=1e-6, atol=1e-7)
        v_prev = info["estimate"][2:4]


def _twin_envs(**config):
    envs = [TPMAdaptEnv(**config) for _ in range(2)]
    for env in envs:
        env.reset(seed=21)
    return envs


def test_reset_and_step_observations_are_fresh_arrays() -> None:
    a, b = (TPMAdaptEnv(scenario="paper", obs_features=("tpm", "time")) for _ in range(2))
    obs_a, info_a = a.reset(seed=1)
    b.reset(seed=1)
    obs_a[:] = 0.5
    info_a["tpm"][:] = 0.25
    info_a["true_state"][:] = 0.0
    action = np.full(9, 0.3)
    results_a, results_b = [], []
    for _ in range(3):
        ra, rb = a.step(action), b.step(action)
        assert not np.shares_memory(ra[0], obs_a)
        ra[0][:] = -7.0  # mutate the returned observation
        results_a.append(ra)
        results_b.append(rb)
    for ra, rb in zip(results_a, results_b, strict=True):
        assert ra[1:4] == rb[1:4]
        np.testing.assert_array_equal(ra[4]["estimate"], rb[4]["estimate"])
    np.testing.assert_array_equal(a.unwrapped.core.observe(), b.unwrapped.core.observe())
    obs1, _ = a.reset(seed=5)
    obs2, _ = a.reset(seed=5)
    assert obs1 is not obs2 and not np.shares_memory(obs1, obs2)


INFO_ARRAYS = [
    "true_state",
    "estimate",
    "covariance",
    "mode_probs",
    "loglik",
    "model_nis",
    "tpm",
]


@pytest.mark.parametrize(
    "key",
    INFO_ARRAYS,
)
def test_mutating_a_step_info_array_does_not_change_the_env(key: str) -> None:
    a, b = _twin_envs(scenario="paper", obs_features=("tpm", "loglik", "nis"))
    action = np.linspace(-1, 1, 9)
    _, _, _, _, info_a = a.step(action)
    b.step(action)
    info_a[key][...] = 0.2  # a caller scribbling on an info array in place
    for _ in range(2):
        oa, ra, *_, ia = a.step(action)
        ob, rb, *_, ib = b.step(action)
        np.testing.assert_array_equal(oa, ob)
        assert ra == rb
        np.testing.assert_array_equal(ia["mode_probs"], ib["mode_probs"])
        np.testing.assert_array_equal(ia["tpm"], ib["tpm"])


def classical_imm(runs: int, seed: int, stay: float = 0.995):
    """The paper scenario's runs seeded ``seed + r`` and a classical IMM run on them."""
    batch = draw_batch(paper_scenario(), Sonar(), runs, seed)
    ref = IMM(paper_bank(), Sonar()).run(
        batch.measurements.z[:, 1:],
        stay_tpm(3, stay),
        batch.x0,
        batch.P0,
        detected=batch.measurements.detected[:, 1:],
    )
    return batch, ref


@pytest.mark.parametrize("seed", [0, 7])
def test_zero_action_reproduces_classical_imm_exactly(seed: int) -> None:
    env = gym.make(PAPER)
    env.reset(seed=seed)
    _, ref = classical_imm(1, seed)
    for k in range(150):
        _, reward, terminated, truncated, info = env.step(np.zeros(9, np.float32))
        assert np.array_equal(info["estimate"], ref.x[0, k]), k
        assert np.array_equal(info["covariance"], ref.P[0, k]), k
        assert np.array_equal(info["mode_probs"], ref.mode_probs[0, k]), k
        assert np.array_equal(info["loglik"], ref.loglik[0, k]), k
        assert np.array_equal(info["model_nis"], ref.model_nis[0, k]), k
        assert info["nis"] == ref.nis[0, k]
        assert np.array_equal(info["tpm"], stay_tpm(3, 0.995))  # the zero action keeps the TPM
        assert info["shadow_position_error"] == info["position_error"]
        assert reward == 0.0 and info["reward_advantage"] == 0.0
        assert not terminated and truncated == (k == 149)


def test_zero_action_in_the_vector_env_is_classical_imm_for_every_sub_env() -> None:
    N, seed = 3, 30
    venv = TPMAdaptVectorEnv(N, config={"scenario": "paper"})
    venv.reset(seed=seed)
    _, ref = classical_imm(N, seed)
    for k in range(150):
        _, reward, *_, info = venv.step(np.zeros((N, 9), np.float32))
        np.testing.assert_array_equal(info["estimate"], ref.x[:, k])
        np.testing.assert_array_equal(info["mode_probs"], ref.mode_probs[:, k])
        np.testing.assert_array_equal(reward, 0.0)


ZERO_ACTION_STAYS = [
    0.995,
    0.9,
    0.6,
    0.409,  # rows sum to 1 - 1 ulp: still passes unchanged
]


@pytest.mark.parametrize("stay", ZERO_ACTION_STAYS)
def test_zero_action_keeps_the_initial_tpm_bitwise_and_advantage_is_zero(stay: float) -> None:
    env = TPMAdaptEnv(scenario="paper", initial_stay=stay)
    env.reset(seed=2)
    for _ in range(30):
        _, reward, *_, info = env.step(np.zeros(9))
        assert np.array_equal(info["tpm"], stay_tpm(3, stay))
        assert reward == 0.0


def test_shadow_is_a_classical_imm_with_shadow_stay() -> None:
    seed, scale = 12, 7.0
    env = TPMAdaptEnv(scenario="paper", shadow_stay=0.6, reward_scale=scale)
    env.reset(seed=seed)
    batch, ref = classical_imm(1, seed, stay=0.6)
    ref_error = np.linalg.norm(ref.x[0, :, :2] - batch.truth.states[0, 1:, :2], axis=-1)
    rng = np.random.default_rng(1)
    nonzero = 0
    for k in range(150):
        _, reward, *_, info = env.step(rng.uniform(-1, 1, 9))  # the action must not matter
        np.testing.assert_allclose(info["shadow_position_error"], ref_error[k], rtol=1e-12)
        e = np.linalg.norm(info["estimate"][:2] - info["true_state"][:2])
        np.testing.assert_allclose(info["position_error"], e, rtol=1e-12)
        np.testing.assert_allclose(reward, (ref_error[k] - e) / scale, rtol=1e-9, atol=1e-12)
        assert reward == info["reward_advantage"]
        np.testing.assert_allclose(info["reward_error"], -e / scale, rtol=1e-12)
        np.testing.assert_allclose(
            info["reward_squared_advantage"], (ref_error[k] ** 2 - e**2) / scale**2, rtol=1e-9
        )
        nonzero += reward != 0.0
    assert nonzero > 100


@pytest.mark.parametrize("reward", ["error", "advantage", "squared_advantage"])
def test_reward_is_the_configured_term(reward: str) -> None:
    env = TPMAdaptEnv(scenario="random", reward=reward)
    env.reset(seed=3)
    rng = np.random.default_rng(3)
    for _ in range(20):
        _, r, *_, info = env.step(rng.uniform(-1, 1, 9))
        assert isinstance(r, float)
        assert r == info[f"reward_{reward}"]
        assert info["reward_error"] == -info["position_error"] / 10.0


def test_the_least_reward_scale_gives_finite_rewards() -> None:
    # 1e-6 m, the least reward_scale (a smaller one whose square underflowed gave NaN rewards)
    for env in (TPMAdaptEnv(reward="squared_advantage", reward_scale=1e-6),
                TPMAdaptVectorEnv(2, reward="squared_advantage", reward_scale=1e-6)):
        env.reset(seed=0)
        rng = np.random.default_rng(0)
        for k in range(4):  # the shadow's TPM (e = e_shadow), then others
            *_, info = env.step(rng.uniform(-1, 1, env.action_space.shape) * (k > 0))
            for key in ("reward_error", "reward_advantage", "reward_squared_advantage"):
                assert np.isfinite(info[key]).all(), key
        assert (np.asarray(info["reward_squared_advantage"]) != 0.0).all()


def test_paper_env_truncates_after_exactly_150_steps() -> None:
    env = gym.make(PAPER)
    env.reset(seed=0)
    for k in range(1, 151):
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        assert terminated is False
        assert truncated is (k == 150)
        assert info["step"] == k and not info["diverged"]
    with pytest.raises(RuntimeError, match="reset"):
        env.unwrapped.step(np.zeros(9, np.float32))
    env.reset()
    _, _, terminated, truncated, info = env.step(np.zeros(9, np.float32))
    assert info["step"] == 1 and not terminated and not truncated


def _all_finite(info: dict) -> None:
    for key, value in info.items():
        arr = np.asarray(value)
        if arr.dtype.kind == "f":
            assert np.all(np.isfinite(arr)), key


@pytest.mark.parametrize(
    "overrides",
    [
        {"divergence_error": 1.0},
        {"divergence_cov": 1.0},
        {"divergence_error": 1.0, "parallel": True},
    ],
)
def test_divergence_terminates_with_flag_and_finite_outputs(overrides: dict) -> None:
    env = gym.make(PAPER, obs_features=("tpm", "loglik", "nis", "time"), **overrides)
    env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(np.zeros(9, np.float32))
    assert terminated is True and truncated is False
    assert bool(info["diverged"]) is True
    assert np.all(np.isfinite(obs)) and env.observation_space.contains(obs)
    assert np.isfinite(reward)
    _all_finite(info)
    if "divergence_error" in overrides:  # the error is capped at the divergence bound
        assert info["position_error"] == 1.0 and info["reward_error"] == -1.0 / 10.0
    with pytest.raises(RuntimeError):
        env.unwrapped.step(np.zeros(9, np.float32))
    env.reset(seed=0)  # a reset starts afresh


def test_no_divergence_flag_in_a_normal_episode() -> None:
    env = TPMAdaptEnv(scenario="paper")
    env.reset(seed=1)
    for _ in range(150):
        *_, terminated, _, info = env.step(np.zeros(9))
        assert not terminated and info["diverged"] is not True and not info["diverged"]


def test_info_carries_ground_truth_and_diagnostics() -> None:
    seed = 9
    env = TPMAdaptEnv(scenario="paper")
    _, reset_info = env.reset(seed=seed)
    batch = draw_batch(paper_scenario(), Sonar(), 1, seed)
    np.testing.assert_array_equal(reset_info["true_state"], batch.truth.states[0, 0])
    np.testing.assert_array_equal(env.core.z[0], batch.measurements.z[0])
    expected_model = [0] * 40 + [2] * 30 + [0] * 20 + [1] * 25 + [0] * 35  # SPEC §3 and §6
    rng = np.random.default_rng(0)
    keys = {
        "true_state",
        "true_model",
        "estimate",
        "covariance",
        "position_error",
        "shadow_position_error",
        "mode_probs",
        "loglik",
        "model_nis",
        "nis",
        "detected",
        "tpm",
        "step",
        "diverged",
        "reward_error",
        "reward_advantage",
        "reward_squared_advantage",
    }
    for k in range(1, 151):
        _, reward, _, _, info = env.step(rng.uniform(-1, 1, 9))
        assert keys <= set(info)
        np.testing.assert_array_equal(info["true_state"], batch.truth.states[0, k])
        assert info["true_model"] == expected_model[k - 1]
        assert info["step"] == k and bool(info["detected"])
        assert info["estimate"].shape == (4,) and info["covariance"].shape == (4, 4)
        assert info["mode_probs"].shape == info["loglik"].shape == info["model_nis"].shape == (3,)
        assert info["tpm"].shape == (3, 3)
        np.testing.assert_allclose(info["tpm"].sum(axis=1), 1.0, atol=1e-12)
        np.testing.assert_allclose(info["mode_probs"].sum(), 1.0, atol=1e-12)
        assert np.all(info["model_nis"] >= 0.0) and info["nis"] >= 0.0
        assert np.all(np.linalg.eigvalsh(info["covariance"]) > 0.0)
        assert reward == info["reward_advantage"]


def _episode(env: TPMAdaptEnv, seed: int | None, actions: np.ndarray) -> list:
    obs, info = env.reset(seed=seed)
    out = [(obs, info["true_state"])]
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        out.append(
            (obs, reward, terminated, truncated, info["true_state"], info["estimate"], info["tpm"])
        )
        if terminated or truncated:
            break
    return out


def _same(x: list, y: list) -> bool:
    if len(x) != len(y):
        return False
    for a, b in zip(x, y, strict=True):
        for u, v in zip(a, b, strict=True):
            if not np.array_equal(u, v):
                return False
    return True


def test_same_seed_same_episode_different_seed_different_episode() -> None:
    actions = np.random.default_rng(0).uniform(-1, 1, (20, 9))
    config = {**SHORT, "obs_features": ("tpm", "loglik", "nis", "innovation", "time")}
    a, b = TPMAdaptEnv(**config), TPMAdaptEnv(**config)
    ep_a, ep_b = _episode(a, 17, actions), _episode(b, 17, actions)
    assert len(ep_a) == 21 and _same(ep_a, ep_b)
    ep_c = _episode(TPMAdaptEnv(**config), 18, actions)
    assert not np.array_equal(ep_a[0][1], ep_c[0][1])  # another target
    assert not _same(ep_a, ep_c)


def test_reset_without_seed_continues_the_stream_deterministically() -> None:
    actions = np.random.default_rng(1).uniform(-1, 1, (20, 9))
    a, b = TPMAdaptEnv(**SHORT), TPMAdaptEnv(**SHORT)
    first_a, first_b = _episode(a, 5, actions), _episode(b, 5, actions)
    second_a, second_b = _episode(a, None, actions), _episode(b, None, actions)
    assert _same(first_a, first_b) and _same(second_a, second_b)
    assert not np.array_equal(first_a[0][1], second_a[0][1])  # a new scenario
    third = _episode(a, 5, actions)  # reseeding restarts the sequence
    assert _same(third, first_a)


def test_unseeded_envs_differ() -> None:
    a, b = TPMAdaptEnv(**SHORT), TPMAdaptEnv(**SHORT)
    _, ia = a.reset()
    _, ib = b.reset()
    assert not np.array_equal(ia["true_state"], ib["true_state"])


def test_common_random_numbers_across_policies() -> None:
    """Two envs with different actions, reset with the same seed, see the same targets and the
    same measurements, episode after episode, even when one of them diverges."""
    rng = np.random.default_rng(2)
    diverging = {**SHORT, "divergence_error": 40.0}
    a, b = TPMAdaptEnv(**diverging), TPMAdaptEnv(**diverging)
    for episode in range(3):
        seed = 33 if episode == 0 else None
        a.reset(seed=seed)
        b.reset(seed=seed)
        np.testing.assert_array_equal(a.core.z, b.core.z)
        np.testing.assert_array_equal(a.core.truth, b.core.truth)
        done_a = done_b = False
        truth_a, truth_b = [], []
        while not (done_a and done_b):
            if not done_a:
                *_, ta, tra, info = a.step(np.ones(9))
                truth_a.append(info["true_state"])
                done_a = ta or tra
            if not done_b:
                *_, tb, trb, info = b.step(rng.uniform(-1, 1, 9))
                truth_b.append(info["true_state"])
                done_b = tb or trb
        n = min(len(truth_a), len(truth_b))
        np.testing.assert_array_equal(truth_a[:n], truth_b[:n])


def test_env_reset_draws_the_same_scenario_and_noise_as_draw_batch() -> None:
    config = EnvConfig(sensor=Sonar(outlier_prob=0.1, detection_prob=0.8))
    env = TPMAdaptEnv(config)
    for seed in (0, 41, 2**31 + 5):
        env.reset(seed=seed)
        batch = draw_batch(config.family, config.sensor, 1, seed)
        np.testing.assert_array_equal(env.core.truth[0], batch.truth.states[0])
        np.testing.assert_array_equal(env.core.z[0], batch.measurements.z[0])
        np.testing.assert_array_equal(env.core.detected[0], batch.measurements.detected[0])


@pytest.mark.parametrize("diverge", [False, True])
def test_one_step_scenario_ends_by_truncation_or_by_divergence(diverge: bool) -> None:
    scenario = {"segments": [{"duration": 1}], "position": [3000.0, 0.0], "velocity": [0, 10]}
    env = TPMAdaptEnv(scenario=scenario, divergence_error=1e-3 if diverge else 5000.0)
    obs, _ = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(np.zeros(9))
    # a divergence at the horizon is a termination, not a truncation
    assert (terminated, truncated) == ((True, False) if diverge else (False, True))
    assert bool(info["diverged"]) is diverge
    assert env.observation_space.contains(obs) and np.isfinite(reward)


@pytest.mark.parametrize("omega_deg", [-3.0, -0.5, 0.0, 1.2, 4.0, 80.0])
def test_heading_rate_of_a_rotated_velocity_is_the_turn_rate(omega_deg: float) -> None:
    from imm_gym.sim.features import heading_rate

    omega, T = np.deg2rad(omega_deg), 2.0
    rng = np.random.default_rng(3)
    v = rng.normal(size=(5, 2)) * 10.0
    c, s = np.cos(omega * T), np.sin(omega * T)
    v_next = v @ np.array([[c, s], [-s, c]])  # each row rotated by omega T
    np.testing.assert_allclose(heading_rate(v, v_next, T), omega, atol=1e-12)
    np.testing.assert_array_equal(heading_rate(np.zeros((1, 2)), v[:1], T), 0.0)


def test_an_episode_diverging_at_its_last_step_is_terminated_not_truncated() -> None:
    """Divergence ends an episode as terminated wherever it happens, the horizon's step too (a
    run both terminated and truncated would bootstrap from a lost track)."""
    scenario = {"segments": [{"duration": 1}], "position": [3000.0, 4000.0],
                "velocity": [10.0, 5.0]}
    config = {"scenario": scenario, "divergence_error": 1e-3}
    env = TPMAdaptEnv(config=config)
    venv = TPMAdaptVectorEnv(2, config=config)
    env.reset(seed=0)
    venv.reset(seed=0)
    _, _, terminated, truncated, info = env.step(np.zeros(9, np.float32))
    assert info["diverged"] and terminated and not truncated
    _, _, terminated, truncated, info = venv.step(np.zeros((2, 9), np.float32))
    assert info["diverged"].all() and terminated.all() and not truncated.any()
