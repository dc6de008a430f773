"""The native Gymnasium vector env (lock-step with scalar envs across NEXT_STEP autoresets, info
masks) and the stable-baselines3 VecEnv adapter (same-step reset, seeding, PPO)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from imm_gym import EnvConfig
from imm_gym.envs import TPMAdaptEnv, TPMAdaptVectorEnv
from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv
from imm_gym.sim.actions import ActionError
from imm_gym.sim.env_config import OBS_FEATURES

SHORT = {
    "scenario": "random",
    "family": {"horizon": 20, "n_segments": (1, 2), "min_duration": 10},
}
ALL_FEATURES = OBS_FEATURES
INFO_COMPARED = ("true_state", "estimate", "mode_probs", "tpm", "position_error", "diverged")


def lockstep(config: dict, N: int = 4, steps: int = 70, seed: int = 11, low: float = -1.5):
    """Step a vector env, N scalar envs (seeds seed + i) and Gymnasium's SyncVectorEnv over the
    scalar env with the same random actions and compare everything exactly, infos and their
    masks included; the scalar env is reset without a seed where the vector env autoresets.
    Returns the number of autoresets seen."""
    rng = np.random.default_rng(seed)
    actions = rng.uniform(low, -low, (steps, N, 9)).astype(np.float32)
    venv = TPMAdaptVectorEnv(N, config=config)
    envs = [TPMAdaptEnv(config=config) for _ in range(N)]
    sync = gym.vector.SyncVectorEnv(
        [lambda: TPMAdaptEnv(config=config)] * N, autoreset_mode=AutoresetMode.NEXT_STEP
    )
    obs, info = venv.reset(seed=seed)
    assert_same_info(info, sync.reset(seed=seed)[1])
    for i, env in enumerate(envs):
        o, inf = env.reset(seed=seed + i)
        np.testing.assert_array_equal(obs[i], o)
        assert set(inf) == {"true_state", "tpm"}
        for key in inf:
            assert info[f"_{key}"][i] and np.array_equal(info[key][i], inf[key])
    done = np.zeros(N, dtype=bool)
    autoresets = 0
    for t in range(steps):
        obs, reward, terminated, truncated, info = venv.step(actions[t])
        assert venv.observation_space.contains(obs)
        assert reward.shape == terminated.shape == truncated.shape == (N,)
        assert terminated.dtype == truncated.dtype == np.bool_
        assert_same_info(info, sync.step(actions[t])[4])
        for i, env in enumerate(envs):
            if done[i]:
                o, inf = env.reset()
                r, te, tr = 0.0, False, False
                autoresets += 1
                for key in INFO_COMPARED:  # the new episode's reset info, the step's masked
                    assert info.get(f"_{key}", np.zeros(N, bool))[i] == (key in inf), key
                    if key in inf:
                        assert np.array_equal(info[key][i], inf[key]), (t, i, key)
            else:
                o, r, te, tr, inf = env.step(actions[t, i])
                for key in INFO_COMPARED:
                    assert info[f"_{key}"][i]
                    assert np.array_equal(info[key][i], inf[key]), (t, i, key)
            assert np.array_equal(obs[i], o), (t, i)
            assert reward[i] == r, (t, i, reward[i] - r)
            assert (bool(terminated[i]), bool(truncated[i])) == (te, tr), (t, i)
            done[i] = te or tr
    return autoresets


def assert_same_info(info: dict, expected: dict) -> None:
    """The same keys and masks, and the same entries where a mask is set."""
    assert set(info) == set(expected)
    for key in (k for k in expected if not k.startswith("_")):
        mask = expected[f"_{key}"]
        np.testing.assert_array_equal(info[f"_{key}"], mask, err_msg=key)
        assert info[f"_{key}"].dtype == np.bool_
        np.testing.assert_array_equal(info[key][mask], expected[key][mask], err_msg=key)


LOCKSTEP_CONFIGS = {
    "default": {},
    "parallel_all_features": {"parallel": True, "p_min": 0.05, "obs_features": ALL_FEATURES},
    "diverging": {"divergence_error": 60.0, "obs_features": ("tpm", "time")},
    "set_outliers_missed": {
        "action_mode": "set",
        "sensor": {"outlier_prob": 0.1, "outlier_scale": 20.0, "detection_prob": 0.7},
    },
    "paper_error_reward": {"scenario": "paper", "reward": "error", "shadow": "none"},
}


@pytest.mark.parametrize("name", sorted(LOCKSTEP_CONFIGS))
def test_vector_env_equals_scalar_envs_across_autoreset(name: str) -> None:
    config = {**SHORT, **LOCKSTEP_CONFIGS[name]}
    steps = 160 if config["scenario"] == "paper" else 70
    autoresets = lockstep(config, steps=steps)
    assert autoresets >= 4  # every sub-env went through at least one NEXT_STEP autoreset
    if name == "diverging":
        assert autoresets > 12  # divergences end episodes before the horizon


def test_vector_env_equals_scalar_envs_with_a_binding_floor() -> None:
    lockstep({**SHORT, "p_min": 0.3}, steps=30)


def test_vector_env_metadata_and_reset_seeds() -> None:
    venv = TPMAdaptVectorEnv(3, config=SHORT)
    assert venv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    obs_int, _ = venv.reset(seed=7)
    truth_int = venv.core.truth.copy()
    obs_list, _ = venv.reset(seed=[7, 8, 9])
    np.testing.assert_array_equal(obs_int, obs_list)
    np.testing.assert_array_equal(venv.core.truth, truth_int)
    venv.reset(seed=[9, None, 7])
    np.testing.assert_array_equal(venv.core.truth[0], truth_int[2])
    np.testing.assert_array_equal(venv.core.truth[2], truth_int[0])
    venv.reset(seed=np.array([9, 8, 7]))  # an array of seeds, numpy integers
    np.testing.assert_array_equal(venv.core.truth[2], truth_int[0])
    venv.reset(seed=np.int64(7))
    np.testing.assert_array_equal(venv.core.truth, truth_int)
    with pytest.raises(ValueError, match=r"sequence of 3 seeds.*got a sequence of 2 entries"):
        venv.reset(seed=[1, 2])
    allowed = r"seed must be None, a non-negative integer .* or a sequence of 3 seeds"
    for bad in (1.5, "abc", True, -1, {1: 2, 3: 4, 5: 6}, np.array(7.0)):
        with pytest.raises(ValueError, match=allowed):
            venv.reset(seed=bad)
    for bad in ([1, 2.0, 3], [1, True, 3], [1, -2, 3], (1, "2", 3)):
        with pytest.raises(ValueError, match=r"seed\[1\] must be None or a non-negative integer"):
            venv.reset(seed=bad)
    np.testing.assert_array_equal(venv.core.truth, truth_int)  # the refused resets did nothing
    with pytest.raises(ValueError, match="num_envs"):
        TPMAdaptVectorEnv(0, config=SHORT)


def test_vector_reset_mask_resets_only_the_masked_sub_envs() -> None:
    """Gymnasium's ``reset(options={"reset_mask": mask})``: the masked sub-envs start the
    episodes their seeds give, the others go on as if no reset had been asked."""
    N, steps = 4, 6
    actions = np.random.default_rng(1).uniform(-1, 1, (2 * steps, N, 9))
    masked, plain = TPMAdaptVectorEnv(N, config=SHORT), TPMAdaptVectorEnv(N, config=SHORT)
    masked.reset(seed=5)
    plain.reset(seed=5)
    for t in range(steps):
        masked.step(actions[t])
        plain.step(actions[t])
    mask = np.array([False, True, False, True])
    obs, info = masked.reset(seed=[None, 40, None, 41], options={"reset_mask": mask})
    fresh, fresh_info = TPMAdaptVectorEnv(N, config=SHORT).reset(seed=[0, 40, 0, 41])
    np.testing.assert_array_equal(obs[mask], fresh[mask])
    assert set(info) == {"true_state", "_true_state", "tpm", "_tpm"}
    for key in ("true_state", "tpm"):  # the reset sub-envs' reset info only
        np.testing.assert_array_equal(info[f"_{key}"], mask)
        np.testing.assert_array_equal(info[key][mask], fresh_info[key][mask])
        assert not info[key][~mask].any()  # zeros, as SyncVectorEnv leaves them
    for t in range(steps, 2 * steps):
        obs, *_ = masked.step(actions[t])
        expected, *_ = plain.step(actions[t])
        np.testing.assert_array_equal(obs[~mask], expected[~mask])
    for bad, error in [
        ([True] * N, TypeError),
        (np.ones(N, dtype=int), TypeError),
        (np.ones(N + 1, dtype=bool), ValueError),
        (np.zeros(N, dtype=bool), ValueError),
    ]:
        with pytest.raises(error, match="reset_mask"):
            masked.reset(options={"reset_mask": bad})


def test_vector_info_masks_are_false_for_autoreset_sub_envs() -> None:
    # except for the reset info (true_state, tpm): an autoreset sub-env gives its new episode's
    N = 5
    venv = TPMAdaptVectorEnv(N, config={**SHORT, "divergence_error": 50.0})
    venv.reset(seed=3)
    rng = np.random.default_rng(0)
    pending = np.zeros(N, dtype=bool)
    seen_partial = False
    for _ in range(60):
        obs, reward, terminated, truncated, info = venv.step(rng.uniform(-1, 1, (N, 9)))
        data_keys = [k for k in info if not k.startswith("_")]
        assert {"estimate", "mode_probs", "tpm", "true_state", "diverged"} <= set(data_keys)
        for key in data_keys:
            mask = info[f"_{key}"]
            assert mask.dtype == np.bool_ and mask.shape == (N,)
            reset_key = key in ("true_state", "tpm")
            np.testing.assert_array_equal(mask, np.ones(N, bool) if reset_key else ~pending)
            assert len(info[key]) == N
        np.testing.assert_array_equal(info["true_state"][pending], venv.core.truth[pending, 0])
        np.testing.assert_array_equal(info["tpm"][pending], venv.core.fixed_tpms[pending])
        assert not np.any(reward[pending]) and not np.any((terminated | truncated)[pending])
        # an autoreset sub-env returns its first observation: uniform probabilities
        np.testing.assert_allclose(obs[pending, :6], 1 / 3, rtol=1e-6)
        seen_partial |= bool(pending.any() and not pending.all())
        pending = terminated | truncated
    assert seen_partial


def test_an_autoreset_sub_env_s_action_is_checked_not_applied() -> None:
    # sub-env 0 autoresets at the step, sub-env 1 steps: any finite row 0 gives the same step;
    # a NaN there is refused and nothing steps or resets
    config = {**SHORT, "divergence_error": 1.0}  # every episode ends at its first step

    def ready() -> TPMAdaptVectorEnv:
        venv = TPMAdaptVectorEnv(2, config=config)
        venv.reset(seed=0)
        venv.step(np.zeros((2, 9)))
        venv.reset(seed=[None, 5], options={"reset_mask": np.array([False, True])})
        return venv

    def step(venv: TPMAdaptVectorEnv, row: np.ndarray) -> tuple:
        return venv.step(np.stack([row, np.full(9, 0.3)]))

    reference = step(ready(), np.zeros(9))
    assert not reference[4]["_step"][0] and reference[4]["_step"][1]
    for row in (np.full(9, 1e6), np.random.default_rng(0).uniform(-1, 1, 9)):
        got = step(ready(), row)
        for a, b in zip(got[:4], reference[:4], strict=True):
            np.testing.assert_array_equal(a, b)
        assert_same_info(got[4], reference[4])
    venv = ready()
    k = venv.core.k.copy()
    with pytest.raises(ActionError, match="finite"):
        step(venv, np.full(9, np.nan))
    np.testing.assert_array_equal(venv.core.k, k)
    got = step(venv, np.zeros(9))  # the autoreset still due, as if no step had been refused
    for a, b in zip(got[:4], reference[:4], strict=True):
        np.testing.assert_array_equal(a, b)
    assert_same_info(got[4], reference[4])


def test_vector_env_returns_fresh_arrays() -> None:
    venv = TPMAdaptVectorEnv(2, config={"scenario": "paper"})
    obs0, _ = venv.reset(seed=0)
    a = np.zeros((2, 9))
    out1 = venv.step(a)
    out2 = venv.step(a)
    for x, y in zip(out1[:4], out2[:4], strict=True):
        assert not np.shares_memory(x, y)
    assert not np.shares_memory(out1[0], obs0)
    out2[0][:] = 0.0
    out2[1][:] = 99.0
    twin = TPMAdaptVectorEnv(2, config={"scenario": "paper"})
    twin.reset(seed=0)
    twin.step(a)
    twin.step(a)
    n1, n2 = venv.step(a), twin.step(a)
    np.testing.assert_array_equal(n1[0], n2[0])
    np.testing.assert_array_equal(n1[1], n2[1])


def test_terminated_is_not_the_info_s_diverged() -> None:
    # a wrapper that rewrites terminations must not rewrite info["diverged"]
    venv = TPMAdaptVectorEnv(2, divergence_error=30.0)
    venv.reset(seed=0)
    _, _, terminated, _, info = venv.step(np.ones((2, 9)))
    assert terminated.all() and info["diverged"].all()
    assert not np.shares_memory(terminated, info["diverged"])
    terminated[:] = False
    assert info["diverged"].all()


def test_an_episode_diverging_at_its_last_step_is_terminated_not_truncated() -> None:
    # one-step episodes: no first estimate is within 1 m of the truth, so every sub-env diverges
    # at the horizon and is terminated only; under the default bound each is truncated there
    one_step = {"scenario": {"segments": [{"duration": 1}]}}
    venv = TPMAdaptVectorEnv(2, config={**one_step, "divergence_error": 1.0})
    venv.reset(seed=0)
    _, _, terminated, truncated, info = venv.step(np.zeros((2, 9)))
    assert info["diverged"].all() and (info["step"] == 1).all()
    np.testing.assert_array_equal(terminated, [True, True])
    np.testing.assert_array_equal(truncated, [False, False])
    venv = TPMAdaptVectorEnv(2, config=one_step)
    venv.reset(seed=0)
    _, _, terminated, truncated, info = venv.step(np.zeros((2, 9)))
    assert not info["diverged"].any() and (info["step"] == 1).all()
    np.testing.assert_array_equal(terminated, [False, False])
    np.testing.assert_array_equal(truncated, [True, True])


@pytest.mark.parametrize(
    "key",
    ["mode_probs", "tpm", "step", "loglik", "model_nis"],
)
def test_mutating_vector_info_does_not_change_the_env(key: str) -> None:
    config = {"scenario": "paper", "obs_features": ("tpm", "time")}
    venv, twin = TPMAdaptVectorEnv(2, config=config), TPMAdaptVectorEnv(2, config=config)
    a = np.full((2, 9), 0.4)
    for v in (venv, twin):
        v.reset(seed=1)
    info = venv.step(a)[4]
    twin.step(a)
    info[key][...] = 140 if key == "step" else 0.2
    for _ in range(2):
        o1, r1, te1, tr1, _ = venv.step(a)
        o2, r2, te2, tr2, _ = twin.step(a)
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(te1, te2)
        np.testing.assert_array_equal(tr1, tr2)


# --------------------------------------------------------------------------- SB3 adapter


def test_sb3_vecenv_api_shapes_and_dtypes() -> None:
    N = 4
    venv = TPMAdaptSB3VecEnv(num_envs=N, config={**SHORT, "obs_features": ("tpm", "time")})
    d = 6 + 9 + 1
    assert venv.num_envs == N
    assert venv.observation_space.shape == (d,) and venv.observation_space.dtype == np.float32
    assert venv.action_space.shape == (9,)
    obs = venv.reset()
    assert obs.dtype == np.float32 and obs.shape == (N, d)
    for _ in range(25):
        obs, rewards, dones, infos = venv.step(np.zeros((N, 9), np.float32))
        assert obs.dtype == np.float32 and obs.shape == (N, d)
        assert rewards.dtype == np.float32 and rewards.shape == (N,)
        assert dones.dtype == np.bool_ and dones.shape == (N,)
        assert isinstance(infos, list) and len(infos) == N
        assert all(isinstance(info, dict) for info in infos)
        assert all(venv.observation_space.contains(o) for o in obs)
        for info in infos:
            assert isinstance(info["position_error"], float)
            assert isinstance(info["diverged"], bool)
    assert venv.get_attr("config") == [venv.config] * N
    assert venv.env_is_wrapped(gym.Wrapper) == [False] * N
    venv.close()


def test_sb3_env_method_runs_once_on_the_shared_core() -> None:
    """``env_method`` on N indices is one call (the sub-envs share the core): a reset through it
    gives the episodes one ``reset`` gives, not the N-th episode of each slot's sequence."""
    N = 3
    venv, twin = (TPMAdaptSB3VecEnv(num_envs=N, config=SHORT) for _ in range(2))
    venv.seed(4)
    twin.seed(4)
    twin.reset()
    obs = venv.env_method("reset")
    assert len(obs) == N
    np.testing.assert_array_equal(venv.core.truth, twin.core.truth)
    np.testing.assert_array_equal(obs[0], twin.core.observe())
    assert len(venv.env_method("reset", indices=[0, 2])) == 2


