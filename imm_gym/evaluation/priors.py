r"""Switching priors given step by step, scored on common random numbers.

A study of TPM rules (``examples/detector_prior.py``, ``examples/detector_headroom.py``) runs
``P`` priors on the same ``R`` runs: one core of ``P * R`` slots, prior-major (slot
``p * R + r`` is prior ``p`` on run ``r``, seed ``seed + r``), in ``set`` mode with each step's
rows handed over as logits :math:`\log \pi / L`. The ``set`` action's softmax per row gives the
rows back exactly wherever every entry is at least the floor ``p_min`` (:data:`P_MIN`, 1e-4,
above the logits' reach :math:`e^{-L}`, :data:`LOGIT` :math:`L = 10`: 4.5e-5). A row with a
smaller entry runs floored: that entry raised to ``P_MIN`` and the row's others shrunk to pay
for it (:func:`~imm_gym.tracking.tpm.apply_floor`), as the environment runs such a prior at that
``p_min`` (the ``turn-rate-prior`` baseline's). Some priors studied have such rows: at share 1
(``examples/detector_headroom.py``'s largest) a belief on some of the models leaves exact zeros
on the others (the true turn rate on a model's own, the interpolation of a rate between two
models) and a network's or the shadow's belief entries below ``P_MIN``; those rows, and the
figures of docs/experiments.md from them, are the floored priors'. Below share 0.96 every entry
of a prior of stay at most 0.995 is at least ``P_MIN`` (``(1 - r)(1 - v) / M``, M = 3).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.evaluation.metrics import mode_accuracy, mode_prob_tv
from imm_gym.evaluation.rollout import armse_from_squared
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.tracking.tpm import validate_tpm
from imm_gym.validation import ConfigError

Array = NDArray[np.float64]

#: ``set`` mode's logit per unit action: ``log pi`` of every row stays inside [-1, 1] · LOGIT.
LOGIT = 10.0
#: The TPM's floor while the priors run: an entry of a prior below it runs at it (module
#: docstring).
P_MIN = 1e-4


@dataclass(frozen=True)
class PriorSlots:
    """A reset core of ``n_priors * runs`` slots, prior-major (module docstring).

    Attributes:
        core: the core, in ``set`` mode, reset on the runs.
        n_priors: ``P``, the priors run side by side.
        runs: ``R``, the runs each prior is scored on.
    """

    core: TrackingCore
    n_priors: int
    runs: int


def prior_core(overrides: Mapping[str, Any], n_priors: int, runs: int, seed: int) -> PriorSlots:
    """A reset core of ``n_priors * runs`` slots on the configuration ``overrides`` in ``set``
    mode: every prior on runs ``seed .. seed + runs - 1`` (module docstring), no features and an
    error reward (nothing but the tracker is read).

    Raises:
        ConfigError: ``n_priors`` or ``runs`` below 1.
    """
    for name, value in (("n_priors", n_priors), ("runs", runs)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")
    config = EnvConfig.build(dict(overrides)).replace(
        action_mode="set", logit_scale=LOGIT, p_min=P_MIN, shadow="fixed", reward="error",
        obs_features=(), tpm_cost=0.0, tpm_change_cost=0.0, mode_reward=0.0,
    )
    core = TrackingCore(config, n_priors * runs)
    core.reset(np.arange(n_priors * runs), [seed + r for _ in range(n_priors) for r in range(runs)])
    return PriorSlots(core, n_priors, runs)


@dataclass(frozen=True)
class PriorRuns:
    """Every prior's errors and mode probabilities on the runs.

    Attributes:
        squared_error: ``(P, R, K)`` squared position errors.
        mode_probs: ``(P, R, K, M)``.
        true_model: ``(R, K)`` the true model of each step.
        live: ``(P, R, K)`` the steps recorded from the tracker itself (False from the step a
            run's tracker diverged at, as :attr:`~imm_gym.evaluation.rollout.Rollout.live`).
    """

    squared_error: Array
    mode_probs: Array
    true_model: NDArray[np.int64]
    live: NDArray[np.bool_]

    @property
    def diverged(self) -> NDArray[np.bool_]:
        """``(P, R)`` the runs whose tracker diverged under each prior."""
        return ~self.live[..., -1]

    def scores(self, prior: int) -> tuple[float, float | None, float | None]:
        """Prior ``prior``'s position ARMSE, mode accuracy and mode-probability total variation
        per step over the live steps (:mod:`imm_gym.evaluation.metrics`; None where nothing
        counts)."""
        probs = self.mode_probs[prior]
        return (
            armse_from_squared(self.squared_error[prior]),
            mode_accuracy(probs, self.true_model),
            mode_prob_tv(probs, self.live[prior]),
        )


def run_priors(
    slots: PriorSlots, rows: Callable[[int, dict[str, Any] | None], Array]
) -> PriorRuns:
    """Run the core of :func:`prior_core` to its horizon, the TPM of step ``k`` (all slots,
    ``(P * R, M, M)``, prior-major) given by ``rows(k, info)``, ``info`` the previous step's
    (None before the first).

    A run whose tracker diverges is scored as :func:`~imm_gym.evaluation.rollout.rollout`
    scores it: from the step it diverges at, its position error is ``divergence_error`` and its
    mode probabilities uniform, and its slot is no longer stepped (its rows are not read).

    Raises:
        ConfigError: a step's rows (of the slots still tracking) not ``(P * R, M, M)``, not
            finite, with a negative entry or a row not summing to 1.
    """
    core, n_priors, runs = slots.core, slots.n_priors, slots.runs
    N, M, K = core.n_envs, core.M, core.horizon
    truth = core.truth[:runs, 1:, :2].copy()
    true_model = core.true_model[:runs].copy()
    held = core.config.divergence_error**2
    squared_error = np.empty((n_priors, runs, K))
    probs = np.empty((n_priors, runs, K, M))
    live = np.empty((n_priors, runs, K), dtype=bool)
    alive = np.ones(N, dtype=bool)
    info = None
    for k in range(K):
        tpm = np.asarray(rows(k, info), dtype=np.float64)
        if tpm.shape != (N, M, M):
            raise ConfigError(f"rows({k}) must have shape {(N, M, M)}, got {tpm.shape}")
        if alive.any():  # every run lost: nothing left to check (or step)
            validate_tpm(tpm[alive], M, name=f"rows({k})")
        action = np.log(np.maximum(np.where(alive[:, None, None], tpm, 1.0), 1e-300)) / LOGIT
        result = core.step(np.clip(action, -1.0, 1.0).reshape(N, M * M), active=alive)
        info = result.info
        alive &= ~result.terminated
        live[:, :, k] = alive.reshape(n_priors, runs)
        position = info["estimate"][:, :2].reshape(n_priors, runs, 2)
        error = np.sum((position - truth[:, k]) ** 2, axis=-1)
        squared_error[:, :, k] = np.where(alive.reshape(n_priors, runs), error, held)
        live_probs = np.where(alive[:, None], info["mode_probs"], 1.0 / M)
        probs[:, :, k] = live_probs.reshape(n_priors, runs, M)
    return PriorRuns(squared_error, probs, true_model, live)
