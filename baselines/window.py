"""Sliding-window TPM estimate (the family of the TIP-IMM paper's reference [18]).

The TPM is re-estimated from the model probabilities of the last ``window`` steps as expected
transition counts, shrunk toward the prior TPM ``pi0``:

    pi_ij ∝ kappa pi0_ij + sum_{t in window} mu_i(t-1) mu_j(t),

then floored by the environment. ``kappa`` (pseudo-counts) keeps the estimate stable while the
window is short. The window lives in the policy ``state`` (reset at ``episode_start``); the
estimate is applied through the ``set`` action.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.tpm import stay_tpm
from imm_gym.validation import check_int, check_range

from .amp_imm import tpm_to_logits
from .base import Baseline
from .registry import register


@register("window", help="the TPM estimated from the model probabilities of a sliding window")
class SlidingWindowTPM(Baseline):
    """Windowed expected-transition-count TPM estimate.

    Args:
        n_models: M.
        window: number of recent transitions counted (an integer >= 1).
        kappa: prior strength in pseudo-counts (per row, > 0).
        prior_stay: diagonal of the prior TPM, in ``[0, 1]``.
        logit_scale: must match the environment's ``logit_scale`` (> 0).

    Raises:
        ConfigError: a parameter outside its range, named with the range.
    """

    def __init__(
        self,
        n_models: int = 3,
        window: int = 10,
        kappa: float = 5.0,
        prior_stay: float = 0.9,
        logit_scale: float = 4.0,
    ) -> None:
        super().__init__(n_models)
        self.window = check_int("window", window, 1)
        self.kappa = check_range("kappa", kappa, 0.0, lo_open=True)
        self.prior = stay_tpm(n_models, check_range("prior_stay", prior_stay, 0.0, 1.0))
        logit_scale = check_range("logit_scale", logit_scale, 0.0, lo_open=True)
        self.logit_scale = logit_scale
        self.env_overrides = {"action_mode": "set", "logit_scale": logit_scale}

    def act(
        self, obs: NDArray[np.float64], state: Any, episode_start: NDArray[np.bool_]
    ) -> tuple[NDArray[np.float64], Any]:
        N, M = obs.shape[0], self.n_models
        mu_now, mu_prev = self.mode_probs(obs)
        counts = np.zeros((N, self.window, M, M)) if state is None else state.copy()
        counts[episode_start] = 0.0
        counts = np.roll(counts, 1, axis=1)
        # an episode's first observation follows no transition (mu(t-1) is mu(t) there)
        seen = mu_prev[:, :, None] * mu_now[:, None, :]
        counts[:, 0] = np.where(episode_start[:, None, None], 0.0, seen)
        tpm = self.kappa * self.prior + counts.sum(axis=1)
        tpm /= tpm.sum(axis=-1, keepdims=True)
        return tpm_to_logits(tpm, self.logit_scale).reshape(N, -1), counts
