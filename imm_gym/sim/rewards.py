r"""Named reward terms, each computed once from the per-step errors that every engine returns.

With ``e`` the position error of the combined estimate and ``e_s`` the shadow IMM's (both capped
at ``divergence_error``) and ``s = reward_scale``:

=====================  ==============================  ========================================
term                   value                           meaning
=====================  ==============================  ========================================
``error``              :math:`-e / s`                  tracking accuracy alone
``advantage``          :math:`(e_s - e) / s`           accuracy beyond the shadow's fixed TPM
``squared_advantage``  :math:`(e_s^2 - e^2) / s^2`     the per-step terms of the mean squared
                                                       error the ARMSE's RMSE(t) are made of
``bank_advantage``     :math:`(\bar e - e) / s`        accuracy beyond the stay bank's IMMs
                                                       weighted by their evidence
=====================  ==============================  ========================================

:math:`\bar e` (:meth:`imm_gym.sim.stay_bank.StayBank.position_error`) follows the stays the
measurements support, as the ``stay`` action's base does (``stay_base: evidence``), so it tracks
the policy's own error more closely than the shadow's fixed TPM does and leaves less of the
targets' and the noise's randomness in the reward; like the shadow's, no action moves it, so the
best policy is the same under either baseline. A term flagged ``needs_stay_bank`` is called with
:class:`StepErrors` in place of the bank step.

Every term the configuration allows is in ``info`` as ``reward_<term>``; the reward is the term
``EnvConfig.reward`` names, minus ``tpm_cost`` times ``info["tpm_divergence"]``, the mean KL
divergence of the TPM's rows from the shadow's (:func:`imm_gym.tracking.tpm.row_divergence`),
minus ``tpm_change_cost`` times ``info["tpm_change"]``, the same divergence from the previous
step's TPM (the TPM stays a switching prior rather than a per-step mixing knob), plus
``mode_reward`` times ``info["mode_score"]``, the log score of the mode probabilities beyond
the shadow's on the model that matches the true motion,
:math:`\ln(\mu_{j^*} + \epsilon) - \ln(\mu^s_{j^*} + \epsilon)` (:func:`mode_score`; 0 where no
model matches): the policy is paid for mode probabilities that identify the maneuver, the IMM's
maneuver detection, not only for position. With ``EnvConfig.mode_score = "hit"`` the term is
:func:`mode_hit` instead, :math:`[\arg\max_j \mu_j = j^*] - [\arg\max_j \mu^s_j = j^*]`: the
maneuver identified, whatever the confidence (the log score also pays for confidence; trained
both ways, the agents were alike: docs/experiments.md, "A fixed TPM with a stay per model").
Adding a term is one :func:`register` call here; :class:`Reward` evaluates them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.bank_step import BankStep
from imm_gym.tracking.tpm import row_divergence

Array = NDArray[np.float64]


@dataclass(frozen=True)
class RewardTerm:
    """A reward term: ``value(step, reward_scale) -> (N,)`` (the scale a number or ``(N,)``);
    ``needs_shadow`` if it uses the shadow IMM's error, ``needs_stay_bank`` if it uses the stay
    bank's (it is then called with :class:`StepErrors` instead of the bank step)."""

    name: str
    value: Callable[[Any, float | Array], Array]
    needs_shadow: bool = False
    needs_stay_bank: bool = False


class StepErrors(NamedTuple):
    """The errors a ``needs_stay_bank`` term reads: ``(N,)`` each, capped at
    ``divergence_error``."""

    position_error: Array  # e, the combined estimate's
    bank_position_error: Array  # \bar e, the stay bank's (StayBank.position_error)


#: Every term by name, in declaration order.
REWARD_TERMS: dict[str, RewardTerm] = {}


def register(term: RewardTerm) -> RewardTerm:
    """Add ``term`` to :data:`REWARD_TERMS` (names are unique)."""
    if term.name in REWARD_TERMS:
        raise ValueError(f"reward term {term.name!r} is already registered")
    REWARD_TERMS[term.name] = term
    return term


def error(step: BankStep, s: float | Array) -> Array:
    """:math:`-e / s`, written ``e / (-s)``: the same IEEE result, one array operation fewer."""
    return step.position_error / -s


def advantage(step: BankStep, s: float | Array) -> Array:
    """:math:`(e_s - e) / s`."""
    return (step.shadow_position_error - step.position_error) / s


def bank_advantage(step: StepErrors, s: float | Array) -> Array:
    r""":math:`(\bar e - e) / s`."""
    return (step.bank_position_error - step.position_error) / s


def squared_advantage(step: BankStep, s: float | Array) -> Array:
    """:math:`(e_s^2 - e^2) / s^2`."""
    return (step.shadow_position_error**2 - step.position_error**2) / s**2


# named functions, not lambdas: an env (and the core holding these) pickles
register(RewardTerm("error", error))
register(RewardTerm("advantage", advantage, needs_shadow=True))
register(RewardTerm("squared_advantage", squared_advantage, needs_shadow=True))
register(RewardTerm("bank_advantage", bank_advantage, needs_stay_bank=True))


#: Floor of the probabilities in :func:`mode_score` (a log score of at most ``-ln 1e-3 = 6.9``).
MODE_SCORE_FLOOR = 1e-3


