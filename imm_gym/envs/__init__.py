"""Gymnasium fronts over :class:`imm_gym.sim.core.TrackingCore` and their registration."""

from __future__ import annotations

import gymnasium as gym

from imm_gym.envs.tpm_adapt import TPMAdaptEnv
from imm_gym.envs.vector import TPMAdaptVectorEnv
from imm_gym.sim.presets import ENV_PRESETS

#: Registered ids and their configuration (:data:`imm_gym.sim.presets.ENV_PRESETS`).
PRESETS = ENV_PRESETS


def register_envs() -> None:
    """Register every id of :data:`PRESETS` (idempotent)."""
    for env_id, preset in PRESETS.items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point="imm_gym.envs.tpm_adapt:TPMAdaptEnv",
            vector_entry_point="imm_gym.envs.vector:TPMAdaptVectorEnv",
            kwargs={"preset": preset},
            disable_env_checker=False,
        )


__all__ = ["PRESETS", "TPMAdaptEnv", "TPMAdaptVectorEnv", "register_envs"]
