"""The baseline registry: each baseline declares itself once, in its own module.

A registered baseline is either a :class:`~baselines.base.Baseline` subclass, built from the number
of models alone (``cls(M)``), or a build function for a baseline tuned on training runs (the best
fixed TPM searches its stay probability, BBSCA tunes the bank's ``Q``). Both build through one
signature, ``build(context) -> (policy, notes)``: the :class:`BuildContext` carries the
evaluation's configuration, the training runs and a scorer of policies on them, provided by the
caller (the evaluation command line), so a baseline never imports the command line. ``notes`` are
reported next to the policy's scores (the stay found, the tuned factors...).

Registering::

    @register("fixed", help="classical IMM, the fixed TPM")
    class FixedTPM(Baseline): ...

    @register("best-fixed", help="the fixed TPM with the lowest ARMSE on training runs")
    def build_best_fixed(context: BuildContext) -> tuple[Baseline, dict[str, Any]]: ...
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from imm_gym.evaluation.rollout import evaluation_config
from imm_gym.sim.env_config import EnvConfig

from .base import Baseline

BuildFn = Callable[["BuildContext"], tuple[Baseline, dict[str, Any]]]
Registered = TypeVar("Registered", bound=Callable[..., Any])


@dataclass(frozen=True)
class BuildContext:
    """What a baseline may use to build its policy.

    Attributes:
        base: the evaluation's common configuration; the policy's ``env_overrides`` go on top.
        train_seed: seed of the first training run; run ``r`` uses ``train_seed + r``, never an
            evaluation seed.
        train_runs: number of training runs.
        train_armse: ``train_armse(policy)``, the policy's position ARMSE over the ``train_runs``
            training runs, its ``env_overrides`` applied to ``base``.
        train_armse_from: ``train_armse_from(policy, tpms)``, the ``(G,)`` ARMSEs of the policy
            started from each TPM of ``tpms (G, M, M)`` on the same training runs, in one
            roll-out of ``G * train_runs`` episodes (the fixed TPMs' search); None where the
            caller does not offer it.
    """

    base: EnvConfig
    train_seed: int
    train_runs: int
    train_armse: Callable[[Baseline], float]
    train_armse_from: Callable[[Baseline, NDArray[np.float64]], NDArray[np.float64]] | None = None

    @property
    def n_models(self) -> int:
        """M, the number of models of the bank."""
        return len(self.base.bank)

    def train_seeds(self, runs: int | None = None) -> str:
        """The seeds of the first ``runs`` (default ``train_runs``) training runs, ``"a..b"``."""
        runs = self.train_runs if runs is None else runs
        return f"{self.train_seed}..{self.train_seed + runs - 1}"


@dataclass(frozen=True)
class Entry:
    """One registered baseline.

    Attributes:
        name: its name on the command line (``--policy NAME``).
        help: one line for the command line's help.
        build: ``build(context) -> (policy, notes)``.
        cls: the class built from M alone (:func:`~baselines.make_baseline`); ``None`` for a
            baseline tuned on training runs.
        check: ``check(base)`` raises :class:`~imm_gym.validation.ConfigError` where the
            baseline cannot run on the configuration ``base`` (a detector rule on a bank its
            detector cannot read, a tuner on varied conditions), before any tuning; a class is
            checked by its settings, ``cls(M).env_overrides`` on ``base``.
    """

    name: str
    help: str
    build: BuildFn
    cls: type[Baseline] | None
    check: Callable[[EnvConfig], None]


class Registry(Mapping[str, Entry]):
    """The registered baselines by name, in registration order."""

    def __init__(self) -> None:
        self._entries: dict[str, Entry] = {}

    def register(
        self, name: str, *, help: str, check: Callable[[EnvConfig], None] | None = None
    ) -> Callable[[Registered], Registered]:
        """Decorator registering a :class:`Baseline` subclass or a build function as ``name``.

        A class is built as ``cls(M)`` with no notes and takes ``name`` as its ``name``; a
        function is the ``build(context) -> (policy, notes)`` of a tuned baseline, ``check``
        (:class:`Entry`) what it cannot run on (none when not given).

        Raises:
            ValueError: ``name`` is already registered.
        """

        def decorate(target: Registered) -> Registered:
            if name in self._entries:
                raise ValueError(f"baseline {name!r} is already registered")
            if isinstance(target, type):
                target.name = name
                entry = Entry(name, help, _built_from_n_models(target), target,
                              check or _settings_check(target))
            else:
                entry = Entry(name, help, target, None, check or _admits_all)
            self._entries[name] = entry
            return target

        return decorate

    def unregister(self, name: str) -> None:
        """Remove ``name`` (a throw-away baseline of a test, say)."""
        del self._entries[name]

    def __getitem__(self, name: str) -> Entry:
        return self._entries[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)


def _admits_all(base: EnvConfig) -> None:
    """The check of a baseline that runs on every configuration."""


def _settings_check(cls: type[Baseline]) -> Callable[[EnvConfig], None]:
    """The check of a class: its settings (``cls(M).env_overrides``) on the configuration."""

    def check(base: EnvConfig) -> None:
        evaluation_config(base, cls(len(base.bank)).env_overrides)

    return check


def _built_from_n_models(cls: type[Baseline]) -> BuildFn:
    def build(context: BuildContext) -> tuple[Baseline, dict[str, Any]]:
        return cls(context.n_models), {}

    return build


#: Every baseline, filled by the ``register`` decorators as the modules of ``baselines`` load.
REGISTRY = Registry()
register = REGISTRY.register
