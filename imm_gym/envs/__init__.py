"""Gymnasium fronts over :class:`imm_gym.sim.core.TrackingCore` and their registration."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from imm_gym.envs.tpm_adapt import TPMAdaptEnv
from imm_gym.envs.vector import TPMAdaptVectorEnv
from imm_gym.tracking.hetero import SONAR_HETERO_BANK

#: Registered ids and their presets (``config`` keyword of the entry points).
PRESETS: dict[str, dict[str, Any]] = {
    # The randomized family (SPEC §6): the training environment.
    "imm_gym/TPMAdapt-v0": {"scenario": "random"},
    # The paper's Table-1 scenario (SPEC §3).
    "imm_gym/TPMAdaptPaper-v0": {"scenario": "paper"},
    # The randomized family with the parallel bank B and entropy fusion (TIP-IMM §3.3), the
    # TIP-IMM floor p_min = 0.05 and the fused probabilities of both banks in the observation.
    "imm_gym/TPMAdaptParallel-v0": {
        "scenario": "random",
        "parallel": True,
        "p_min": 0.05,
        "obs_features": ("bank_b",),
    },
    # The randomized family with seed 002's heterogeneous bank: NCV [px, py, vx, vy], CT
    # [px, py, v, psi, omega] (turn rate estimated), CTRA [.., a], IMM-EKF with state conversions
    # before mixing and combination; noise scaled to the sonar scenarios (SONAR_HETERO_BANK).
    "imm_gym/TPMAdaptHetero-v0": {
        "scenario": "random",
        "bank": dict(SONAR_HETERO_BANK),
        "filter": "ekf",
    },
}


def register_envs() -> None:
    """Register every id of :data:`PRESETS` (idempotent)."""
    for env_id, preset in PRESETS.items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point="imm_gym.envs.tpm_adapt:TPMAdaptEnv",
            vector_entry_point="imm_gym.envs.vector:TPMAdaptVectorEnv",
            kwargs={"config": preset},
            disable_env_checker=False,
        )


__all__ = ["PRESETS", "TPMAdaptEnv", "TPMAdaptVectorEnv", "register_envs"]
