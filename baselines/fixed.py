"""Classical IMM: a fixed TPM (the zero ``scale`` action)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.tpm import stay_tpm

from .base import Baseline
from .registry import register


@register("fixed", help="classical IMM, the fixed TPM")
class FixedTPM(Baseline):
    """Classical IMM with ``stay`` on the diagonal of the TPM at every step: one stay for
    every model or one per model (:func:`imm_gym.tracking.tpm.stay_tpm`).

    The environment starts from this TPM (``initial_stay``; without ``stay``, the configured
    initial TPM, sojourn-based if configured) and the policy's zero ``scale`` action keeps it:
    ``p_min`` is set at or below its smallest entry (0 without ``stay``).
    """

    def __init__(
        self, n_models: int = 3, stay: float | Sequence[float] | None = None
    ) -> None:
        super().__init__(n_models)
        if stay is not None:
            stay_tpm(n_models, stay)  # refuses a stay outside [0, 1], or not one per model
        # one stay (a numpy scalar too) or one per model, as plain floats
        self.stay = (
            None if stay is None else float(stay) if np.ndim(stay) == 0 else tuple(map(float, stay))
        )
        # without a stay, no floor: the configured TPM is kept whatever the base's p_min
        self.env_overrides = {"action_mode": "scale", "p_min": 0.0}
        if stay is not None:
            stays = np.broadcast_to(np.asarray(stay, dtype=np.float64), (n_models,))
            smallest = float(min(stays.min(), ((1.0 - stays) / (n_models - 1)).min()))
            self.env_overrides.update(
                {"initial_stay": self.stay, "sojourn": None, "p_min": min(1e-3, smallest)}
            )

    def act(
        self, obs: NDArray[np.float64], state: Any, episode_start: NDArray[np.bool_]
    ) -> tuple[NDArray[np.float64], Any]:
        return np.zeros((obs.shape[0], self.n_models**2)), state