def test_sb3_same_step_reset_matches_scalar_envs() -> None:
    """SB3 sub-env i plays the episodes of a scalar env seeded s + i; a finished episode is
    reset within the same step, its last observation in ``terminal_observation``."""
    N, seed, steps = 4, 5, 70
    config = {**SHORT, "divergence_error": 60.0, "obs_features": ("tpm", "loglik")}
    venv = TPMAdaptSB3VecEnv(num_envs=N, config=config)
    venv.seed(seed)
    obs = venv.reset()
    envs = [TPMAdaptEnv(config=config) for _ in range(N)]
    for i, env in enumerate(envs):
        np.testing.assert_array_equal(obs[i], env.reset(seed=seed + i)[0])
    rng = np.random.default_rng(seed)
    truncations = divergences = 0
    for _ in range(steps):
        actions = rng.uniform(-1, 1, (N, 9)).astype(np.float32)
        obs, rewards, dones, infos = venv.step(actions)
        for i, env in enumerate(envs):
            o, r, te, tr, info = env.step(actions[i])
            assert rewards[i] == np.float32(r)
            assert dones[i] == (te or tr)
            assert infos[i]["diverged"] == bool(info["diverged"])
            assert infos[i]["position_error"] == info["position_error"]
            if te or tr:
                np.testing.assert_array_equal(infos[i]["terminal_observation"], o)
                assert infos[i]["TimeLimit.truncated"] is (tr and not te)
                truncations += tr
                divergences += te
                o, _ = env.reset()
            else:
                assert "terminal_observation" not in infos[i]
                assert "TimeLimit.truncated" not in infos[i]
            np.testing.assert_array_equal(obs[i], o)
    assert truncations >= 2 and divergences >= 2


