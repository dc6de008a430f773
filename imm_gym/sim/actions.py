r"""From an action to the TPM bank A mixes with (the numpy reference of the compiled
:func:`imm_gym.sim.kernels.tpm_from_action`).

The action ``a`` is ``(N, M*M)``, row-major over ``(i, j)``, clipped to [-1, 1]:

* ``scale`` mode: :math:`\pi_{ij} \leftarrow \pi_{ij}\, f^{a_{ij}}` on the current TPM
  (``f = max_factor``; TIP-IMM's α/β steps are ``a = log α / log f``, ``log β / log f``);
* ``set`` mode: :math:`\pi_i = \operatorname{softmax}(\lambda a_i)` row by row
  (``lambda = logit_scale``);

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


def validate_action(action: NDArray[Any], n_envs: int, action_dim: int) -> Array:
    """``action`` as float64 after checking shape ``(N, M*M)`` and finiteness (not clipped)."""
    a = np.asarray(action, dtype=np.float64)
    if a.shape != (n_envs, action_dim):
        raise ActionError(
            f"action must have shape ({n_envs}, {action_dim}) "
            f"(or ({action_dim},) for the scalar env), got {np.shape(action)}"
        )
    if np.count_nonzero(np.isfinite(a)) != a.size:
        raise ActionError("action must be finite (got NaN or inf)")
    return a


def tpm_from_action(action: Array, tpm: Array, config: EnvConfig) -> Array:
    """The ``(N, M, M)`` TPMs an action ``(N, M*M)`` (finite) produces from the current ``tpm``
    (``scale``) or from scratch (``set``), rows normalized and floored."""
    a = np.clip(action, -1.0, 1.0)
    N, M = a.shape[0], tpm.shape[-1]
    a = a.reshape(N, M, M)
    if config.action_mode == "scale":
        raw = tpm * np.power(config.max_factor, a)
    else:
        logits = config.logit_scale * a
        raw = np.exp(logits - logits.max(axis=-1, keepdims=True))
    return apply_floor(raw, config.p_min)
