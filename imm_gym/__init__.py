"""imm_gym: learn to adapt the transition probability matrix of an IMM tracker.

The numerical core (no Gymnasium import in its modules): motion models, scenarios, sensors,
filters, the batched IMM bank, metrics, the batched simulation. Importing the package registers the
environment ids (``imm_gym/TPMAdapt-v0`` ...) with Gymnasium. See README.md.
"""

# first: numba caches compiled from other sources than the package's are dropped at its import
from imm_gym import kernel_cache  # noqa: F401
from imm_gym.evaluation.clairvoyant import clairvoyant_filter
from imm_gym.scenarios.segments import (
    RandomFamily,
    Scenario,
    Segment,
    Truth,
    generate_truth,
    paper_scenario,
)
from imm_gym.seeding import streams
from imm_gym.sim.actions import ActionError
from imm_gym.sim.conditions import Variation
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import Batch, draw_batch
from imm_gym.sim.replay import TrackResult, run_policy
from imm_gym.tracking.filters import (
    ExtendedKalmanFilter,
    KalmanFilter,
    UnscentedKalmanFilter,
    make_filter,
    predict,
)
from imm_gym.tracking.imm import IMM, IMMResult, IMMState, IMMStep, combine, mix, update_mode_probs
from imm_gym.tracking.initiation import initiate
from imm_gym.tracking.models import MotionModel, ct_transition, paper_bank
from imm_gym.tracking.sensors import Measurements, PositionSensor, Sonar
from imm_gym.tracking.tpm import stay_tpm, tpm_from_sojourn, validate_tpm
from imm_gym.validation import ConfigError

__version__ = "0.1.0"


def _register() -> None:
    from imm_gym.envs import register_envs

    register_envs()


_register()

__all__ = [
    "IMM",
    "ActionError",
    "Batch",
    "ConfigError",
    "EnvConfig",
    "ExtendedKalmanFilter",
    "IMMResult",
    "IMMState",
    "IMMStep",
    "KalmanFilter",
    "Measurements",
    "MotionModel",
    "PositionSensor",
    "RandomFamily",
    "Scenario",
    "Segment",
    "Sonar",
    "TrackResult",
    "TrackingCore",
    "Truth",
    "UnscentedKalmanFilter",
    "Variation",
    "__version__",
    "clairvoyant_filter",
    "combine",
    "ct_transition",
    "draw_batch",
    "generate_truth",
    "initiate",
    "make_filter",
    "mix",
    "paper_bank",
    "paper_scenario",
    "predict",
    "run_policy",
    "stay_tpm",
    "streams",
    "tpm_from_sojourn",
    "update_mode_probs",
    "validate_tpm",
]