def test_sb3_horizon_end_and_divergence_flags() -> None:
    venv = TPMAdaptSB3VecEnv(num_envs=3, config=SHORT)
    venv.seed(4)
    obs = venv.reset()
    last = obs
    for t in range(20):
        obs, _, dones, infos = venv.step(np.zeros((3, 9), np.float32))
        assert dones.all() == (t == 19) and dones.any() == (t == 19)
        if t < 19:
            last = obs
    for info in infos:
        assert info["TimeLimit.truncated"] is True and info["diverged"] is False
        assert info["terminal_observation"].shape == obs.shape[1:]
        assert not np.array_equal(info["terminal_observation"], last[0])
    np.testing.assert_allclose(obs[:, :6], 1 / 3, rtol=1e-6)  # reset observations
    diverging = TPMAdaptSB3VecEnv(num_envs=2, config={**SHORT, "divergence_error": 1.0})
    diverging.seed(4)  # unseeded, a first estimate within 1 m of the truth ended no episode
    diverging.reset()
    obs, rewards, dones, infos = diverging.step(np.zeros((2, 9), np.float32))
    assert dones.all() and np.all(np.isfinite(obs)) and np.all(np.isfinite(rewards))
    for info in infos:
        assert info["TimeLimit.truncated"] is False and info["diverged"] is True
        assert np.all(np.isfinite(info["terminal_observation"]))


