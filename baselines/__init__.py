"""Rule-based TPM policies with the stable-baselines3 ``predict`` interface.

Every baseline acts only through the environment's action space and declares the environment
settings it needs (``env_overrides``). Each registers itself once, by name, in its own module
(:mod:`baselines.registry`), and importing this package imports every module of it: a new
baseline is one new file here. :func:`make_baseline` builds a baseline that needs only the number
of models; ``REGISTRY[name].build(context)`` builds any.
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import Any

from .base import Baseline, Policy
from .registry import REGISTRY, BuildContext, Entry, Registry, register

# isort: off
# The shipped baselines register in this order, the order the command line lists them in.
from .fixed import FixedTPM
from .tip_imm import TIPIMM
from .best_fixed import STAY_GRID, best_fixed_stay, stay_grid
from .turn_rate_prior import TurnRatePrior
from .amp_imm import AMPIMM
from .window import SlidingWindowTPM
from .bbsca import BBSCATunedIMM

# isort: on


def _import_other_modules() -> None:
    """Import (and so register) every other module of the package, in alphabetical order."""
    for module in sorted(m.name for m in pkgutil.iter_modules(__path__)):
        importlib.import_module(f"{__name__}.{module}")


def make_baseline(name: str, n_models: int = 3, **kwargs: Any) -> Baseline:
    """The registered baseline ``name`` built from M and its keyword arguments.

    Raises:
        ValueError: ``name`` is unknown, or is tuned on training runs (build it from a
            :class:`BuildContext` with ``REGISTRY[name].build``).
        ConfigError: a keyword argument outside its range (the message names it and the range).
    """
    if name not in REGISTRY:
        raise ValueError(f"unknown baseline {name!r}; available: {sorted(REGISTRY)}")
    cls = REGISTRY[name].cls
    if cls is None:
        raise ValueError(
            f"baseline {name!r} is tuned on training runs: build it with "
            f"REGISTRY[{name!r}].build(context)"
        )
    return cls(n_models, **kwargs)


_import_other_modules()

__all__ = [
    "AMPIMM",
    "REGISTRY",
    "STAY_GRID",
    "TIPIMM",
    "BBSCATunedIMM",
    "Baseline",
    "BuildContext",
    "Entry",
    "FixedTPM",
    "Policy",
    "Registry",
    "SlidingWindowTPM",
    "TurnRatePrior",
    "best_fixed_stay",
    "make_baseline",
    "register",
    "stay_grid",
]
