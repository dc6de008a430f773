"""The transition probability matrix (TPM): convention, construction and validation.

Convention, used everywhere in imm_gym::

    tpm[..., i, j] = P(model j at step k | model i at step k-1),   each row sums to 1.

(FilterPy's docstring states it the other way round; its code uses this one.)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .config import ConfigError, check_range

Array = NDArray[np.float64]

ROW_SUM_TOL = 1e-8


def stay_tpm(n_models: int, stay: float) -> Array:
    """TPM with ``stay`` on the diagonal and ``(1 - stay) / (M - 1)`` elsewhere.

    ``stay = 0.995`` with M = 3 is the paper-preset fixed TPM (SPEC §6); ``stay = 1/M`` is the
    uniform TPM.
    """
    if n_models < 1:
        raise ConfigError(f"n_models must be >= 1, got {n_models}")
    check_range("stay", stay, 0.0, 1.0)
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
