"""Classical IMM: a fixed TPM (the zero ``scale`` action); the best fixed TPM found by search."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .base import Baseline

#: Stay probabilities searched for the best fixed TPM: from 1/M (uniform) to 0.999.
STAY_GRID = (1 / 3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 0.999)


class FixedTPM(Baseline):
    """Classical IMM with ``stay`` on the diagonal of the TPM at every step.

    The environment starts from this TPM (``initial_stay``) and the policy's zero ``scale``
    action keeps it.
    """

    name = "fixed"

    def __init__(self, n_models: int = 3, stay: float | None = None) -> None:
        super().__init__(n_models)
        self.stay = stay
        self.env_overrides = {"action_mode": "scale"}
        if stay is not None:
            off = (1.0 - stay) / (n_models - 1)
            self.env_overrides.update({"initial_stay": stay, "p_min": min(1e-3, stay, off)})

    def act(
        self, obs: NDArray[np.float64], state: Any, episode_start: NDArray[np.bool_]
    ) -> tuple[NDArray[np.float64], Any]:
        return np.zeros((obs.shape[0], self.n_models**2)), state


def best_fixed_stay(
    score: Any, grid: Sequence[float] = STAY_GRID
) -> tuple[float, dict[float, float]]:
    """The stay probability with the lowest score (``score(stay) -> ARMSE`` on training runs)."""
    results = {float(p): float(score(p)) for p in grid}
    best = min(results, key=results.__getitem__)
    return best, results
