"""Named configurations, each defined once: the registered environment ids
(:data:`ENV_PRESETS`, :mod:`imm_gym.envs`) and the banks of ``python -m imm_gym.evaluate --bank``
(:data:`BANK_PRESETS`) are :class:`~imm_gym.sim.env_config.EnvConfig` overrides."""

from __future__ import annotations

from typing import Any

from imm_gym.tracking.hetero import SONAR_HETERO_BANK

#: Banks by name: the paper's (CV, CT(±4°/s), SVD-UKF; EnvConfig's default) and source 002's
#: heterogeneous NCV [px, py, vx, vy], CT [px, py, v, psi, omega] (turn rate estimated) and
#: CTRA [.., a] IMM-EKF, with state conversions before mixing and combination and noise scaled
#: to the sonar scenarios (SONAR_HETERO_BANK).
BANK_PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "hetero": {"bank": dict(SONAR_HETERO_BANK), "filter": "ekf"},
}

#: Registered ids and their configuration (``config`` keyword of the entry points).
ENV_PRESETS: dict[str, dict[str, Any]] = {
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
    # The randomized family with the heterogeneous bank.
    "imm_gym/TPMAdaptHetero-v0": {"scenario": "random", **BANK_PRESETS["hetero"]},
}
