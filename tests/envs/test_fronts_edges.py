"""Edges of the env fronts that the lock-step tests do not reach: the scalar env's render modes
(a window only for ``"human"``, drawn at every reset and step, released by ``close``), its
action check off the compiled solo step and its datasheet's observation table; the vector env's
``num_envs`` check, its own generator, an autoreset in a one-step episode and its render
warning; the SB3 adapter's critic bounds, per-step infos, its refusal of a ``step_wait``
without its own ``step_async`` and of ``set_attr``, its images and a mixture's parts over an
id's preset; the registered ids' env checker."""

from __future__ import annotations

import re

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.seeding import np_random
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers import PassiveEnvChecker

import imm_gym.envs.tpm_adapt as tpm_adapt
from imm_gym.envs import PRESETS, TPMAdaptEnv, TPMAdaptVectorEnv
from imm_gym.envs.render import CoreRenderer
from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv
from imm_gym.sim.actions import ActionError
from imm_gym.sim.core import CRITIC_CLIP, critic_state_size
from imm_gym.sim.env_config import OBS_FEATURES

SHORT = {
    "scenario": "random",
    "family": {"horizon": 20, "n_segments": (1, 2), "min_duration": 10},
}


@pytest.fixture
def renderer_calls(monkeypatch) -> list:
    """What the scalar env asks of its renderer: ``("window", bool)`` when it is built, then
    ``"show"`` and ``"close"`` in order (the renderer still draws as it would)."""
    calls: list = []

    class Spy(CoreRenderer):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            calls.append(("window", self.window))

        def show(self, slot: int = 0) -> None:
            calls.append("show")
            super().show(slot)

        def close(self) -> None:
            calls.append("close")
            super().close()

    monkeypatch.setattr(tpm_adapt, "CoreRenderer", Spy)
    return calls


def test_human_mode_draws_a_window_at_every_reset_and_step_and_close_releases_it(
    renderer_calls: list,
) -> None:
    env = TPMAdaptEnv(config=SHORT, render_mode="human")
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.zeros(9, dtype=np.float32))
    assert env.render() is None
    env.reset()
    env.close()
    # one picture per reset (2) and per step (3), into a window, then released
    assert renderer_calls == [("window", True), *["show"] * 5, "close"]


def test_rgb_array_mode_draws_off_screen_only_when_asked_and_close_releases_it(
    renderer_calls: list,
) -> None:
    env = TPMAdaptEnv(config=SHORT, render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.zeros(9, dtype=np.float32))
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3
    env.close()
    assert renderer_calls == [("window", False), "close"]


@pytest.mark.parametrize(
    ("overrides", "render_mode"),
    [({}, None), ({"obs_features": ("tpm",)}, None), ({}, "rgb_array")],
    ids=["solo", "features", "rendered"],
)
def test_the_scalar_env_names_its_own_action_shape_on_every_path(
    overrides: dict, render_mode: str | None
) -> None:
    """A ``(1, 9)`` action (a batch of one) is refused as the scalar env's ``(9,)`` action, also
    where the step is the core's (an observation feature, a render mode) and not the compiled
    solo step's."""
    env = TPMAdaptEnv(config={**SHORT, **overrides}, render_mode=render_mode)
    assert (env._solo is not None) == (overrides == {} and render_mode is None)
    env.reset(seed=0)
    for bad in (np.zeros((1, 9)), np.zeros((3, 3)), np.zeros(3)):
        shape = re.escape(str(bad.shape))
        with pytest.raises(ActionError, match=rf"action must have shape \(9,\), got {shape}"):
            env.step(bad)
    env.step(np.zeros(9))  # the refused actions consumed nothing
    env.close()


def test_the_vector_env_refuses_a_bool_number_of_envs() -> None:
    with pytest.raises(ValueError, match="num_envs must be a positive integer, got True"):
        TPMAdaptVectorEnv(True, config=SHORT)


def test_the_vector_env_seeds_its_own_generator_as_gymnasium_does() -> None:
    """``reset(seed=s)`` seeds ``np_random`` as Gymnasium's ``VectorEnv.reset`` does (its
    ``seeding.np_random(s)``), so the vector env's own draws repeat with the seed."""
    venv = TPMAdaptVectorEnv(2, config=SHORT)
    for seed in (7, 123):
        venv.reset(seed=seed)
        assert venv.np_random_seed == seed
        expected, _ = np_random(seed)
        np.testing.assert_array_equal(venv.np_random.random(5), expected.random(5))


