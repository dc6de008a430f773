"""BBSCA-tuned classical IMM: the fixed TPM with the bank's process noise tuned offline.

Seed 003 tunes ``Q`` and ``R`` by the bare-bones sine-cosine algorithm
(:mod:`imm_gym.papers.tuning`). In the environments the sensor that makes the measurements is also
the filter's ``R``, so here only the models' ``Q`` factors are tuned (one per model): BBSCA
minimizes the innovation mean-square error of the classical IMM (fixed TPM ``initial_stay``) on
training runs, and the policy is that IMM with the tuned bank (``env_overrides["bank"]``), acting
with the zero action like :class:`~baselines.fixed.FixedTPM`. Evaluated, it tracks the targets
drawn for the untuned bank, those every other policy meets (a designed family's turns follow the
CT models' ``Q``: :func:`~imm_gym.evaluation.rollout.evaluation_config`).

The tuner runs the engine of :mod:`imm_gym.tracking.hetero` (an EKF for the sonar) on the bank; the
environment then runs the tuned bank with its own filter (the SVD-UKF by default), whose
predictions differ from the EKF's only through the weak measurement nonlinearity (SPEC §6).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from imm_gym.papers.tuning import TunedBank, TunerConfig, bank_objective, tune
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.tracking.hetero import HeteroBank, HeteroIMM, linear_models
from imm_gym.tracking.models import MotionModel
from imm_gym.validation import ConfigError, check_range

from .fixed import FixedTPM
from .registry import BuildContext, register


def scaled_bank(
    bank: Sequence[MotionModel] | HeteroBank, q_scale: Sequence[float]
) -> tuple[MotionModel, ...] | HeteroBank:
    """The bank with model j's ``Q`` (``q`` and ``q_acc``, or a heterogeneous bank's
    ``q_scale``) multiplied by ``q_scale[j]`` (> 0)."""
    if len(q_scale) != len(bank):
        raise ConfigError(f"q_scale must have {len(bank)} entries (one per model), got {q_scale!r}")
    q_scale = [check_range(f"q_scale[{j}]", s, 0.0, lo_open=True) for j, s in enumerate(q_scale)]
    if isinstance(bank, HeteroBank):
        return dataclasses.replace(
            bank, q_scale=tuple(s * b for s, b in zip(q_scale, bank.q_scale, strict=True))
        )
    return tuple(
        m.scaled(s)
        for m, s in zip(bank, q_scale, strict=True)
    )


class BBSCATunedIMM(FixedTPM):
    """Classical IMM (fixed TPM) whose bank's ``Q`` factors were tuned by BBSCA.

    Args:
        bank: the untuned bank; q_scale: one factor per model; stay: the TPM's diagonal
            (``None``: the environment's ``initial_stay``).
    """

    name = "bbsca"

    def __init__(
        self,
        bank: Sequence[MotionModel] | HeteroBank,
        q_scale: Sequence[float],
        stay: float | None = None,
    ) -> None:
        super().__init__(len(bank), stay)
        self.q_scale = tuple(float(s) for s in q_scale)
        self.env_overrides["bank"] = scaled_bank(bank, self.q_scale)


def check_tunable(base: EnvConfig) -> None:
    """Raise :class:`~imm_gym.validation.ConfigError` where the bank of ``base`` cannot be tuned:
    varied conditions (one bank is tuned for one sampling period and sensor)."""
    if base.vary.active:
        raise ConfigError(
            "the bbsca baseline tunes one bank for one sampling period and sensor; it does not "
            f"take varied conditions (vary: {', '.join(base.vary.varied)})"
        )


def tune_classical(
    base: EnvConfig, train_runs: int, seed: int, config: TunerConfig | None = None
) -> tuple[BBSCATunedIMM, dict[str, Any]]:
    """Tune ``base``'s bank on ``train_runs`` runs seeded ``seed + r``; the policy and notes."""
    config = config or TunerConfig()
    check_tunable(base)
    # the environment's reset draws with the linear bank too (a designed family needs it)
    batch = draw_batch(
        base.source, base.sensor, train_runs, seed, base.velocity_std, bank=base.linear_bank
    )
    models = base.bank if isinstance(base.bank, HeteroBank) else linear_models(base.bank)
    imm = HeteroIMM(models, base.sensor, T=base.source.T)
    tpm = base.initial_tpm(base.source.T)
    tuned, result = tune(imm, batch, tpm, base.sensor.sigma, config, bank="env", tune_r=False)
    untuned = bank_objective(imm, batch, tpm, base.sensor.sigma, tune_r=False)
    notes = {
        "q_scale": list(tuned.q_scale),
        "train_objective": result.value,
        "untuned_train_objective": float(untuned(np.zeros((1, imm.n_models)))[0]),
        "train_seeds": f"{seed}..{seed + train_runs - 1}",
        "evaluations": result.evaluations,
    }
    return BBSCATunedIMM(base.bank, tuned.q_scale), notes


@register(
    "bbsca",
    help="classical IMM with the bank's Q factors tuned by BBSCA on training runs",
    check=check_tunable,
)
def build_bbsca(context: BuildContext) -> tuple[BBSCATunedIMM, dict[str, Any]]:
    """:func:`tune_classical` on the first fifth of the training runs; notes as it returns them."""
    return tune_classical(context.base, context.train_runs // 5, context.train_seed)


__all__ = [
    "BBSCATunedIMM",
    "TunedBank",
    "build_bbsca",
    "check_tunable",
    "scaled_bank",
    "tune_classical",
]