def test_sb3_returns_fresh_arrays() -> None:
    venv = TPMAdaptSB3VecEnv(num_envs=2, config=SHORT)
    venv.seed(0)
    first = venv.reset()
    outs = []
    for _ in range(21):  # crosses the horizon: a same-step reset happens at step 20
        outs.append(venv.step(np.zeros((2, 9), np.float32)))
    arrays = [first] + [o[0] for o in outs] + [o[1] for o in outs] + [o[2] for o in outs]
    for i, x in enumerate(arrays):
        for y in arrays[i + 1 :]:
            assert not np.shares_memory(x, y)
    term = outs[19][3][0]["terminal_observation"]
    assert not np.shares_memory(term, outs[19][0])
    # scribbling on a returned observation does not change the env
    twin = TPMAdaptSB3VecEnv(num_envs=2, config=SHORT)
    twin.seed(0)
    twin.reset()
    for _ in range(21):
        twin.step(np.zeros((2, 9), np.float32))
    for o in outs:
        o[0][:] = -1.0
    np.testing.assert_array_equal(
        venv.step(np.ones((2, 9), np.float32))[0], twin.step(np.ones((2, 9), np.float32))[0]
    )


def test_sb3_seed_then_reset_reproduces_the_gymnasium_vector_reset() -> None:
    config = {**SHORT, "parallel": True, "obs_features": ("bank_b", "tpm")}
    sb3 = TPMAdaptSB3VecEnv(num_envs=3, config=config)
    seeds = sb3.seed(42)
    assert list(seeds) == [42, 43, 44]
    obs = sb3.reset()
    gvenv = TPMAdaptVectorEnv(3, config=config)
    g_obs, _ = gvenv.reset(seed=42)
    np.testing.assert_array_equal(obs, g_obs)
    np.testing.assert_array_equal(sb3.core.truth, gvenv.core.truth)
    np.testing.assert_array_equal(sb3.core.z, gvenv.core.z)
    a = np.random.default_rng(0).uniform(-1, 1, (3, 9)).astype(np.float32)
    np.testing.assert_array_equal(sb3.step(a)[0], gvenv.step(a)[0])
    # a reset without seed continues the streams; reseeding replays
    sb3.reset()
    assert not np.array_equal(sb3.core.truth, gvenv.core.truth)
    sb3.seed(42)
    sb3.reset()
    np.testing.assert_array_equal(sb3.core.truth, gvenv.core.truth)


