"""``agents.rllib.export_agent`` of a policy trained without an observation normalizer
(``normalize: false``): an agent the project's loader takes, with RLlib's weights. The algorithm
is a stand-in holding the weights (no Ray is started)."""

from __future__ import annotations

import json
import types
from pathlib import Path

import numpy as np
import pytest

# ray.rllib, not ray: with tests/ on the path this very directory imports as a namespace "ray"
pytest.importorskip("ray.rllib")

pytestmark = pytest.mark.ray

ENV_ID = "imm_gym/TPMAdapt-v0"
HIDDEN = [32, 16]


def _weights(obs_size: int, actions: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """RLlib's default PPO module weights (its parameter names), drawn at random."""
    shapes = {}
    for encoder in ("actor", "critic"):
        for j, (n_in, n_out) in zip((0, 2), [(obs_size, HIDDEN[0]), HIDDEN], strict=True):
            shapes[f"encoder.{encoder}_encoder.net.mlp.{j}.weight"] = (n_out, n_in)
            shapes[f"encoder.{encoder}_encoder.net.mlp.{j}.bias"] = (n_out,)
    shapes |= {
        "pi.net.mlp.0.weight": (actions, HIDDEN[1]),
        "pi.net.mlp.0.bias": (actions,),
        "pi.log_std": (actions,),
        "vf.net.mlp.0.weight": (1, HIDDEN[1]),
        "vf.net.mlp.0.bias": (1,),
    }
    return {k: rng.normal(size=s).astype(np.float32) for k, s in shapes.items()}


#: RLlib's names to SB3's MlpPolicy's (agents.rllib.sb3_state's docstring)
SB3_NAMES = {
    "encoder.actor_encoder.net.mlp.": "mlp_extractor.policy_net.",
    "encoder.critic_encoder.net.mlp.": "mlp_extractor.value_net.",
    "pi.net.mlp.0.": "action_net.",
    "vf.net.mlp.0.": "value_net.",
    "pi.log_std": "log_std",
}


def test_an_agent_trained_without_a_normalizer_exports_as_one_the_loader_takes(tmp_path: Path):
    """``agent.json`` records no normalizer and no ``vecnormalize.json`` is written (one left by
    an earlier export is removed): the loader takes the agent (it requires that file exactly
    where ``normalize`` is true) and its network holds RLlib's weights."""
    from agents import rllib
    from agents.policy import load_agent
    from agents.training import load_hyperparams
    from imm_gym.envs import PRESETS
    from imm_gym.sim.actions import action_size
    from imm_gym.sim.env_config import EnvConfig
    from imm_gym.sim.features import observation_size

    params, _ = load_hyperparams(ENV_ID)
    params = {
        **params,
        "normalize": False,
        "frame_stack": 1,
        "policy_kwargs": {"net_arch": {"pi": HIDDEN, "vf": HIDDEN}},
    }
    config = EnvConfig.build({**PRESETS[ENV_ID], **params["env_kwargs"]})
    M = len(config.bank)
    obs_size = observation_size(config.obs_features, M, config.sensor.dim_z)
    weights = _weights(obs_size, action_size(config.action_mode, M), np.random.default_rng(5))
    runner = types.SimpleNamespace(_env_to_module=types.SimpleNamespace(connectors=[]))
    algo = types.SimpleNamespace(
        learner_group=types.SimpleNamespace(get_weights=lambda: {"default_policy": weights}),
        env_runner_group=types.SimpleNamespace(local_env_runner=runner),
    )
    directory = tmp_path / "agent"
    directory.mkdir()
    (directory / "vecnormalize.json").write_text("{}")  # an earlier export's
    rllib.export_agent(algo, directory, params, ENV_ID, {"seed": 0})
    assert json.loads((directory / "agent.json").read_text())["normalize"] is False
    assert not (directory / "vecnormalize.json").exists()
    policy = load_agent(directory)
    assert policy.obs_mean is None and policy.obs_size == obs_size
    state = {k: v.detach().numpy() for k, v in policy.model.state_dict().items()}
    for name, value in weights.items():
        old = next(o for o in SB3_NAMES if name.startswith(o))
        np.testing.assert_array_equal(state[SB3_NAMES[old] + name[len(old) :]], value, name)
