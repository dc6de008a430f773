"""The transition probability matrix (TPM): convention, construction and validation.

Convention, used everywhere in imm_gym::

    tpm[..., i, j] = P(model j at step k | model i at step k-1),   each row sums to 1.

(FilterPy's docstring states it the other way round; its code uses this one.)

A TPM is either given per step (:func:`stay_tpm`) or derived from the models' mean sojourn times
and the sampling period (:func:`tpm_from_sojourn`: a continuous-time Markov chain discretized), so
that one definition is right at any ``T``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import expm
from scipy.special import rel_entr

from imm_gym.validation import ConfigError, check_int, check_range, check_sequence

Array = NDArray[np.float64]

ROW_SUM_TOL = 1e-8

#: Largest ``T / τ_i`` of :func:`tpm_from_sojourn` (``expm`` overflows near ``1e38``; at ``1e12``
#: the chain has long forgotten its model within one step).
MAX_T_OVER_SOJOURN = 1e12


def stay_tpm(n_models: int, stay: float | Sequence[float]) -> Array:
    """TPM with ``stay`` on the diagonal and ``(1 - stay) / (M - 1)`` elsewhere in each row.

    ``stay`` is one probability for every model or one per model (``stay[i]`` on row ``i``:
    models of different mean sojourns, e.g. a sticky straight-flight model beside short-lived
    maneuver models). ``stay = 0.995`` with M = 3 is the paper-preset fixed TPM (SPEC §6);
    ``stay = 1/M`` is the uniform TPM.
    """
    n_models = check_int("n_models", n_models, 1)
    if _is_sequence(stay):
        stays = np.array([
            check_range(f"stay[{i}]", s, 0.0, 1.0)
            for i, s in enumerate(check_sequence("stay", stay, n_models))
        ])
    else:
        stays = np.full(n_models, check_range("stay", stay, 0.0, 1.0))
    if n_models == 1:
        return np.ones((1, 1))
    return stay_tpm_rows(stays[None], n_models)[0]


def stay_tpm_rows(stays: ArrayLike, n_models: int) -> Array:
    """``(N, M, M)`` TPMs with ``stays`` on the diagonal — ``(N,)``, one for every row, or
    ``(N, M)``, one per row — and the rest of each row spread evenly: :func:`stay_tpm` for
    many TPMs at once, unchecked (stays in ``[0, 1]``)."""
    M = n_models
    stays = np.asarray(stays, dtype=np.float64)
    per_row = np.broadcast_to(stays.reshape(len(stays), -1), (len(stays), M))
    tpm = np.repeat(((1.0 - per_row) / max(M - 1, 1))[:, :, None], M, axis=2)
    idx = np.arange(M)
    tpm[:, idx, idx] = per_row
    return tpm


def _is_sequence(value: object) -> bool:
    """A list, tuple or array of entries (a string is a value, checked as one)."""
    return isinstance(value, (Sequence, np.ndarray)) and not isinstance(value, (str, bytes))


def sojourn_generator(sojourn_s: Sequence[float], switch: ArrayLike | None = None) -> Array:
    r"""Generator of the continuous-time Markov chain of the models with mean sojourn times
    ``sojourn_s``:

    .. math::
        A_{ii} = -\frac{1}{\tau_i}, \qquad A_{ij} = \frac{s_{ij}}{\tau_i} \quad (j \ne i),

    each row summing to 0: model i is left at the rate ``1/τ_i`` (an exponential sojourn of mean
    ``τ_i``) for model j with probability ``s_ij``.

    Args:
        sojourn_s: ``τ_i`` (s), one per model (at least 2), each > 0 and finite.
        switch: ``(M, M)`` ``s_ij``: each row non-negative, summing to 1, zero on the diagonal.
            ``None``: departures split equally among the other models, ``1/(M - 1)``.

    Raises:
        ConfigError: naming ``sojourn_s[i]``, ``switch`` or ``switch[i][j]``.
    """
    taus = check_sequence("sojourn_s", sojourn_s)
    M = len(taus)
    if M < 2:
        raise ConfigError(f"sojourn_s needs one mean sojourn time per model (>= 2), got {taus!r}")
    rates = np.array(
        [1.0 / check_range(f"sojourn_s[{i}]", t, 0.0, lo_open=True) for i, t in enumerate(taus)]
    )
    if switch is None:
        shares = np.full((M, M), 1.0 / (M - 1))
        np.fill_diagonal(shares, 0.0)
    else:
        shares = _switch_shares(switch, M)
    A = rates[:, None] * shares
    np.fill_diagonal(A, -rates)
    return A


def _switch_shares(switch: ArrayLike, M: int) -> Array:
    """``switch`` checked as ``(M, M)``, non-negative rows summing to 1 with a zero diagonal."""
    if isinstance(switch, np.ndarray):
        switch = switch.tolist()
    rows = check_sequence("switch", switch, M)
    shares = np.array(
        [
            [
                check_range(f"switch[{i}][{j}]", v, 0.0, 1.0)
                for j, v in enumerate(check_sequence(f"switch[{i}]", row, M))
            ]
            for i, row in enumerate(rows)
        ]
    )
    for i in range(M):
        if shares[i, i] != 0.0:
            raise ConfigError(
                f"switch[{i}][{i}] must be 0 (model {i} is left at the rate 1/sojourn_s[{i}]), "
                f"got {shares[i, i]!r}"
            )
        total = float(shares[i].sum())
        if abs(total - 1.0) > ROW_SUM_TOL:
            raise ConfigError(
                f"switch[{i}] must sum to 1 (where departures from model {i} go), got {total!r}"
            )
    return shares


def tpm_from_sojourn(
    sojourn_s: Sequence[float], T: float, switch: ArrayLike | None = None
) -> Array:
    r"""TPM of the continuous-time Markov chain of :func:`sojourn_generator` sampled every ``T``:

    .. math::
        \Pi = e^{A T}, \qquad \Pi_{ij} = P(\text{model } j \text{ at } t + T \mid
        \text{model } i \text{ at } t),

    computed by :func:`scipy.linalg.expm`; entries below 0 by rounding are set to 0 and each row
    divided by its sum. ``Π_ii >= exp(-T/τ_i)`` (staying throughout, or leaving and coming back),
    equal to first order in ``T/τ_i``; the discrete chain's mean sojourn ``T / (1 - Π_ii)`` tends to
    ``τ_i`` as ``T -> 0``. With two models, ``a = 1/τ_1``, ``b = 1/τ_2``:
    ``Π_11 = (b + a e^{-(a+b)T}) / (a + b)``.

    Args:
        sojourn_s: mean sojourn time of each model ``τ_i`` (s), > 0.
        T: sampling period (s), > 0.
        switch: ``(M, M)`` split of departures (:func:`sojourn_generator`); ``None``: equal.

    Returns:
        ``(M, M)`` row-stochastic TPM.

    Raises:
        ConfigError: naming the invalid argument (``sojourn_s[i]``, ``T``, ``switch[i][j]``), or
            ``T / τ_i`` above :data:`MAX_T_OVER_SOJOURN`.

    Example:
        >>> tpm_from_sojourn([60.0, 20.0, 20.0], T=1.0).round(4)  # CV 60 s, turns 20 s
        array([[0.9837, 0.0082, 0.0082],
               [0.0245, 0.9516, 0.0239],
               [0.0245, 0.0239, 0.9516]])
    """
    A = sojourn_generator(sojourn_s, switch)
    T = check_range("T", T, 0.0, lo_open=True)
    steps = -T * np.diag(A)  # T / τ_i
    i = int(steps.argmax())
    if steps[i] > MAX_T_OVER_SOJOURN:
        raise ConfigError(
            f"T / sojourn_s[{i}] must be at most {MAX_T_OVER_SOJOURN:g} (the exponential's range), "
            f"got T = {T!r}, sojourn_s[{i}] = {-1.0 / A[i, i]!r}"
        )
    tpm = np.maximum(expm(A * T), 0.0)
    tpm /= tpm.sum(axis=1, keepdims=True)
    return validate_tpm(tpm, len(A), "exp(A T)")


def validate_tpm(tpm: Array, n_models: int, name: str = "tpm") -> Array:
    """Return ``tpm`` as a float array after checking shape ``(..., M, M)`` and stochasticity.

    Raises:
        ConfigError: naming ``name`` if the shape is wrong, an entry is negative or non-finite, or
            a row does not sum to 1 (tolerance 1e-8).
    """
    a = np.asarray(tpm, dtype=np.float64)
    if a.ndim < 2 or a.shape[-2:] != (n_models, n_models):
        raise ConfigError(f"{name} must have shape (..., {n_models}, {n_models}), got {a.shape}")
    if a.size == 0:  # an empty batch of TPMs
        return a
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
    ``p_min < 1/M`` the largest entry is at most ``1 - (M-1) p_min <= 1 - p_min``. This is SPEC
    §6's "clip, then renormalize" made exact: dividing a clipped row by its sum would pull the
    clipped entries back below ``p_min`` (by about ``p_min^2``), which §5's bound forbids.

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


#: Floor of the reference's entries in :func:`row_divergence` (at most ``-ln 1e-12 = 27.6`` nats
#: per unit of probability moved onto a zero entry).
DIVERGENCE_FLOOR = 1e-12


def row_divergence(tpm: Array, reference: Array) -> Array:
    """Mean Kullback-Leibler divergence of the rows of ``tpm`` from those of ``reference``:
    ``D = (1/M) Σ_i Σ_j π_ij ln(π_ij / max(ρ_ij, DIVERGENCE_FLOOR))`` (``0 ln 0 = 0``), over
    the leading axes of ``tpm``.

    Zero exactly when the two TPMs are equal. The floor keeps ``D`` finite where the reference
    has zero entries (a stay of 1, or ``p_min = 0``), which the exact divergence makes infinite;
    elsewhere it changes nothing.
    """
    tpm = np.asarray(tpm, dtype=float)
    return rel_entr(tpm, np.maximum(reference, DIVERGENCE_FLOOR)).sum(axis=-1).mean(axis=-1)
