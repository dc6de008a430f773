"""The TIP-IMM transition-probability rule (seed 000 §3.2, eqs. 13-17; SPEC §4 and §6).

The rule is written as a matrix of multiplicative factors on the current TPM, which is exactly
what a ``scale`` action of the environment applies (then rows are normalized, eq. 17, and floored).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imm_gym.validation import ConfigError, check_range

Array = NDArray[np.float64]

READINGS = ("literal", "intent")


def tip_factors(
    mu_now: Array,
    mu_prev: Array,
    alpha: float = 1.1,
    beta: float = 0.9,
    reading: str = "literal",
) -> Array:
    """Factors ``f_ij`` of the TIP-IMM update ``pi_ij <- f_ij pi_ij``, batched over N.

    With ``i = argmax mu(t)`` (ties: the first model) and ``Delta = mu(t) - mu(t-1)``:

    * if ``argmax mu(t-1) != i``: no change (all factors 1);
    * ``f_ii = alpha`` if ``Delta_i >= 0`` else ``beta``;
    * for ``j != i`` either eq. (15): ``f_ij = alpha, f_ji = beta``, or eq. (16):
      ``f_ij = beta, f_ji = alpha``. If ``Delta_i >= 0``: (15) when ``Delta_j > Delta_i``, else
      (16). If ``Delta_i < 0``: the paper names (15) when ``Delta_j < Delta_i`` ("literal"
      reading, SPEC §6 default) while its sentence describes (16) ("intent" reading); the
      other case gets the other equation.

    Args:
        mu_now, mu_prev: ``(N, M)`` model probabilities at t and t-1.
        alpha: growth factor > 1; beta: shrink factor in (0, 1).
        reading: ``"literal"`` or ``"intent"``.

    Returns:
        ``(N, M, M)`` factors.
    """
    check_range("alpha", alpha, 1.0, lo_open=True)
    check_range("beta", beta, 0.0, 1.0, lo_open=True, hi_open=True)
    if reading not in READINGS:
        raise ConfigError(f"reading must be one of {list(READINGS)}, got {reading!r}")
    mu_now = np.atleast_2d(mu_now)
    mu_prev = np.atleast_2d(mu_prev)
    N, M = mu_now.shape
    rows = np.arange(N)
    main = np.argmax(mu_now, axis=-1)
    same = main == np.argmax(mu_prev, axis=-1)
    delta = mu_now - mu_prev
    d_main = delta[rows, main][:, None]
    if reading == "literal":
        decaying = d_main < 0
        eq15 = np.where(~decaying, delta > d_main, delta < d_main)
    else:
        eq15 = np.where(d_main >= 0, delta > d_main, delta >= d_main)
    factors = np.ones((N, M, M))
    factors[rows, main, :] = np.where(eq15, alpha, beta)
    factors[rows, :, main] = np.where(eq15, beta, alpha)
    factors[rows, main, main] = np.where(d_main[:, 0] >= 0, alpha, beta)
    factors[~same] = 1.0
    return factors
