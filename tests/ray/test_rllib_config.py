"""``agents.rllib.ppo_config``: each setting of the hyperparameter entry lands in RLlib's PPO
configuration (README, "Scaling out"). Builds the configuration only: no Ray is started."""

from __future__ import annotations

import pytest

# ray.rllib, not ray: with tests/ on the path this very directory imports as a namespace "ray"
pytest.importorskip("ray.rllib")

pytestmark = pytest.mark.ray

ENV_ID = "imm_gym/TPMAdapt-v0"
#: every setting a value of its own (none the entry's or RLlib's default), so that a setting
#: read from another key, or left at a default, is seen
ENTRY = {
    "n_envs": 8,
    "n_steps": 16,
    "batch_size": 96,
    "n_epochs": 3,
    "gamma": 0.97,
    "gae_lambda": 0.91,
    "learning_rate": "lin_0.001",
    "n_timesteps": 5000,
    "clip_range": 0.15,
    "ent_coef": 0.01,
    "vf_coef": 0.4,
    "max_grad_norm": 0.7,
    "frame_stack": 3,
    "policy_kwargs": {"net_arch": {"pi": [32, 16], "vf": [32, 16]}, "activation_fn": "relu"},
}


def test_every_setting_of_the_entry_reaches_rllibs_ppo() -> None:
    from agents import rllib
    from agents.training import load_hyperparams

    params, _ = load_hyperparams(ENV_ID)
    config = rllib.ppo_config({**params, **ENTRY}, ENV_ID, 3, 2, "ledger")
    got = {
        "gamma": config.gamma,
        "lambda": config.lambda_,
        "minibatch": config.minibatch_size,
        "epochs": config.num_epochs,
        "clip": config.clip_param,
        "entropy": config.entropy_coeff,
        "vf": config.vf_loss_coeff,
        "grad_clip": config.grad_clip,
        "lr": config.lr,
        "fragment": config.rollout_fragment_length,
        "sub_envs": config.num_envs_per_env_runner,
        "runners": config.num_env_runners,
        "samples": config.train_batch_size_per_learner,
        "lookback": config.episode_lookback_horizon,
        "seed": config.seed,
        "hidden": config.model_config["fcnet_hiddens"],
        "activation": config.model_config["fcnet_activation"],
    }
    assert got == {
        "gamma": 0.97,
        "lambda": 0.91,
        "minibatch": 96,
        "epochs": 3,
        "clip": 0.15,
        "entropy": 0.01,
        "vf": 0.4,
        "grad_clip": 0.7,
        # lin_0.001: 0.001 at step 0, down to 0 at the budget's 5000 steps
        "lr": [[0, 0.001], [5000, 0.0]],
        "fragment": 16,
        "sub_envs": 8,
        "runners": 2,
        "samples": 16 * 8 * 2,  # n_steps x n_envs from each of the two runners
        "lookback": 3,  # the frames stacked
        "seed": 3,
        "hidden": [32, 16],
        "activation": "relu",
    }
    assert config.env_config["seed_ledger"] == "ledger"
    assert config.env_config["env_id"] == ENV_ID


def test_a_constant_learning_rate_is_passed_as_is() -> None:
    from agents import rllib
    from agents.training import load_hyperparams

    params, _ = load_hyperparams(ENV_ID)
    config = rllib.ppo_config({**params, **ENTRY, "learning_rate": 2.5e-4}, ENV_ID, 0, 0, "l")
    assert config.lr == 2.5e-4
    assert config.train_batch_size_per_learner == 16 * 8  # the driver samples
