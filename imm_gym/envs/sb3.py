"""stable-baselines3 ``VecEnv`` over the batched core: :class:`TPMAdaptSB3VecEnv`.

SB3 conventions: same-step reset (a finished episode is reset inside ``step_wait``, its last
observation goes to ``info["terminal_observation"]``), ``info["TimeLimit.truncated"]`` for a
truncation, ``dones = terminated | truncated``, fresh arrays every step. Actions have shape
``(num_envs, action_dim)`` (``M*M`` entries, one per TPM entry, or ``M`` in the stay modes, one
stay per model); another shape or a NaN/inf entry raises
:class:`~imm_gym.sim.actions.ActionError`, as in the Gymnasium fronts. ``seed(s)`` seeds the
next ``reset`` with ``s + i`` per sub-env, like the Gymnasium vector env.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from imm_gym.sim.actions import ActionError
from imm_gym.sim.core import CRITIC_CLIP, TrackingCore, critic_state_size
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.mixture import MixtureCore

#: Per-step diagnostics copied into each sub-env's info dict (the rest stays in the core).
SB3_INFO_KEYS = (
    "position_error",
    "shadow_position_error",
    "reward_error",
    "reward_advantage",
    "reward_squared_advantage",
    "stay_bank_position_error",
    "reward_bank_advantage",
    "diverged",
)


class TPMAdaptSB3VecEnv(VecEnv):
    """N TPM-adaptation episodes for stable-baselines3 (see :class:`TPMAdaptEnv` for the MDP).

    Args:
        num_envs: number of sub-environments.
        config: an :class:`EnvConfig` or a mapping; keyword arguments override fields.
        env_id: take the preset of a registered id (``"imm_gym/TPMAdapt-v0"``) as the base
            config; a ``config`` mapping updates it, an :class:`EnvConfig` replaces it.
        critic_state: append :meth:`~imm_gym.sim.core.TrackingCore.critic_state` (ground truth) to
            every observation, for an asymmetric actor-critic whose actor does not read it
            (:class:`agents.asymmetric.AsymmetricActorCriticPolicy`).
        mixture: training across trackers: further configurations, each ``{"env_kwargs":
            EnvConfig fields over the preset of env_id, "share": weight}``, that take their
            share of the slots (:class:`~imm_gym.sim.mixture.MixtureCore`); ``config`` keeps
            ``1 - sum(shares)`` of them (the shares must leave it some).
    """

    def __init__(
        self,
        num_envs: int = 1,
        config: EnvConfig | Mapping[str, Any] | None = None,
        env_id: str | None = None,
        critic_state: bool = False,
        mixture: Sequence[Mapping[str, Any]] = (),
        **kwargs: Any,
    ) -> None:
        preset: dict[str, Any] = {}
        if env_id is not None:
            preset = dict(gym.spec(env_id).kwargs.get("preset") or {})
        self.config = EnvConfig.build(config, preset, **kwargs)
        self.core: TrackingCore | MixtureCore
        if mixture:
            self.core = MixtureCore.of(self.config, mixture, preset, num_envs, "mixture")
        else:
            self.core = TrackingCore(self.config, n_envs=num_envs)
        self.critic_state = critic_state
        low, high = self.core.obs_low, self.core.obs_high
        if critic_state:
            extra = np.full(critic_state_size(self.core.M), CRITIC_CLIP, dtype=np.float32)
            low, high = np.concatenate([low, -extra]), np.concatenate([high, extra])
        observation_space = spaces.Box(low, high, dtype=np.float32)
        action_space = spaces.Box(-1.0, 1.0, (self.core.action_dim,), dtype=np.float32)
        self.render_mode = None
        super().__init__(num_envs, observation_space, action_space)
        self._actions: NDArray[Any] | None = None

    def reset(self) -> NDArray[np.float32]:
        self.core.reset(np.arange(self.num_envs), list(self._seeds))
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return self._with_critic_state(self.core.observe())

    def _with_critic_state(self, obs: NDArray[np.float32]) -> NDArray[np.float32]:
        if self.critic_state:
            return np.concatenate([obs, self.core.critic_state()], axis=-1)
        return obs

    def step_async(self, actions: NDArray[Any]) -> None:
        """Take ``(num_envs, action_dim)`` actions (``M*M``, or ``M`` in the stay modes); any
        other shape raises ``ActionError`` (never reshaped: an ``(action_dim, num_envs)`` array
        is not the same actions)."""
        a = np.asarray(actions)
        if a.shape != (self.num_envs, self.core.action_dim):
            raise ActionError(
                f"actions must have shape ({self.num_envs}, {self.core.action_dim}), got {a.shape}"
            )
        self._actions = a

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait called without step_async")
        a = self._actions
        self._actions = None
        result = self.core.step(a)
        obs = self._with_critic_state(result.obs)
        dones = result.terminated | result.truncated
        keys = [key for key in SB3_INFO_KEYS if key in result.info]
        columns = [result.info[key].tolist() for key in keys]  # Python scalars, column by column
        infos: list[dict[str, Any]] = [
            dict(zip(keys, row, strict=True)) for row in zip(*columns, strict=True)
        ]
        finished = np.flatnonzero(dones)
        if finished.size:
            for i in finished:
                infos[i]["terminal_observation"] = obs[i].copy()
                infos[i]["TimeLimit.truncated"] = bool(
                    result.truncated[i] and not result.terminated[i]
                )
            self.core.reset(finished, [None] * finished.size)
            obs = self._with_critic_state(self.core.observe())
        return obs, result.reward.astype(np.float32), dones, infos

    def close(self) -> None:
        """Nothing to release."""

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The adapter's attribute for every index asked; ``config`` of a mixture is each slot's
        part's configuration (the others are shared by every sub-env)."""
        targets = list(self._get_indices(indices))
        if attr_name == "config" and isinstance(self.core, MixtureCore):
            slots = np.asarray(targets, dtype=np.int64).reshape(-1)
            if np.any((slots < 0) | (slots >= self.num_envs)):
                raise IndexError(f"indices {targets} outside [0, {self.num_envs})")
            parts = np.searchsorted(self.core.starts, slots, side="right") - 1
            return [self.core.cores[p].config for p in parts]
        return [getattr(self, attr_name) for _ in targets]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        raise AttributeError(f"TPMAdaptSB3VecEnv sub-envs share one core; cannot set {attr_name!r}")

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **kwargs: Any
    ) -> list[Any]:
        """Call the method once: the sub-envs share one core, so a method of "each" sub-env is
        one call of the adapter's; its result is given for every index asked."""
        targets = self._get_indices(indices)
        result = getattr(self, method_name)(*method_args, **kwargs)
        return [result for _ in targets]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[NDArray[Any] | None]:
        return [None for _ in range(self.num_envs)]


#: The adapter's name before it was told apart from the Gymnasium vector env by name; kept so that
#: ``from imm_gym.envs.sb3 import TPMAdaptVecEnv`` in existing scripts still works.
TPMAdaptVecEnv = TPMAdaptSB3VecEnv