def test_sb3_env_id_gives_the_preset() -> None:
    venv = TPMAdaptSB3VecEnv(num_envs=2, env_id="imm_gym/TPMAdaptParallel-v0")
    assert venv.config == EnvConfig.build(gym.spec("imm_gym/TPMAdaptParallel-v0").kwargs["preset"])
    venv = TPMAdaptSB3VecEnv(num_envs=2, env_id="imm_gym/TPMAdaptPaper-v0", parallel=True)
    assert venv.config.scenario == "paper" and venv.config.parallel


def test_sb3_env_id_preset_is_the_base_of_a_given_config() -> None:
    venv = TPMAdaptSB3VecEnv(num_envs=2, env_id="imm_gym/TPMAdaptPaper-v0", config={"p_min": 0.01})
    assert venv.config.scenario == "paper" and venv.config.p_min == 0.01


def test_ppo_learns_on_the_sb3_adapter_without_error() -> None:
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    venv = TPMAdaptSB3VecEnv(num_envs=4, config={**SHORT, "obs_features": ("tpm", "time")})
    model = PPO(
        "MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1, seed=0, device="cpu", verbose=0
    )
    model.learn(512)
    assert model.num_timesteps >= 512
    action, _ = model.predict(venv.reset(), deterministic=True)
    assert action.shape == (4, 9) and np.all(np.isfinite(action))
