"""Training across trackers: the slots of one batch split among several configurations.

A :class:`MixtureCore` runs a :class:`~imm_gym.sim.core.TrackingCore` per configuration, each on
its share of the N slots (slots ``starts[p] .. starts[p+1]-1`` are part ``p``'s), and presents
them as one core: one observation and action space, one step. The parts may differ in their
tracker (sensor, bank, filter, TPM), their targets and conditions (scenario, family, ``vary``),
their initiation and their reward; what the policy reads and writes must be the same
(:data:`POLICY_FIELDS`), so that one network serves every part and the agent's recorded settings
(the first part's) are those it was trained with. ``vary`` draws conditions per episode within
one bank; a mixture also spans banks (the paper's per-step noise beside a physically scaled one,
say).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from fractions import Fraction
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.actions import validate_action
from imm_gym.sim.core import StepResult, TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.model_order import model_roles
from imm_gym.validation import ConfigError, shown

#: The fields every part of a mixture must share: the observation (its blocks and the models
#: they are per), the action's meaning and the banks a feature reads.
POLICY_FIELDS = (
    "obs_features",
    "model_order",
    "action_mode",
    "stay_base",
    "detector_share",
    "detector",
    "detector_weights",
    "stay_grid",
    "max_factor",
    "logit_scale",
    "p_min",
    "parallel",
    "shadow",
    "shadow_stay",
    "loglik_clip",
)
#: What an agent is trained as: :data:`POLICY_FIELDS` and what it is rewarded for. A
#: hyperparameter entry's ``env_kwargs`` keep only these under ``train.py --env-config`` (the
#: files give the trackers and targets).
AGENT_FIELDS = (
    *POLICY_FIELDS, "reward", "reward_scale", "tpm_cost", "tpm_change_cost", "mode_reward",
    "mode_score",
)

#: The largest denominator of a share in :func:`slot_counts` (the shares are taken as the nearest
#: fractions with at most it, so that the float rounding of ``1 - sum(shares)`` breaks no tie).
SHARE_DENOMINATOR = 10**9


def check_mixture(
    where: str, parts: Any
) -> tuple[list[dict[str, Any]], list[float]]:
    """The further parts of a mixture, ``[{"env_kwargs": {...}, "share": w}, ...]``, checked: each
    part's EnvConfig fields and its share of the slots (the main configuration keeps
    ``1 - sum(w)``, so the shares are in (0, 1) and sum below 1).

    Raises:
        ConfigError: naming ``where``, the part and the key.
    """
    if not isinstance(parts, (list, tuple)) or not parts:
        raise ConfigError(
            f"{where} must be a non-empty list of {{env_kwargs, share}}, got {shown(parts)}"
        )
    kwargs, shares = [], []
    for i, part in enumerate(parts):
        if not isinstance(part, Mapping) or set(part) != {"env_kwargs", "share"}:
            raise ConfigError(
                f"{where}[{i}] must be a mapping with the keys env_kwargs and share, got "
                f"{shown(part)}"
            )
        if not isinstance(part["env_kwargs"], Mapping):
            raise ConfigError(f"{where}[{i}].env_kwargs must be a mapping of EnvConfig fields")
        share = part["share"]
        if isinstance(share, bool) or not isinstance(share, (int, float)) or not 0 < share < 1:
            raise ConfigError(f"{where}[{i}].share must be a number in (0, 1), got {shown(share)}")
        kwargs.append(dict(part["env_kwargs"]))
        shares.append(float(share))
    if not sum(shares) < 1.0:
        raise ConfigError(
            f"{where}: the shares {shares} sum to {sum(shares):g}; they must leave the main "
            "configuration a share (sum < 1)"
        )
    return kwargs, shares


def check_parts(configs: Sequence[EnvConfig]) -> None:
    """Raise :class:`ConfigError` where a part differs from the first in a field of
    :data:`POLICY_FIELDS` or in its number of models (the policy's spaces), or lists the same
    models as the first (kind, and a CT model's sense of turn: :func:`model_roles`, in the
    configuration's ``model_order``) in another order: entry ``j`` of the observation and the
    action would be, say, CV in one part and CT(−) in the other. Parts of other models (a CA model
    beside CT ones) have no common order to keep: a policy reading them tells them apart by
    their per-model features."""
    first = configs[0]
    order = first.model_order
    for p, config in enumerate(configs[1:], start=1):
        differ = [f for f in POLICY_FIELDS if getattr(config, f) != getattr(first, f)]
        if len(config.bank) != len(first.bank):
            differ.append(f"bank size ({len(config.bank)} models, not {len(first.bank)})")
        if differ:
            raise ConfigError(
                f"mixture part {p} differs from part 0 in {differ}: the parts of a mixture "
                f"share what the policy reads and writes ({', '.join(POLICY_FIELDS)})"
            )
        roles, first_roles = model_roles(config.bank, order), model_roles(first.bank, order)
        if sorted(roles) == sorted(first_roles) and roles != first_roles:
            raise ConfigError(
                f"mixture part {p} gives its models the entries {list(roles)}, part 0 "
                f"{list(first_roles)} (model_order {order}): list them so that each entry is "
                "the same kind of model in every part"
            )


def slot_counts(shares: Sequence[float], n_envs: int) -> list[int]:
    """The slots of each part: ``n_envs`` split in proportion to ``shares`` (positive weights)
    by largest remainders, ties to the earlier part. The arithmetic is exact, on each share as
    the nearest fraction of denominator at most :data:`SHARE_DENOMINATOR` (``1 - 0.55`` is
    0.44999999999999996 in floating point, 9/20 here: 30 slots split 9:11 are 14 and 16).

    Raises:
        ConfigError: a share that is not positive and finite, or one that gets no slot.
    """
    w = np.asarray(shares, dtype=np.float64)
    if w.ndim != 1 or w.size == 0 or not np.all(np.isfinite(w) & (w > 0.0)):
        raise ConfigError(f"mixture shares must be positive numbers, got {list(shares)}")
    weights = [Fraction(float(x)).limit_denominator(SHARE_DENOMINATOR) or Fraction(float(x))
               for x in w]
    exact = [x * n_envs / sum(weights) for x in weights]
    counts = np.array([math.floor(x) for x in exact], dtype=int)
    order = sorted(range(len(exact)), key=lambda i: -(exact[i] - counts[i]))  # stable: ties
    counts[order[: n_envs - int(counts.sum())]] += 1
    if np.any(counts == 0):
        raise ConfigError(
            f"mixture shares {list(shares)} of {n_envs} slots leave part "
            f"{int(np.flatnonzero(counts == 0)[0])} without a slot; give more slots (n_envs) "
            "or a larger share"
        )
    return counts.tolist()


class MixtureCore:
    """N slots split among the cores of several configurations (module docstring).

    Args:
        configs: the parts' configurations; the first is the mixture's :attr:`config` (what an
            agent trained on it records).
        shares: each part's weight (positive; normalized).
        n_envs: the number of slots N.

    Raises:
        ConfigError: the parts differ in a field of :data:`POLICY_FIELDS` or in the number of
            models, or a share gets no slot.
    """

    def __init__(self, configs: Sequence[EnvConfig], shares: Sequence[float], n_envs: int) -> None:
        if len(configs) != len(shares):
            raise ConfigError(f"{len(configs)} mixture configurations for {len(shares)} shares")
        check_parts(configs)
        counts = slot_counts(shares, n_envs)
        self.cores = [TrackingCore(c, n) for c, n in zip(configs, counts, strict=True)]
        #: first slot of each part, and N at the end
        self.starts = np.concatenate([[0], np.cumsum(counts)])
        self.config = configs[0]
        self.n_envs = n_envs
        core = self.cores[0]
        self.M, self.action_dim = core.M, core.action_dim
        self.obs_low, self.obs_high, self.obs_dim = core.obs_low, core.obs_high, core.obs_dim

    @classmethod
    def of(
        cls,
        config: EnvConfig,
        mixture: Sequence[Mapping[str, Any]],
        preset: Mapping[str, Any],
        n_envs: int,
        where: str = "env_mixture",
    ) -> MixtureCore:
        """The mixture of ``config`` and the further parts ``mixture`` (a hyperparameter entry's
        ``env_mixture``, checked by :func:`check_mixture` and named ``where`` in its errors; each
        part's fields over ``preset``); ``config`` keeps ``1 - sum(shares)`` of the slots."""
        parts, shares = check_mixture(where, mixture)
        others = [EnvConfig.build({**preset, **part}) for part in parts]
        return cls([config, *others], [1.0 - sum(shares), *shares], n_envs)

    def _parts(self, indices: NDArray[np.int64]) -> list[tuple[TrackingCore, NDArray[np.bool_]]]:
        """Each core with the mask of ``indices`` that are its slots.

        Raises:
            ValueError: an index outside ``[0, N)`` (it would be no part's and be left out).
        """
        outside = indices[(indices < 0) | (indices >= self.n_envs)]
        if outside.size:
            raise ValueError(
                f"slot indices {outside.tolist()} outside [0, {self.n_envs}): the mixture has "
                f"{self.n_envs} slots"
            )
        return [
            (core, (indices >= lo) & (indices < hi))
            for core, lo, hi in zip(self.cores, self.starts[:-1], self.starts[1:], strict=True)
        ]

    def reset(self, indices: NDArray[np.int64], seeds: list[int | None]) -> None:
        """:meth:`TrackingCore.reset` of the slots ``indices``, each by its part.

        Raises:
            ValueError: an index outside ``[0, N)``, or not one seed per index.
        """
        indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        if len(seeds) != indices.size:
            raise ValueError(f"{len(seeds)} seeds for {indices.size} slots")
        for p, (core, mine) in enumerate(self._parts(indices)):
            if np.count_nonzero(mine):
                chosen = [s for s, m in zip(seeds, mine, strict=True) if m]
                core.reset(indices[mine] - self.starts[p], chosen)

    def reset_info(self, indices: NDArray[np.int64]) -> dict[str, NDArray[Any]]:
        """:meth:`TrackingCore.reset_info` of the slots ``indices``, each row by its part.

        Raises:
            ValueError: an index outside ``[0, N)``.
        """
        indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        info: dict[str, NDArray[Any]] = {}
        for p, (core, mine) in enumerate(self._parts(indices)):
            if np.count_nonzero(mine):
                for key, value in core.reset_info(indices[mine] - self.starts[p]).items():
                    if key not in info:
                        info[key] = np.zeros((indices.size, *value.shape[1:]), value.dtype)
                    info[key][mine] = value
        return info

    def validate_action(self, action: NDArray[Any]) -> NDArray[Any]:
        """``action`` checked as a whole (shape ``(N, action_dim)``, finite), then each part's
        :meth:`TrackingCore.validate_action` on its slots' actions."""
        action = validate_action(action, self.n_envs, self.action_dim)
        parts = [
            core.validate_action(action[self.starts[p] : self.starts[p + 1]])
            for p, core in enumerate(self.cores)
        ]
        return np.concatenate(parts)

    def step(self, action: NDArray[Any], active: NDArray[np.bool_] | None = None) -> StepResult:
        """Every part's step on its slots' actions; the results concatenated in slot order (the
        info keys every part gives, each cut to the leading block every part has: a bank with a
        CA model estimates a 6-d state, whose first four entries — position and velocity — are
        those of a bank without one). The whole step is checked before any part steps: a
        rejected action (``ActionError``) or an ended episode among the active slots
        (``RuntimeError``) leaves every slot as it was."""
        action = np.asarray(action)
        self.validate_action(action)
        done = np.concatenate([core.done for core in self.cores])
        if active is not None:
            done &= np.asarray(active, dtype=bool)
        if np.count_nonzero(done):
            raise RuntimeError(
                f"episodes in slots {np.flatnonzero(done).tolist()} have ended; call reset "
                "before step"
            )
        results = []
        for p, core in enumerate(self.cores):
            part = slice(self.starts[p], self.starts[p + 1])
            results.append(core.step(action[part], None if active is None else active[part]))
        keys = [k for k in results[0].info if all(k in r.info for r in results[1:])]
        return StepResult(
            np.concatenate([r.obs for r in results]),
            np.concatenate([r.reward for r in results]),
            np.concatenate([r.terminated for r in results]),
            np.concatenate([r.truncated for r in results]),
            {k: _concatenate_leading([np.asarray(r.info[k]) for r in results]) for k in keys},
        )

    def observe(self) -> NDArray[np.float32]:
        return np.concatenate([core.observe() for core in self.cores])

    def critic_state(self) -> NDArray[np.float32]:
        return np.concatenate([core.critic_state() for core in self.cores])

    def streams(self) -> list[tuple[np.random.Generator, np.random.Generator] | None]:
        return [pair for core in self.cores for pair in core.streams()]

    def set_streams(
        self, generators: list[tuple[np.random.Generator, np.random.Generator]]
    ) -> None:
        if len(generators) != self.n_envs:
            raise ValueError(f"{len(generators)} stream pairs for {self.n_envs} slots")
        for p, core in enumerate(self.cores):
            core.set_streams(list(generators[self.starts[p] : self.starts[p + 1]]))


def _concatenate_leading(arrays: Sequence[NDArray[Any]]) -> NDArray[Any]:
    """The arrays concatenated along the slots, each cut to the smallest size of every further
    axis (the leading block, e.g. position and velocity of estimates of 4 and 6 entries)."""
    if all(a.shape[1:] == arrays[0].shape[1:] for a in arrays[1:]):
        return np.concatenate(arrays)
    common = tuple(slice(min(a.shape[i] for a in arrays)) for i in range(1, arrays[0].ndim))
    return np.concatenate([a[(slice(None), *common)] for a in arrays])
