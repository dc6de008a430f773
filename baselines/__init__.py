"""Rule-based TPM policies with the stable-baselines3 ``predict`` interface.

Every baseline acts only through the environment's action space and declares the environment
settings it needs (``env_overrides``). :func:`make_baseline` builds one by name.
"""

from __future__ import annotations

from typing import Any

from .amp_imm import AMPIMM
from .base import Baseline, Policy
from .fixed import STAY_GRID, FixedTPM, best_fixed_stay
from .tip_imm import TIPIMM
from .window import SlidingWindowTPM

BASELINES: dict[str, type[Baseline]] = {
    "fixed": FixedTPM,
    "tip-imm": TIPIMM,
    "amp-imm": AMPIMM,
    "window": SlidingWindowTPM,
}


def make_baseline(name: str, n_models: int = 3, **kwargs: Any) -> Baseline:
    """The baseline called ``name`` (``fixed``, ``tip-imm``, ``amp-imm``, ``window``)."""
    if name not in BASELINES:
        raise ValueError(f"unknown baseline {name!r}; available: {sorted(BASELINES)}")
    return BASELINES[name](n_models, **kwargs)


__all__ = [
    "AMPIMM",
    "BASELINES",
    "STAY_GRID",
    "TIPIMM",
    "Baseline",
    "FixedTPM",
    "Policy",
    "SlidingWindowTPM",
    "best_fixed_stay",
    "make_baseline",
]
