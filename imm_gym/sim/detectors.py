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
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

#: The detectors ``EnvConfig.detector`` names.
DETECTORS = ("shadow", "turn_rate")
#: Smoothing factor ``lambda`` of the ``turn_rate`` detector's heading rate (about 3 steps).
TURN_RATE_FACTOR = 0.7


def model_turn_rates(bank: Any) -> Array | None:
    """``(M,)`` each model's turn rate (rad/s; 0 for CV and CA) of a linear bank, None for a
    heterogeneous bank (whose CT model estimates its own turn rate)."""
    if not isinstance(bank, tuple):
        return None
    return np.array([m.omega for m in bank])


def turn_rate_belief(rate: Array, omegas: Array) -> Array:
    r"""``(N, M)`` the piecewise-linear interpolation weights of the turn rates ``rate (N,)``
    between the models' turn rates ``omegas (M,)`` (rad/s).

    With the distinct rates :math:`u_0 < \dots < u_{L-1}` and :math:`u_l \le \omega \le
    u_{l+1}`, level :math:`l` gets :math:`(u_{l+1} - \omega) / (u_{l+1} - u_l)` and level
    :math:`l + 1` the rest (:math:`\omega` clipped to :math:`[u_0, u_{L-1}]`); models sharing
    a rate share its weight evenly. Rows sum to 1; a bank of one rate gets the uniform belief.
    """
    levels, level_of = np.unique(omegas, return_inverse=True)
    N, M, L = rate.shape[0], omegas.shape[0], levels.size
    if L == 1:
        return np.full((N, M), 1.0 / M)
    w = np.clip(rate, levels[0], levels[-1])
    low = np.clip(np.searchsorted(levels, w, side="right") - 1, 0, L - 2)
    t = (w - levels[low]) / (levels[low + 1] - levels[low])
    weight = np.zeros((N, L))
    rows = np.arange(N)
    weight[rows, low] = 1.0 - t
    weight[rows, low + 1] += t
    per_model = np.bincount(level_of, minlength=L)
    return weight[:, level_of] / per_model[level_of]
