"""AMP-IMM (seed 003 §3.1): TPM adapted by the ratio of error compression ratios.

Seed 003 lost its equations in extraction; this is the standard construction of that family
(Zhang Rongchun et al.'s AMP-IFIMM generalized to M models), written down here so it can be
checked. The error compression ratio of model j is ``lambda_j = mu_j(k) / cbar_j(k)`` — the
posterior over the predicted model probability, which equals ``Lambda_j / sum_l Lambda_l cbar_l``
— so the ratio of ratios is the likelihood ratio ``d_ij = lambda_j / lambda_i = Lambda_j /
Lambda_i``. The adapted TPM scales the switching probabilities and keeps rows stochastic:

    pi_ij' = d_ij pi_ij  (j != i),     pi_ii' = 1 - sum_{j != i} pi_ij'.

Seed 003's guard (its Step 3): the adapted TPM is accepted only if every diagonal entry exceeds
0.6 (a stay probability below 0.5 would describe a transient, not a motion mode); otherwise the
TPM is kept. Its Step 2 first tests "the necessary conditions for adaptive adjustment", equation
(22), lost in extraction with the others: that precondition is not applied here (the update is
proposed every step and the guard alone decides).
The likelihoods come from the observation feature ``loglik`` (log-likelihoods relative to the best
model, clipped to ``[-loglik_clip, 0]``), the current TPM from the feature ``tpm``; the new TPM is
set through the ``set`` action (row logits ``log pi'``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.validation import check_range

from .base import Baseline
from .registry import register


@register("amp-imm", help="AMP-IMM, seed 003's TPM scaled by likelihood ratios, with a guard")
class AMPIMM(Baseline):
    """Error-compression-ratio adaptive TPM with seed 003's diagonal guard.

    Args:
        n_models: M.
        guard: an adapted TPM is accepted only if every diagonal entry exceeds ``guard`` (seed
            003: 0.6), in ``[0, 1)``: a diagonal entry is at most 1, so a guard of 1 or more
            would refuse every adaptation.
        loglik_clip, logit_scale: must match the environment's (defaults 20 and 4; > 0).

    Raises:
        ConfigError: a parameter outside its range, named with the range.
    """

    def __init__(
        self,
        n_models: int = 3,
        guard: float = 0.6,
        loglik_clip: float = 20.0,
        logit_scale: float = 4.0,
    ) -> None:
        super().__init__(n_models)
        self.guard = check_range("guard", guard, 0.0, 1.0, hi_open=True)
        self.loglik_clip = check_range("loglik_clip", loglik_clip, 0.0, lo_open=True)
        self.logit_scale = check_range("logit_scale", logit_scale, 0.0, lo_open=True)
        self.env_overrides = {
            "action_mode": "set",
            "logit_scale": self.logit_scale,
            "loglik_clip": self.loglik_clip,
            "obs_features": ("tpm", "loglik"),
        }

    def adapt(self, tpm: NDArray[np.float64], loglik: NDArray[np.float64]) -> NDArray[np.float64]:
        """The guarded AMP update of ``(N, M, M)`` TPMs given ``(N, M)`` log-likelihoods."""
        M = self.n_models
        d = np.exp(loglik[:, None, :] - loglik[:, :, None])  # d_ij = Lambda_j / Lambda_i
        off = ~np.eye(M, dtype=bool)
        new = np.where(off, tpm * d, 0.0)
        diag = 1.0 - new.sum(axis=-1)
        new[:, np.arange(M), np.arange(M)] = diag
        accept = (diag > self.guard).all(axis=-1)
        return np.where(accept[:, None, None], new, tpm)

    def act(
        self, obs: NDArray[np.float64], state: Any, episode_start: NDArray[np.bool_]
    ) -> tuple[NDArray[np.float64], Any]:
        M = self.n_models
        tpm = self.feature(obs, "tpm").reshape(-1, M, M)
        loglik = self.feature(obs, "loglik") * self.loglik_clip
        new = self.adapt(tpm, loglik)
        return tpm_to_logits(new, self.logit_scale).reshape(obs.shape[0], -1), state


def tpm_to_logits(tpm: NDArray[np.float64], logit_scale: float) -> NDArray[np.float64]:
    """``set`` actions whose row softmax is ``tpm``: ``a = 1 + (log pi - max_j log pi) /
    logit_scale``.

    Each row is anchored at its largest entry (action 1), so the environment's clipping to
    ``[-1, 1]`` can only raise entries below ``exp(-2 logit_scale)`` times the largest
    (3.4e-4 at the default 4), which its floor ``p_min`` (1e-3) raises anyway: the row the
    environment applies is ``tpm`` floored. (Centring each row on the midpoint of its log range
    instead would clip its largest entry too once the ratio passed ``exp(2 logit_scale)``, and
    move every other entry.)
    """
    logp = np.log(np.maximum(tpm, 1e-300))
    return 1.0 + (logp - logp.max(axis=-1, keepdims=True)) / logit_scale
