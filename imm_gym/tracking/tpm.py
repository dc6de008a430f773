"""The transition probability matrix (TPM): convention, construction and validation.

Convention, used everywhere in imm_gym::

    tpm[..., i, j] = P(model j at step k | model i at step k-1),   each row sums to 1.

(FilterPy's docstring states it the other way round; its code uses this one.)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.special import rel_entr

from imm_gym.validation import ConfigError, check_int, check_range

Array = NDArray[np.float64]

ROW_SUM_TOL = 1e-8


def stay_tpm(n_models: int, stay: float) -> Array:
    """TPM with ``stay`` on the diagonal and ``(1 - stay) / (M - 1)`` elsewhere.

    ``stay = 0.995`` with M = 3 is the paper-preset fixed TPM (SPEC §6); ``stay = 1/M`` is the
    uniform TPM.
    """
    n_models = check_int("n_models", n_models, 1)
    stay = check_range("stay", stay, 0.0, 1.0)
    if n_models == 1:
        return np.ones((1, 1))
    tpm = np.full((n_models, n_models), (1.0 - stay) / (n_models - 1))
    np.fill_diagonal(tpm, stay)
    return tpm


def validate_tpm(tpm: Array, n_models: int, name: str = "tpm") -> Array:
    """Return ``tpm`` as a float array after checking shape ``(..., M, M)`` and stochasticity.

    Raises:
        ConfigError: naming ``name`` if the shape is wrong, an entry is negative or non-finite, or
            a row does not sum to 1 (tolerance 1e-8).
    """
    a = np.asarray(tpm, dtype=np.float64)
    if a.ndim < 2 or a.shape[-2:] != (n_models, n_models):
        raise ConfigError(f"{name} must have shape (..., {n_models}, {n_models}), got {a.shape}")
    lowest = a.min()
    if not np.isfinite(a.sum()):
        raise ConfigError(f"{name} must be finite")
    if lowest < 0.0:
        raise ConfigError(f"{name} entries must be >= 0, got minimum {lowest:.6g}")
    worst = float(np.abs(a.sum(axis=-1) - 1.0).max())
    if worst > ROW_SUM_TOL:
        raise ConfigError(
            f"{name} rows must sum to 1 (±{ROW_SUM_TOL}); worst row is off by {worst:.3g}"
        )
    return a


def apply_floor(tpm: Array, p_min: float) -> Array:
    """Row-normalize and keep every entry in ``[p_min, 1 - p_min]`` so the IMM can always switch.

    Entries below ``p_min`` are raised to it and the other entries of the row shrink
    proportionally to pay for it, repeated until no entry is below (at most M passes). A row that
    already satisfies the floor is only normalized, so a valid TPM passes unchanged. With
    ``p_min < 1/M`` the largest entry is at most ``1 - (M-1) p_min <= 1 - p_min``.

    Args:
        tpm: ``(..., M, M)`` non-negative, finite, with positive row sums.
        p_min: floor in ``[0, 1/M)``.
    """
    M = tpm.shape[-1]
    if not 0.0 <= p_min < 1.0 / M:
        raise ConfigError(f"p_min must be in [0, 1/M) = [0, {1.0 / M:.6g}), got {p_min!r}")
    row_sum = tpm.sum(axis=-1, keepdims=True)
    # rows that already sum to 1 (to a few ulps) are not divided: a valid TPM passes bit for bit
    t = np.where(np.abs(row_sum - 1.0) <= 4 * np.finfo(np.float64).eps, tpm, tpm / row_sum)
    if p_min == 0.0 or t.min() >= p_min:
        return t
    fixed = np.zeros(t.shape, dtype=bool)
    for _ in range(M):
        low = fixed | (t < p_min)
        grew = (low != fixed).any(axis=-1, keepdims=True)  # rows with a newly floored entry
        if not grew.any():
            break
        fixed = low
        free_mass = np.where(fixed, 0.0, t).sum(axis=-1, keepdims=True)
        budget = 1.0 - p_min * fixed.sum(axis=-1, keepdims=True)
        # only rows that changed this pass are rescaled: each row's result is its own
        t = np.where(fixed, p_min, np.where(grew, t * (budget / free_mass), t))
    return t


def row_divergence(tpm: Array, reference: Array) -> Array:
    """Mean Kullback-Leibler divergence of the rows of ``tpm`` from those of ``reference``:
    ``D = (1/M) Σ_i Σ_j π_ij ln(π_ij / ρ_ij)`` (``0 ln 0 = 0``), over the leading axes of ``tpm``.

    Zero exactly when the two TPMs are equal; ``reference`` needs positive entries.
    """
    tpm = np.asarray(tpm, dtype=float)
    return rel_entr(tpm, reference).sum(axis=-1).mean(axis=-1)
