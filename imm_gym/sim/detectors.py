r"""Maneuver detectors: the belief that leans a switching prior's jumps
(``EnvConfig.detector``, with ``detector_share``; :func:`imm_gym.sim.stay_bank.detector_tpm_rows`).

* ``"shadow"``: the shadow IMM's mode probabilities :math:`\mu_S` — a classical IMM at the
  tracker's own TPM, which accumulates the evidence of a maneuver and which no action steers.
* ``"turn_rate"``: where the bank's models place the target's estimated turn rate. The heading
  rate of bank A's combined estimate (:func:`imm_gym.sim.features.heading_rate`) is smoothed,

  .. math::
      \bar\omega(t) = \lambda\, \bar\omega(t-1) + (1 - \lambda)\, \dot\psi(t),
      \qquad \lambda = \text{TURN_RATE_FACTOR},

  and the belief is the piecewise-linear interpolation weights of :math:`\bar\omega` between the
  models' turn rates (:func:`turn_rate_belief`): with CV at 0 and CT at :math:`\pm\omega_b`,
  :math:`b = (1 - |w|,\ \max(w, 0),\ \max(-w, 0))`, :math:`w = \bar\omega / \omega_b` clipped
  to :math:`[-1, 1]`. A turn slower than the bank's CT models is a blend of CV and the turn
  model of its sign; a nearly uniform prior's mixing at every step stands in for it blindly
  (docs/experiments.md, "Where the default loses"), this prior aims the mixing at it.
* ``"learned"``: a network's belief of the coming step's turn rate, learned from the true one's
  interpolation weights (:mod:`imm_gym.sim.learned_detector`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

#: The detectors ``EnvConfig.detector`` names.
DETECTORS = ("shadow", "turn_rate", "learned")
#: Smoothing factor ``lambda`` of the ``turn_rate`` detector's heading rate (about 3 steps).
TURN_RATE_FACTOR = 0.7


def model_turn_rates(bank: Any) -> Array | None:
    """``(M,)`` each model's turn rate (rad/s; 0 for CV and CA) of a linear bank, None for a
    heterogeneous bank (whose CT model estimates its own turn rate)."""
    if not isinstance(bank, tuple):
        return None
    return np.array([m.omega for m in bank])


class TurnRateBelief:
    r"""The piecewise-linear interpolation weights of turn rates between the models' turn rates
    ``omegas (M,)`` (rad/s), the levels sorted once: a call ``(N,) -> (N, M)``.

    With the distinct rates :math:`u_0 < \dots < u_{L-1}`, level :math:`l` gets the hat
    function

    .. math::
        h_l(\omega) = \operatorname{clip}\Big(\min\Big(
        \frac{\omega - u_{l-1}}{u_l - u_{l-1}},\ \frac{u_{l+1} - \omega}{u_{l+1} - u_l}\Big),
        0, 1\Big)

    (a missing neighbour's ratio dropped), at :math:`\omega` clipped to :math:`[u_0, u_{L-1}]`:
    between :math:`u_l` and :math:`u_{l+1}` the two neighbours share it linearly and every
    other level gets 0. Models sharing a rate share its weight evenly. Rows sum to 1; a bank of
    one rate gets the uniform belief.
    """

    def __init__(self, omegas: Array) -> None:
        levels, level_of = np.unique(np.asarray(omegas, dtype=np.float64), return_inverse=True)
        self.M, self.L = level_of.size, levels.size
        self._lo, self._hi = levels[0], levels[-1]
        self._levels = levels
        # each level's distance to its lower and upper neighbour (inf: none)
        self._gap_down = np.append(np.inf, np.diff(levels))
        self._gap_up = np.append(np.diff(levels), np.inf)
        self._level_of = level_of
        self._share = 1.0 / np.bincount(level_of, minlength=self.L)[level_of]

    def __call__(self, rate: Array) -> Array:
        N = rate.shape[0]
        if self.L == 1:
            return np.full((N, self.M), 1.0 / self.M)
        d = np.clip(rate, self._lo, self._hi)[:, None] - self._levels
        # above a level it falls toward the upper neighbour, below toward the lower one (the
        # other ratio is then <= 0); levels a subnormal gap apart overflow to inf, weight 0
        with np.errstate(over="ignore"):
            fall = np.maximum(d / self._gap_up, -d / self._gap_down)
        weight = np.maximum(1.0 - fall, 0.0)
        return weight[:, self._level_of] * self._share


def turn_rate_belief(rate: Array, omegas: Array) -> Array:
    """``(N, M)`` the interpolation weights of the turn rates ``rate (N,)`` between the models'
    turn rates ``omegas (M,)`` (rad/s): :class:`TurnRateBelief` built for one call."""
    return TurnRateBelief(omegas)(rate)


def true_turn_rates(truth: Array, T: float | Array) -> Array:
    """``(R, K)`` the target's turn rate over each step ``k`` (from state ``k`` to ``k + 1`` of
    ``truth (R, K + 1, 4)``, ``[x, y, vx, vy]``): the heading change, across ±π, over the
    sampling period ``T`` (one, or one per run ``(R,)``) — what the ``learned`` detector learns
    to believe (``python -m agents.detector``)."""
    heading = np.unwrap(np.arctan2(truth[..., 3], truth[..., 2]), axis=1)
    return np.diff(heading, axis=1) / np.reshape(T, (-1, 1))
