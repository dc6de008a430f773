"""The best fixed TPM: the classical IMM whose stay probability has the lowest training ARMSE."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from .fixed import FixedTPM
from .registry import BuildContext, register

#: Stay probabilities searched for the best fixed TPM: from 1/M (uniform) to 0.999.
STAY_GRID = (1 / 3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 0.999)


def best_fixed_stay(
    score: Callable[[float], float], grid: Sequence[float] = STAY_GRID
) -> tuple[float, dict[float, float]]:
    """The stay probability with the lowest score (``score(stay) -> ARMSE`` on training runs)."""
    results = {float(p): float(score(p)) for p in grid}
    best = min(results, key=results.__getitem__)
    return best, results


@register("best-fixed", help="the fixed TPM with the lowest ARMSE on training runs")
def build_best_fixed(context: BuildContext) -> tuple[FixedTPM, dict[str, Any]]:
    """:class:`FixedTPM` with the stay of :data:`STAY_GRID` scoring best on the training runs.

    Notes: the stay found, the training ARMSE of every stay searched, the training runs and seeds.
    """
    M = context.n_models
    stay, grid = best_fixed_stay(lambda p: context.train_armse(FixedTPM(M, p)))
    notes = {
        "stay": stay,
        "search": {f"{p:.4f}": v for p, v in grid.items()},
        "train_runs": context.train_runs,
        "train_seeds": context.train_seeds(),
    }
    return FixedTPM(M, stay), notes
