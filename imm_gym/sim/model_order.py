r"""The bank's models in a canonical order, so that a policy does not depend on how a tracker's
configuration happens to list them (``EnvConfig.model_order``).

An IMM's models are a set: listing a bank as CT(+4 °/s), CV, CT(−4 °/s) instead of CV, CT(+4),
CT(−4) is the same tracker. A learned policy reads per-model entries and writes one stay (or one
row) per model by position, so without an agreed order it acts on the wrong models. With
``model_order="canonical"`` the observation lists the models, and the action addresses them, in
the order of the key

.. math::
    (\text{kind}, |\omega|, \omega < 0, \sigma_v),

kinds ranked CV, CA, CT (a heterogeneous bank: NCV, CT, CTRA, with ``q_scale`` in place of
:math:`\sigma_v`), :math:`\omega` the turn rate and :math:`\sigma_v` the RMS velocity process
noise per step; ties keep the bank's order (the tied models are interchangeable). The banks of
the presets and examples (CV, CT(+ω), CT(−ω)) are already in it. Inside the core everything
stays in the bank's order (the TPM, the filters, ``info``); only the observation, the critic's
state and the action are reordered, by index arrays built once:

* observation: ``obs_canonical = obs[:, observation_index(...)]``;
* action: ``action_bank = action_canonical[:, action_index(...)]``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.features import FEATURES

Index = NDArray[np.intp]

#: The orders of ``EnvConfig.model_order``.
MODEL_ORDERS = ("bank", "canonical")
#: Rank of each model kind in the canonical order (linear and heterogeneous banks).
KIND_RANK = {"cv": 0, "ncv": 0, "ca": 1, "ct": 2, "ctra": 3}


def canonical_order(bank: Any, velocity_noise: Sequence[float] | None = None) -> Index:
    """``order`` with ``order[c]`` the bank index of the model at canonical position ``c``.

    Args:
        bank: a tuple of :class:`~imm_gym.tracking.models.MotionModel` or a
            :class:`~imm_gym.tracking.hetero.HeteroBank`.
        velocity_noise: ``(M,)`` each linear model's RMS velocity noise per step (the last key;
            None: not used).
    """
    if isinstance(bank, tuple):
        noise = [0.0] * len(bank) if velocity_noise is None else list(velocity_noise)
        keys = [
            (KIND_RANK[m.kind], abs(m.omega), m.omega < 0.0, float(noise[j]))
            for j, m in enumerate(bank)
        ]
    else:
        scales = bank.q_scale or (1.0,) * len(bank.models)
        keys = [
            (KIND_RANK[kind], 0.0, False, float(scales[j])) for j, kind in enumerate(bank.models)
        ]
    return np.array(sorted(range(len(keys)), key=lambda j: keys[j]), dtype=np.intp)


def model_roles(bank: Any, order: str = "bank") -> tuple[str, ...]:
    """What each model of ``bank`` stands for, in ``order`` (``EnvConfig.model_order``): its kind,
    and for a CT model of a linear bank the sense of its turn (``"CT(+)"``, ``"CT(−)"``) — what a
    policy trained on one bank reads each per-model entry as."""
    if isinstance(bank, tuple):
        roles = [
            m.kind.upper() + ("" if m.kind != "ct" else "(+)" if m.omega > 0.0 else "(−)")
            for m in bank
        ]
    else:
        roles = [kind.upper() for kind in bank.models]
    ranks = canonical_order(bank) if order == "canonical" else range(len(roles))
    return tuple(roles[j] for j in ranks)


def block_index(models: str, order: Index, size: int, dim_z: int) -> Index:
    """The positions of one observation block of ``size`` entries whose entries are per model
    as ``models`` says (:class:`~imm_gym.sim.features.Feature`), read in canonical order."""
    M = len(order)
    if models == "":
        return np.arange(size)
    if models == "M":
        return order.copy()
    if models == "kM":
        return (np.arange(size // M)[:, None] * M + order[None, :]).ravel()
    if models == "Mm":
        return (order[:, None] * dim_z + np.arange(dim_z)[None, :]).ravel()
    if models == "MM":
        return (order[:, None] * M + order[None, :]).ravel()
    raise ValueError(f"unknown per-model layout {models!r}")


def observation_index(features: Sequence[str], order: Index, dim_z: int) -> Index:
    """``idx`` with ``obs[:, idx]`` the observation ``[μ(t), μ(t−1)]`` + the blocks of
    ``features`` (:mod:`imm_gym.sim.core`) with its models in canonical ``order``."""
    M = len(order)
    parts = [order, M + order]
    offset = 2 * M
    for name in features:
        f = FEATURES[name]
        size = f.size(M, dim_z)
        parts.append(offset + block_index(f.models, order, size, dim_z))
        offset += size
    return np.concatenate(parts).astype(np.intp)


def action_index(action_size: int, order: Index) -> Index:
    """``idx`` with ``action[:, idx]`` in the bank's order for an action (one entry per model,
    or an ``M x M`` matrix row-major) written in canonical ``order``."""
    M = len(order)
    inverse = np.argsort(order).astype(np.intp)
    if action_size == M:
        return inverse
    return (inverse[:, None] * M + inverse[None, :]).ravel()


def critic_index(size: int, order: Index) -> Index:
    """``idx`` reordering :meth:`~imm_gym.sim.core.TrackingCore.critic_state` (the errors, then
    the coming model one-hot in its last ``M`` entries) to canonical ``order``."""
    M = len(order)
    return np.concatenate([np.arange(size - M), size - M + order]).astype(np.intp)


def frame_layout(features: Sequence[str], n_models: int, dim_z: int) -> tuple[Index, Index]:
    """Where each model's entries and the shared ones are in one observation frame
    ``[μ(t), μ(t−1)]`` + the blocks of ``features``: ``(per_model, shared)``, ``per_model[j]``
    the positions of model ``j``'s entries (the same feature entry in the same column for every
    model), ``shared`` those of no model. A network that reads ``obs[per_model[j]]`` with
    ``obs[shared]`` through weights shared by the models reads a bank of any size
    (:mod:`agents.per_model`).

    Raises:
        ValueError: a block is an ``M x M`` matrix (``models="MM"``, the TPM): its entries are
            per pair of models, not per model.
    """
    M = n_models
    per_model = [np.arange(M)[:, None], M + np.arange(M)[:, None]]
    shared = []
    offset = 2 * M
    for name in features:
        f = FEATURES[name]
        size = f.size(M, dim_z)
        if f.models == "MM":
            raise ValueError(f"feature {name!r} is per pair of models, not per model")
        if f.models == "":
            shared.append(offset + np.arange(size))
        else:
            block = offset + block_index(f.models, np.arange(M), size, dim_z)
            if f.models == "kM":
                per_model.append(block.reshape(size // M, M).T)
            else:
                per_model.append(block.reshape(M, size // M))
        offset += size
    return (
        np.concatenate(per_model, axis=1).astype(np.intp),
        np.concatenate(shared or [np.zeros(0)]).astype(np.intp),
    )


def for_bank(policy: Any, n_models: int) -> Any:
    """``policy`` for a bank of ``n_models`` models: a learned policy whose network is shared by
    the models rebuilt for that many (its ``for_models``, :mod:`agents.per_model`); any other
    policy as it is (a network that reads models by position is refused on another bank by the
    size of what it reads)."""
    for_models = getattr(policy, "for_models", None)
    return policy if for_models is None else for_models(n_models)
