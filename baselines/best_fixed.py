"""The best fixed TPM: the classical IMM whose stay probability has the lowest training ARMSE —
one stay for every model (``best-fixed``), or one for the first model and one for the others
(``best-fixed-rows``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from imm_gym.tracking.tpm import stay_tpm
from imm_gym.validation import ConfigError

from .fixed import FixedTPM
from .registry import BuildContext, register

#: Stay probabilities searched for the best fixed TPM of three models: from 1/3 (uniform) to
#: 0.999 (:func:`stay_grid` for M models).
STAY_GRID = (1 / 3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 0.999)


def stay_grid(n_models: int) -> tuple[float, ...]:
    """The stays searched for a bank of ``n_models``: ``1/M`` (the uniform TPM) and every stay
    of :data:`STAY_GRID` above it — never one below ``1/M``, a prior that leaves its model more
    often than it keeps it (:data:`STAY_GRID` itself for three models)."""
    uniform = 1.0 / n_models
    return (uniform, *(s for s in STAY_GRID if s > uniform * (1.0 + 1e-12)))


def best_fixed_stay(
    scores: Sequence[float], grid: Sequence[float] = STAY_GRID
) -> tuple[float, dict[float, float]]:
    """The stay probability of ``grid`` with the lowest score (``scores[i]``: the training
    ARMSE of ``grid[i]``), and every stay's score."""
    results = {float(p): float(v) for p, v in zip(grid, scores, strict=True)}
    best = min(results, key=results.__getitem__)
    return best, results


@register("best-fixed", help="the fixed TPM with the lowest ARMSE on training runs")
def build_best_fixed(context: BuildContext) -> tuple[FixedTPM, dict[str, Any]]:
    """:class:`FixedTPM` with the stay of :func:`stay_grid` scoring best on the training runs
    (every stay's classical IMM on the same runs, in one roll-out).

    Notes: the stay found, the training ARMSE of every stay searched, the training runs and seeds.
    """
    if context.train_armse_from is None:
        raise ConfigError("best-fixed needs a build context that offers train_armse_from")
    M = context.n_models
    stays = stay_grid(M)
    tpms = np.stack([stay_tpm(M, p) for p in stays])
    stay, grid = best_fixed_stay(context.train_armse_from(FixedTPM(M), tpms), stays)
    notes = {
        "stay": stay,
        "search": {f"{p:.4f}": v for p, v in grid.items()},
        "train_runs": context.train_runs,
        "train_seeds": context.train_seeds(),
    }
    return FixedTPM(M, stay), notes


@register(
    "best-fixed-rows",
    help="the fixed TPM with one stay for the first model and one for the others, lowest "
    "ARMSE on training runs",
)
def build_best_fixed_rows(context: BuildContext) -> tuple[FixedTPM, dict[str, Any]]:
    """:class:`FixedTPM` with the stays ``(a, b, ..., b)`` scoring best on the training runs,
    ``a`` (the first model's: straight flight in the built-in banks) and ``b`` (every other
    model's) each from :func:`stay_grid` — the TPM of models with different mean sojourns, a
    sticky non-maneuvering model beside short-lived maneuver models, which a single stay cannot
    express (``best-fixed`` is its diagonal ``a = b``). Every pair's classical IMM on the same
    runs, in one roll-out of ``len(stay_grid(M))²`` TPMs.

    Notes: the stays found, the training ARMSE of every pair searched (``"a/b"``), the training
    runs and seeds.
    """
    if context.train_armse_from is None:
        raise ConfigError("best-fixed-rows needs a build context that offers train_armse_from")
    M = context.n_models
    stays = stay_grid(M)
    pairs = [(a, b) for a in stays for b in stays]
    tpms = np.stack([stay_tpm(M, (a,) + (b,) * (M - 1)) for a, b in pairs])
    scores = context.train_armse_from(FixedTPM(M), tpms)
    best = int(np.argmin(scores))
    a, b = pairs[best]
    stays = (float(a),) + (float(b),) * (M - 1)
    notes = {
        "stays": list(stays),
        "search": {f"{a:.4f}/{b:.4f}": float(v) for (a, b), v in zip(pairs, scores, strict=True)},
        "train_runs": context.train_runs,
        "train_seeds": context.train_seeds(),
    }
    return FixedTPM(M, stays), notes