def test_a_one_step_episode_autoresets_with_neither_flag_set() -> None:
    """Episodes of one step: every other step ends them (truncated), and the step between
    restarts them (reward 0, neither flag), as Gymnasium's ``SyncVectorEnv`` of scalar envs."""
    config = {
        "scenario": {"segments": [{"duration": 1}], "position": [3000.0, 0.0], "velocity": [0, 10]}
    }
    venv = TPMAdaptVectorEnv(2, config=config)
    sync = gym.vector.SyncVectorEnv(
        [lambda: TPMAdaptEnv(config=config)] * 2, autoreset_mode=AutoresetMode.NEXT_STEP
    )
    np.testing.assert_array_equal(venv.reset(seed=3)[0], sync.reset(seed=3)[0])
    for t in range(6):
        obs, reward, terminated, truncated, _ = venv.step(np.zeros((2, 9)))
        expected = sync.step(np.zeros((2, 9)))
        ends = t % 2 == 0
        np.testing.assert_array_equal(truncated, [ends, ends])
        np.testing.assert_array_equal(terminated, [False, False])
        if not ends:
            np.testing.assert_array_equal(reward, [0.0, 0.0])
        for got, want in zip((obs, reward, terminated, truncated), expected[:4], strict=True):
            np.testing.assert_array_equal(got, want)


def test_the_critic_entries_are_bounded_on_both_sides_and_hold_what_they_bound() -> None:
    """The critic's ground-truth entries (signed errors, clipped to ``±CRITIC_CLIP``) get the
    bounds ``[-CRITIC_CLIP, CRITIC_CLIP]`` behind the actor's, and every observation of an
    episode lies in the space (the errors go negative)."""
    venv = TPMAdaptSB3VecEnv(num_envs=3, config=SHORT, critic_state=True)
    plain = TPMAdaptSB3VecEnv(num_envs=3, config=SHORT)
    n, extra = plain.observation_space.shape[0], critic_state_size(3)
    space = venv.observation_space
    assert space.shape == (n + extra,)
    np.testing.assert_array_equal(space.low[:n], plain.observation_space.low)
    np.testing.assert_array_equal(space.high[:n], plain.observation_space.high)
    np.testing.assert_array_equal(space.low[n:], np.full(extra, -CRITIC_CLIP, np.float32))
    np.testing.assert_array_equal(space.high[n:], np.full(extra, CRITIC_CLIP, np.float32))
    venv.seed(0)
    obs = [venv.reset()]
    rng = np.random.default_rng(0)
    for _ in range(25):  # past the 20-step horizon: the reset observations too
        obs.append(venv.step(rng.uniform(-1, 1, (3, 9)).astype(np.float32))[0])
    obs = np.concatenate(obs)
    assert (obs[:, n:] < 0).any()
    assert all(space.contains(o) for o in obs)


@pytest.mark.parametrize(
    ("reward", "keys"),
    [
        ("advantage", ()),
        ("bank_advantage", ("stay_bank_position_error", "reward_bank_advantage")),
    ],
)
def test_the_sb3_infos_are_the_vector_env_s_step_infos(reward: str, keys: tuple) -> None:
    """Each sub-env's info holds the errors, the reward terms and the divergence flag, each the
    number the Gymnasium vector env gives for the same seeds and actions (the stay bank's two
    where the reward runs it)."""
    expected_keys = {
        "position_error",
        "shadow_position_error",
        "reward_error",
        "reward_advantage",
        "reward_squared_advantage",
        "diverged",
        *keys,
    }
    config = {**SHORT, "reward": reward}
    sb3 = TPMAdaptSB3VecEnv(num_envs=2, config=config)
    venv = TPMAdaptVectorEnv(2, config=config)
    sb3.seed(5)
    sb3.reset()
    venv.reset(seed=5)
    rng = np.random.default_rng(1)
    for _ in range(5):
        actions = rng.uniform(-1, 1, (2, 9)).astype(np.float32)
        _, _, _, infos = sb3.step(actions)
        _, _, _, _, info = venv.step(actions)
        for i, sub_info in enumerate(infos):
            assert set(sub_info) == expected_keys
            for key in expected_keys:
                assert sub_info[key] == info[key][i], key
    assert any(sub_info["reward_advantage"] != 0.0 for sub_info in infos)


