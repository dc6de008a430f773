"""What one step of all banks returns for N slots, from either engine
(:mod:`imm_gym.sim.engines`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


class BankStep(NamedTuple):
    """One step of bank A, bank B (``parallel``) and the shadow IMM (``shadow="fixed"``).

    The compiled engine builds it inside :func:`imm_gym.sim.kernels.env_step`, the numpy engine
    from the trackers' ``step``; fresh arrays either way. The arrays of a bank that did not run
    are its inputs as they were (and ``velocity_s`` and ``shadow_position_error`` zeros without
    the shadow).
    """

    tpm: Array  # (N, M, M) the TPM bank A mixed with (from the action)
    x_a: Array  # (N, M, n) bank A's model-conditioned posterior
    P_a: Array  # (N, M, n, n)
    mode_probs: Array  # (N, M) mu(t): bank A's, or the fused U when parallel (both banks' next)
    x_b: Array  # (N, M, n) bank B's posterior
    P_b: Array  # (N, M, n, n)
    mu_b: Array  # (N, M) bank B's probabilities before the fusion
    x_s: Array  # (N, M, n) the shadow IMM's posterior
    P_s: Array  # (N, M, n, n)
    mu_s: Array  # (N, M)
    estimate: Array  # (N, n) combined estimate
    covariance: Array  # (N, n, n)
    cbar: Array  # (N, M) bank A's predicted model probabilities
    loglik: Array  # (N, M) bank A's per-model log-likelihoods
    model_nis: Array  # (N, M)
    innovation: Array  # (N, M, m) whitened innovations
    cbar_s: Array  # (N, M) the shadow's predicted model probabilities (zeros without it)
    loglik_s: Array  # (N, M) the shadow's per-model log-likelihoods (zeros without it)
    nis: Array  # (N,) NIS of bank A's predicted measurement mixture
    velocity: Array  # (N, 2) velocity of the combined estimate
    velocity_s: Array  # (N, 2) velocity of the shadow's estimate
    position_error: Array  # (N,) |p_hat - p| capped at divergence_error (NaN -> the cap)
    shadow_position_error: Array  # (N,) the same for the shadow's estimate
    diverged: NDArray[np.bool_]  # (N,) a failed bank, the error or P_xx + P_yy above its cap
