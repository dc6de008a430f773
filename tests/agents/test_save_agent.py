"""``agents.training.save_agent``: what it writes is what the loader reads back."""

from __future__ import annotations

import json
from pathlib import Path

from stable_baselines3 import PPO

from agents.policy import load_agent
from agents.training import build_algorithm, make_training_env, save_agent

ENV_ID = "imm_gym/TPMAdapt-v0"


def test_an_agent_without_a_normalizer_saved_over_one_with_it_loads(tmp_path: Path) -> None:
    """Saving into a directory that held a normalized agent removes its ``vecnormalize.json``:
    the record says ``normalize: false`` and the loader refuses the file then."""
    for normalize in (True, False):
        env = make_training_env(ENV_ID, 2, 0, {}, normalize, 1, 0.9)
        model = build_algorithm(PPO, "MlpPolicy", env, 0, n_steps=8, batch_size=16)
        save_agent(tmp_path, model, env, {}, "ppo", 1)
        assert json.loads((tmp_path / "agent.json").read_text())["normalize"] is normalize
        assert (tmp_path / "vecnormalize.json").exists() is normalize
        assert (load_agent(tmp_path).obs_mean is not None) is normalize