def test_every_sb3_step_wait_needs_its_own_step_async() -> None:
    """``step_wait`` without ``step_async`` is refused, also after a step: the actions given are
    used for one step only, never again."""
    venv = TPMAdaptSB3VecEnv(num_envs=2, config=SHORT)
    venv.reset()
    message = "step_wait called without step_async"
    with pytest.raises(RuntimeError, match=message):
        venv.step_wait()
    venv.step_async(np.zeros((2, 9), dtype=np.float32))
    venv.step_wait()
    with pytest.raises(RuntimeError, match=message):
        venv.step_wait()


@pytest.mark.parametrize("env_id", sorted(PRESETS))
def test_make_wraps_every_registered_id_in_gymnasium_s_passive_checker(env_id: str) -> None:
    """Every id is registered with Gymnasium's env checker on (its default), so ``gym.make``
    checks the spaces and the first reset and step of the env it builds."""
    assert gym.spec(env_id).disable_env_checker is False
    env, wrappers = gym.make(env_id), []
    while isinstance(env, gym.Wrapper):
        wrappers.append(type(env))
        env = env.env
    assert PassiveEnvChecker in wrappers and isinstance(env, TPMAdaptEnv)


def test_the_sb3_adapter_refuses_set_attr_naming_it() -> None:
    """The sub-envs share one core: setting an attribute of "one" of them is refused, naming it,
    and changes nothing."""
    venv = TPMAdaptSB3VecEnv(num_envs=3, config=SHORT)
    with pytest.raises(AttributeError, match="share one core; cannot set 'critic_state'"):
        venv.set_attr("critic_state", True, indices=[1])
    assert venv.get_attr("critic_state") == [False] * 3


def test_the_sb3_adapter_gives_one_absent_image_per_sub_env() -> None:
    """``get_images`` (what SB3's ``VecEnv.render`` tiles) has one entry per sub-env, None: the
    adapter draws nothing."""
    assert TPMAdaptSB3VecEnv(num_envs=3, config=SHORT).get_images() == [None, None, None]


def test_a_mixture_s_parts_build_on_the_env_id_s_preset() -> None:
    """With ``env_id``, each further part's ``env_kwargs`` are fields over that id's preset (the
    parallel id: a parallel bank, ``p_min = 0.05``, the ``bank_b`` feature), as ``config``'s
    are."""
    venv = TPMAdaptSB3VecEnv(
        4,
        env_id="imm_gym/TPMAdaptParallel-v0",
        mixture=[{"env_kwargs": {"sensor": {"outlier_prob": 0.1}}, "share": 0.5}],
    )
    configs = venv.get_attr("config")
    assert [c.sensor.outlier_prob for c in configs] == [0.0, 0.0, 0.1, 0.1]
    for c in configs:
        assert (c.parallel, c.p_min, c.obs_features) == (True, 0.05, ("bank_b",))


def test_the_scalar_env_s_datasheet_lists_every_observation_entry() -> None:
    """``help(TPMAdaptEnv)`` shows the observation table (index, meaning, min, max): a row per
    optional feature and the two rows of model probabilities, bounded as the space is."""
    doc = TPMAdaptEnv.__doc__
    assert "{observation_table}" not in doc
    rows = [line.strip() for line in doc.splitlines() if line.strip().startswith("| ")]
    for feature in OBS_FEATURES:
        assert any(row.startswith(f"| ``{feature}`` |") for row in rows), feature
    space = TPMAdaptEnv(config=SHORT).observation_space
    assert (space.shape, float(space.low.min()), float(space.high.max())) == ((6,), 0.0, 1.0)
    probability_rows = [row for row in rows if "model probabilities" in row]
    assert len(probability_rows) >= 2
    assert all(row.endswith("| 0 | 1 |") for row in probability_rows[:2])


def test_the_vector_env_warns_when_rendered_without_a_render_mode() -> None:
    venv = TPMAdaptVectorEnv(2, config=SHORT)
    venv.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode='rgb_array'"):
        assert venv.render() is None