def mode_score(mode_probs: Array, shadow_probs: Array, true_model: NDArray[np.int64]) -> Array:
    r"""``(N,)`` :math:`\ln(\mu_{j^*} + \epsilon) - \ln(\mu^s_{j^*} + \epsilon)` with ``j*`` the
    true model of the step and ``epsilon = MODE_SCORE_FLOOR``; 0 where ``j* = -1``. A failed
    tracker's probabilities (NaN) score as 0 on the true model, the lowest score."""
    rows = np.arange(mode_probs.shape[0])
    j = np.maximum(true_model, 0)
    score = np.log(_identified(mode_probs)[rows, j] + MODE_SCORE_FLOOR) - np.log(
        _identified(shadow_probs)[rows, j] + MODE_SCORE_FLOOR
    )
    return np.where(true_model >= 0, score, 0.0)


def _identified(mode_probs: Array) -> Array:
    """``mode_probs`` with a failed tracker's row (NaN) at 0: it identifies no model."""
    return np.nan_to_num(mode_probs, nan=0.0)


def mode_hit(mode_probs: Array, shadow_probs: Array, true_model: NDArray[np.int64]) -> Array:
    r"""``(N,)`` :math:`[\arg\max_j \mu_j = j^*] - [\arg\max_j \mu^s_j = j^*]`, the step's
    mode identification (the argmax on the true model) beyond the shadow's; 0 where
    ``j* = -1``; a failed tracker (NaN probabilities) identifies none."""
    hit = (np.argmax(mode_probs, axis=1) == true_model) & np.isfinite(mode_probs).all(axis=1)
    shadow_hit = (np.argmax(shadow_probs, axis=1) == true_model) & np.isfinite(
        shadow_probs
    ).all(axis=1)
    return np.where(true_model >= 0, hit.astype(np.float64) - shadow_hit, 0.0)


#: The mode-identification terms by ``EnvConfig.mode_score``.
MODE_SCORES: dict[str, Callable[[Array, Array, NDArray[np.int64]], Array]] = {
    "log": mode_score,
    "hit": mode_hit,
}


class Reward:
    """The reward of one configuration, its terms resolved once (a step costs only the terms'
    arithmetic).

    Args:
        name: the rewarded term; shadow: the shadow IMM runs; stay_bank: the stay bank runs
            (its terms are computed only then).
        tpm_cost: weight of the TPM's divergence from ``shadow_tpm`` ``(M, M)`` or ``(N, M, M)``
            (the slots', read at each call).
        mode_reward: weight of the mode-identification term, ``MODE_SCORES[mode_score]``.
        tpm_change_cost: weight of the TPM's divergence from the previous step's.
    """

    def __init__(
        self,
        name: str,
        shadow: bool,
        tpm_cost: float,
        shadow_tpm: Array,
        mode_reward: float = 0.0,
        tpm_change_cost: float = 0.0,
        stay_bank: bool = False,
        mode_score: str = "log",
    ) -> None:
        usable = [
            t
            for t in REWARD_TERMS.values()
            if (shadow or not t.needs_shadow) and (stay_bank or not t.needs_stay_bank)
        ]
        self._terms = tuple((f"reward_{t.name}", t.value) for t in usable if not t.needs_stay_bank)
        self._bank_terms = tuple((f"reward_{t.name}", t.value) for t in usable if t.needs_stay_bank)
        #: whether a call needs the stay bank's error
        self.needs_stay_bank = bool(self._bank_terms)
        self._rewarded = f"reward_{name}"
        self._tpm_cost = tpm_cost
        self._shadow_tpm = shadow_tpm
        self._mode_reward = mode_reward
        self._mode_score = MODE_SCORES[mode_score]
        self._tpm_change_cost = tpm_change_cost

    def __call__(
        self,
        step: BankStep,
        scale: float | Array,
        true_model: NDArray[np.int64],
        previous_tpm: Array,
        bank_error: Array | None = None,
    ) -> tuple[Array, dict[str, Array]]:
        """The reward of every slot ``(N,)`` and the ``info`` entries of its terms
        (``scale``: ``reward_scale`` in metres, a number or the slots' ``(N,)``; ``true_model``:
        the step's true model per slot, -1 for none; ``previous_tpm``: the ``(N, M, M)`` TPMs of
        the step before; ``bank_error``: the stay bank's error, needed when
        :attr:`needs_stay_bank`)."""
        terms = {key: value(step, scale) for key, value in self._terms}
        if self._bank_terms:
            if bank_error is None:
                raise ValueError("this reward needs the stay bank's position error")
            errors = StepErrors(step.position_error, bank_error)
            terms.update((key, value(errors, scale)) for key, value in self._bank_terms)
        reward = terms[self._rewarded].copy()
        if self._tpm_cost > 0.0:
            terms["tpm_divergence"] = row_divergence(step.tpm, self._shadow_tpm)
            reward -= self._tpm_cost * terms["tpm_divergence"]
        if self._tpm_change_cost > 0.0:
            terms["tpm_change"] = row_divergence(step.tpm, previous_tpm)
            reward -= self._tpm_change_cost * terms["tpm_change"]
        if self._mode_reward > 0.0:
            terms["mode_score"] = self._mode_score(step.mode_probs, step.mu_s, true_model)
            reward += self._mode_reward * terms["mode_score"]
        return reward, terms
