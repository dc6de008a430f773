"""The policy protocol shared by the baselines and stable-baselines3 models.

A policy maps a batch of observations to a batch of actions:
``predict(obs, state=None, episode_start=None, deterministic=True) -> (actions, state)``, the
signature of SB3's ``BasePolicy.predict``, so one evaluation path runs every policy. Rule memory
(a window of past probabilities, say) lives in ``state``, reset where ``episode_start`` is True.
``episode_start=None`` means no episode starts, as for sb3-contrib's recurrent policies, unless
``state`` is None too (the first call: every slot starts).

A baseline also declares the environment settings it needs (``env_overrides``: the action mode,
observation features, the parallel bank...). The evaluation applies them to the common
configuration; scenario and sensor stay shared, so every policy sees the same targets and noise.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.features import feature_sizes

Obs = NDArray[np.float32]


class Policy(Protocol):
    """What :func:`imm_gym.evaluation.rollout.rollout` needs from a policy."""

    def predict(
        self,
        observation: Obs,
        state: Any = None,
        episode_start: NDArray[np.bool_] | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray[Any], Any]: ...


class Baseline:
    """Base class of the rule-based policies.

    Attributes:
        name: the policy's name in the evaluation tool (given by ``register``).
        n_models: M, the number of models of the bank.
        env_overrides: :class:`~imm_gym.EnvConfig` fields this policy needs.
    """

    name = "baseline"

    def __init__(self, n_models: int = 3) -> None:
        self.n_models = n_models
        self.env_overrides: dict[str, Any] = {}

    def predict(
        self,
        observation: Obs,
        state: Any = None,
        episode_start: NDArray[np.bool_] | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray[np.float64], Any]:
        """SB3's signature; a single observation ``(d,)`` gives a single action ``(M*M,)``.

        ``episode_start``: ``(N,)``, True where an episode starts (the rule's memory is reset
        there). ``None`` is sb3-contrib's convention for recurrent policies: no episode starts
        (the memory in ``state`` carries on), except on a first call, ``state=None``, where every
        slot starts.
        """
        obs = np.asarray(observation, dtype=np.float64)
        single = obs.ndim == 1
        obs = obs[None] if single else obs
        start = (
            np.full(obs.shape[0], state is None)
            if episode_start is None
            else np.asarray(episode_start, dtype=bool).reshape(obs.shape[0])
        )
        actions, state = self.act(obs, state, start)
        return (actions[0] if single else actions), state

    def act(
        self, obs: NDArray[np.float64], state: Any, episode_start: NDArray[np.bool_]
    ) -> tuple[NDArray[np.float64], Any]:
        """Actions ``(N, M*M)`` for observations ``(N, d)``; the rule of each baseline."""
        raise NotImplementedError

    def mode_probs(
        self, obs: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``mu(t)`` and ``mu(t-1)``: the first 2M observation entries."""
        M = self.n_models
        return obs[:, :M], obs[:, M : 2 * M]

    def feature(self, obs: NDArray[np.float64], name: str) -> NDArray[np.float64]:
        """An optional observation block by name (the policy's ``obs_features`` order)."""
        M = self.n_models
        sizes = feature_sizes(M, 2)
        start = 2 * M
        for f in self.env_overrides.get("obs_features", ()):
            if f == name:
                return obs[:, start : start + sizes[f]]
            start += sizes[f]
        raise KeyError(f"{self.name} needs the observation feature {name!r}")
