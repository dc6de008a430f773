"""Named configurations, each defined once: the registered environment ids
(:data:`ENV_PRESETS`, :mod:`imm_gym.envs`) and the banks of ``python -m imm_gym.evaluate --bank``
(:data:`BANK_PRESETS`) are :class:`~imm_gym.sim.env_config.EnvConfig` overrides."""

from __future__ import annotations

from typing import Any

from imm_gym.tracking.hetero import SONAR_HETERO_BANK
from imm_gym.tracking.models import MotionModel

#: White-noise acceleration densities (m²/s³) of the physically defined CV and CT(±4°/s) bank:
#: the velocity variance they add in one second, ``q T`` at T = 1 s, is the paper bank's
#: (0.12 m²/s² for CV, half of it for CT), and its position variance ``q T³/3`` (0.04, 0.02 m²
#: against 0.1, 0.05) and the correlation ``q T²/2`` are far below the sonar's noise: at T = 1 s the
#: two banks track alike (fixed TPM, 200 runs: position ARMSE 18.342 m against 18.346 m on the
#: paper scenario, 21.157 m against 21.152 m on the randomized family).
CONTINUOUS_INTENSITY = {"cv": 0.12, "ct": 0.06}

#: CV, CT(+4°/s), CT(-4°/s) with continuous white-noise acceleration
#: (:func:`~imm_gym.tracking.models.white_acceleration_noise`), right at any sampling period.
CONTINUOUS_BANK = (
    MotionModel("cv", noise="continuous", intensity=CONTINUOUS_INTENSITY["cv"]),
    MotionModel("ct", 4.0, noise="continuous", intensity=CONTINUOUS_INTENSITY["ct"]),
    MotionModel("ct", -4.0, noise="continuous", intensity=CONTINUOUS_INTENSITY["ct"]),
)

#: Banks by name: the paper's (CV, CT(±4°/s) with its per-step Q, SVD-UKF; EnvConfig's
#: default), the same models with their noise defined physically (CONTINUOUS_BANK) and source
#: 002's heterogeneous NCV [px, py, vx, vy], CT [px, py, v, psi, omega] (turn rate estimated) and
#: CTRA [.., a] IMM-EKF, with state conversions before mixing and combination and noise scaled
#: to the sonar scenarios (SONAR_HETERO_BANK).
BANK_PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "cv-ct-continuous": {"bank": CONTINUOUS_BANK},
    "hetero": {"bank": dict(SONAR_HETERO_BANK), "filter": "ekf"},
}

#: Registered ids and their configuration (``preset`` keyword of the entry points: the base a
#: ``config`` mapping and keyword arguments update).
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
