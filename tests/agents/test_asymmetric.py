"""Asymmetric actor-critic: the critic's ground-truth block is what it says, the actor never
reads it, and a run trained with it is an agent the evaluation scores."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from gymnasium import spaces
from hypothesis import given, settings
from hypothesis import strategies as st

import train
from agents.asymmetric import AsymmetricActorCriticPolicy, actor_index
from agents.policy import load_agent
from imm_gym.cli.evaluate import main as evaluate_main
from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv
from imm_gym.sim.core import CRITIC_CLIP, critic_state_size

ENV = dict(action_mode="set", shadow_stay=1 / 3)


def test_actor_index_skips_the_critic_entries_of_every_frame() -> None:
    assert actor_index(12, 3, 1) == [0, 1, 2, 4, 5, 6, 8, 9, 10]
    assert actor_index(5, 1, 0) == [0, 1, 2, 3, 4]
    for bad in ((10, 3, 1), (12, 3, 4), (12, 3, -1)):
        with pytest.raises(ValueError, match="frames"):
            actor_index(*bad)


def test_critic_state_is_the_trackers_errors_and_the_coming_model() -> None:
    env = TPMAdaptSB3VecEnv(num_envs=3, env_id="imm_gym/TPMAdapt-v0", critic_state=True, **ENV)
    core = env.core
    n_obs = core.obs_dim
    obs = env.reset()
    assert obs.shape == (3, n_obs + critic_state_size(3)) == (3, env.observation_space.shape[0])
    rng = np.random.default_rng(0)
    scale = np.array([50.0, 50.0, 5.0, 5.0])
    for _ in range(40):
        k = core.k.copy()
        obs, _, dones, infos = env.step(rng.uniform(-1, 1, (3, 9)).astype(np.float32))
        if dones.any():
            break
        block = obs[:, n_obs:]
        np.testing.assert_array_equal(obs[:, :n_obs], core.observe())
        for i in range(3):
            truth = core.truth[i, k[i] + 1]
            error_a = np.clip((core_estimate(core, i) - truth) / scale, -CRITIC_CLIP, CRITIC_CLIP)
            np.testing.assert_allclose(block[i, :4], error_a, rtol=1e-5, atol=1e-6)
            np.testing.assert_allclose(
                np.hypot(*block[i, :2]) * 50.0, infos[i]["position_error"], rtol=1e-5
            )
            np.testing.assert_allclose(
                np.hypot(*block[i, 4:6]) * 50.0, infos[i]["shadow_position_error"], rtol=1e-5
            )
            coming = core.true_model[i, min(k[i] + 1, core.horizon - 1)]
            np.testing.assert_array_equal(block[i, 8:], np.eye(3)[coming])


def test_the_terminal_observation_holds_the_critic_state() -> None:
    # the ended episode's last observation, as the next ones, with the critic's columns: the
    # critic bootstraps a truncated episode's value from it
    env = TPMAdaptSB3VecEnv(num_envs=2, env_id="imm_gym/TPMAdapt-v0", critic_state=True,
                            family={"horizon": 30, "min_duration": 5}, **ENV)
    core = env.core
    env.reset()
    last: list[np.ndarray] = []
    reset = core.reset

    def remember(indices, seeds):  # the observation and critic state before the autoreset
        last.append(np.concatenate([core.observe(), core.critic_state()], axis=1))
        reset(indices, seeds)

    core.reset = remember
    dones = np.zeros(2, dtype=bool)
    while not dones.any():
        _, _, dones, infos = env.step(np.zeros((2, 9), dtype=np.float32))
    assert len(last) == 1
    for i in np.flatnonzero(dones):
        terminal = infos[i]["terminal_observation"]
        assert terminal.shape == env.observation_space.shape
        np.testing.assert_array_equal(terminal, last[0][i])
        assert np.any(terminal[core.obs_dim :] != 0.0)


def core_estimate(core, i: int) -> np.ndarray:
    """Combined estimate of slot ``i``, summed by hand: ``Σ_j μ_j x_j``."""
    return sum(core.mu[i, j] * core.state_a.x[i, j] for j in range(core.M))


def _policy(frame: int, stack: int, critic_dims: int) -> AsymmetricActorCriticPolicy:
    space = spaces.Box(-10.0, 10.0, (frame * stack,), dtype=np.float32)
    return AsymmetricActorCriticPolicy(
        space,
        spaces.Box(-1.0, 1.0, (9,), dtype=np.float32),
        lambda _: 1e-3,
        net_arch=dict(pi=[16, 16], vf=[16]),
        critic_dims=critic_dims,
        frame_stack=stack,
    )


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_the_actor_does_not_read_the_critic_entries(seed: int) -> None:
    torch.manual_seed(seed)
    frame, stack, critic = 7, 3, 2
    policy = _policy(frame, stack, critic)
    rng = np.random.default_rng(seed)
    obs = rng.uniform(-5, 5, (4, frame * stack)).astype(np.float32)
    other = obs.copy()
    for f in range(stack):
        other[:, f * frame + frame - critic : (f + 1) * frame] = rng.uniform(-5, 5, (4, critic))
    with torch.no_grad():
        mean_a = policy.get_distribution(torch.as_tensor(obs)).distribution.mean
        mean_b = policy.get_distribution(torch.as_tensor(other)).distribution.mean
        value_a = policy.predict_values(torch.as_tensor(obs))
        value_b = policy.predict_values(torch.as_tensor(other))
    assert torch.equal(mean_a, mean_b)
    assert not torch.allclose(value_a, value_b)


def test_a_run_with_the_critic_state_gives_an_agent_the_evaluation_scores(tmp_path) -> None:
    cfg = tmp_path / "ac.yml"
    cfg.write_text("n_envs: 8\nn_steps: 32\nbatch_size: 128\nn_epochs: 1\ncritic_state: true\n")
    argv = ["--config", str(cfg), "--out", str(tmp_path), "--no-progress", "--no-eval"]
    steps = ["--timesteps", "512", "--validate-every", "256", "--validation-runs", "2"]
    assert train.main([*argv, *steps]) == 0
    agent_dir = tmp_path / "seed_0" / "agent"
    assert json.loads((agent_dir / "agent.json").read_text())["critic_dims"] == 11
    policy = load_agent(agent_dir)
    assert isinstance(policy.model, AsymmetricActorCriticPolicy) and policy.critic_dims == 11
    result = tmp_path / "res.json"
    runs = ["--scenario", "paper", "--runs", "3", "--quiet", "--no-clairvoyant"]
    code = evaluate_main(["--policy", str(agent_dir), *runs, "--json", str(result)])
    assert code == 0
    assert np.isfinite(json.loads(result.read_text())["policies"][str(agent_dir)]["armse_pos"])


def test_critic_state_with_a_recurrent_agent_is_rejected(tmp_path, capsys) -> None:
    cfg = tmp_path / "ac.yml"
    cfg.write_text("critic_state: true\n")
    argv = ["--algo", "recurrent-ppo", "--config", str(cfg), "--out", str(tmp_path)]
    with pytest.raises(SystemExit) as exit_info:
        train.main([*argv, "--no-eval", "--no-progress"])
    assert exit_info.value.code == 2
    assert "critic_state" in capsys.readouterr().err


def test_the_actor_and_critic_are_the_mlps_worked_by_hand() -> None:
    """In numpy from the network's weights, 2 frames of 4 entries with 1 critic-only entry
    each: the actor's latent is tanh(W2 tanh(W1 x_a + b1) + b2) of x_a = entries 0, 1, 2, 4, 5,
    6, the critic's tanh(V1 x + c1) of all 8, the action mean the action layer of the first,
    the value the value layer of the second."""
    space = spaces.Box(-10.0, 10.0, (8,), dtype=np.float32)
    policy = AsymmetricActorCriticPolicy(
        space, spaces.Box(-1.0, 1.0, (2,), dtype=np.float32), lambda _: 1e-3,
        net_arch=dict(pi=[5, 3], vf=[4]), activation_fn=torch.nn.Tanh, critic_dims=1,
        frame_stack=2,
    )
    torch.manual_seed(1)
    with torch.no_grad():
        for p in policy.parameters():
            p.normal_(0.0, 0.5)
    obs = np.random.default_rng(1).normal(size=(5, 8)).astype(np.float32)
    with torch.no_grad():
        mean = policy.get_distribution(torch.as_tensor(obs)).distribution.mean.numpy()
        value = policy.predict_values(torch.as_tensor(obs)).numpy()
    w = {k: v.detach().numpy().astype(np.float64) for k, v in policy.state_dict().items()}
    x = obs.astype(np.float64)
    a = x[:, [0, 1, 2, 4, 5, 6]]
    for i in (0, 2):
        layer = f"mlp_extractor.policy_net.{i}"
        a = np.tanh(a @ w[f"{layer}.weight"].T + w[f"{layer}.bias"])
    v = np.tanh(x @ w["mlp_extractor.value_net.0.weight"].T + w["mlp_extractor.value_net.0.bias"])
    np.testing.assert_allclose(mean, a @ w["action_net.weight"].T + w["action_net.bias"],
                               rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(value, v @ w["value_net.weight"].T + w["value_net.bias"],
                               rtol=1e-4, atol=1e-5)


def test_the_policy_saved_by_sb3_loads_with_its_frames(tmp_path) -> None:
    """SB3's own save and load (the earlier pickled format that agents/export.py converts)
    rebuild the network with its critic_dims and frame_stack: the actor skips entries 6 and 13
    of the 2 frames of 7 again, and its means are the saved network's."""
    policy = _policy(7, 2, 1)
    policy.save(str(tmp_path / "policy.pt"))
    loaded = AsymmetricActorCriticPolicy.load(str(tmp_path / "policy.pt"), device="cpu")
    assert (loaded.critic_dims, loaded.frame_stack) == (1, 2)
    assert loaded.mlp_extractor.index.tolist() == [0, 1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 12]
    obs = torch.as_tensor(np.random.default_rng(3).normal(size=(2, 14)).astype(np.float32))
    with torch.no_grad():
        assert torch.equal(policy.get_distribution(obs).distribution.mean,
                           loaded.get_distribution(obs).distribution.mean)
