r"""From an action to the TPM bank A mixes with (the numpy reference of the compiled
:func:`imm_gym.sim.kernels.tpm_from_action`).

The action ``a`` is ``(N, M*M)``, row-major over ``(i, j)``, clipped to [-1, 1]:

* ``scale`` mode: :math:`\pi_{ij} \leftarrow \pi_{ij}\, f^{a_{ij}}` on the current TPM
  (``f = max_factor``; TIP-IMM's α/β steps are ``a = log α / log f``, ``log β / log f``);
* ``set`` mode: :math:`\pi_i = \operatorname{softmax}(\lambda a_i)` row by row
  (``lambda = logit_scale``);
* ``stay`` mode, ``a`` is ``(N, M)``: each row's stay probability moved from the tracker's own
  TPM :math:`\pi^0` (its initial TPM, the one bank B keeps) on the logit scale,
  :math:`s_i = \sigma(\operatorname{logit} \pi^0_{ii} + \lambda a_i)` clipped to
  :math:`[\min(1/M, \pi^0_{ii}), 1 - (M-1) p_{min}]` (below :math:`1/M` only where
  :math:`\pi^0`'s own stay is), the rest of the row in :math:`\pi^0`'s proportions,
  :math:`\pi_{ij} = (1 - s_i)\, \pi^0_{ij} / (1 - \pi^0_{ii})` (uniform where
  :math:`\pi^0_{ii} = 1`): the TPM stays a switching prior of the tracker's structure, the
  zero action keeps the tracker's TPM exactly (the classical IMM), and an action means the
  same change of mean sojourn (in logits) on every tracker;
* ``stay_step`` mode, ``a`` is ``(N, M)``: the same rows, each stay moved from the *current*
  TPM's, :math:`s_i = \sigma(\operatorname{logit} \pi_{ii} + \lambda a_i)`: the policy steers
  the stays by steps of at most ``logit_scale`` logits (a smooth TPM, and exploration that
  drifts instead of averaging out); the zero action keeps the current TPM;

then every row is normalized and floored to ``[p_min, 1 - p_min]``
(:func:`imm_gym.tracking.tpm.apply_floor`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.env_config import EnvConfig
from imm_gym.tracking.tpm import apply_floor

Array = NDArray[np.float64]


class ActionError(ValueError):
    """An action has the wrong shape or a non-finite entry."""


def real_numbers(action: Any) -> NDArray[Any]:
    """``action`` as an array after checking it holds real numbers (bool, integer or float):
    a complex action would lose its imaginary part, a string be parsed."""
    a = action if isinstance(action, np.ndarray) else np.asarray(action)
    if a.dtype.kind not in "biuf":
        raise ActionError(f"action must hold real numbers, got dtype {a.dtype}")
    return a


def validate_action(action: NDArray[Any], n_envs: int, action_dim: int) -> Array:
    """``action`` as a C-contiguous, writeable float64 array after checking its type (real
    numbers: bool, integer or float), shape ``(N, action_dim)`` and finiteness (not clipped)."""
    a = np.asarray(real_numbers(action), dtype=np.float64)
    if a.shape != (n_envs, action_dim):
        raise ActionError(
            f"action must have shape ({n_envs}, {action_dim}) "
            f"(or ({action_dim},) for the scalar env), got {np.shape(action)}"
        )
    if np.count_nonzero(np.isfinite(a)) != a.size:
        raise ActionError("action must be finite (got NaN or inf)")
    # the compiled step is cached for one layout: a strided, Fortran-ordered or read-only action
    # would compile it anew (minutes), so such an action is copied
    return a if a.flags.c_contiguous and a.flags.writeable else a.copy()


#: the modes whose action is one entry per model (a stay probability per row)
STAY_MODES = ("stay", "stay_step")


def action_size(action_mode: str, n_models: int) -> int:
    """Entries of one action: ``M`` in the stay modes, ``M*M`` otherwise."""
    return n_models if action_mode in STAY_MODES else n_models * n_models


def tpm_from_action(action: Array, tpm: Array, config: EnvConfig, base: Array) -> Array:
    """The ``(N, M, M)`` TPMs an action (finite, ``(N, action_size)``) produces from the current
    ``tpm`` (``scale``, ``stay_step``), from scratch (``set``) or from the tracker's own TPMs
    ``base`` (``stay``; the stay modes keep ``base``'s switching structure), rows normalized and
    floored."""
    a = np.clip(action, -1.0, 1.0)
    N, M = a.shape[0], tpm.shape[-1]
    if config.action_mode in STAY_MODES:
        source = base if config.action_mode == "stay" else tpm
        rows = stay_rows(a, source, base, config.logit_scale, config.p_min)
        return apply_floor(rows, config.p_min)
    a = a.reshape(N, M, M)
    if config.action_mode == "scale":
        raw = tpm * np.power(config.max_factor, a)
    else:
        logits = config.logit_scale * a
        raw = np.exp(logits - logits.max(axis=-1, keepdims=True))
    return apply_floor(raw, config.p_min)


def stay_rows(a: Array, source: Array, structure: Array, gain: float, p_min: float) -> Array:
    """The stay modes (module docstring): each row's stay probability moved ``gain * a``
    ``(N, M)`` logits from the row of ``source (N, M, M)``, the rest of the row in the
    proportions of ``structure``'s; a zero entry keeps its ``source`` row exactly.

    Computed through the leaving probability ``1 - s_i = 1 / (1 + exp(logit))``, the accurate
    side for stays near 1, clipped to ``[(M-1) p_min, max(1 - 1/M, 1 - structure_ii)]``: no
    stay below ``1/M`` unless ``structure``'s own is (a base that leans a row toward another
    mode, ``detector_share``), so a small action moves a row a little."""
    M = source.shape[-1]
    eye = np.eye(M, dtype=bool)
    stay0 = np.diagonal(source, axis1=-2, axis2=-1)
    leave0 = 1.0 - np.diagonal(structure, axis1=-2, axis2=-1)
    with np.errstate(divide="ignore", over="ignore"):  # a stay of 0 or 1: logit -inf or inf
        logit = np.log(stay0) - np.log1p(-stay0) + gain * a
        most = np.maximum(1.0 - 1.0 / M, leave0)
        leave = np.clip(1.0 / (1.0 + np.exp(logit)), (M - 1) * p_min, most)
    share = np.where(
        leave0[..., None] > 0.0,
        structure / np.where(leave0 > 0.0, leave0, 1.0)[..., None],
        1.0 / max(M - 1, 1),
    )
    rows = np.where(eye, (1.0 - leave)[..., None], leave[..., None] * share)
    return np.where((a == 0.0)[..., None], source, rows)
