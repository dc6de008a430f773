"""The natively batched Gymnasium vector environment: :class:`TPMAdaptVectorEnv`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

from imm_gym.sim.actions import ActionError
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig


class TPMAdaptVectorEnv(VectorEnv):
    """N TPM-adaptation episodes in one batched core (see :class:`TPMAdaptEnv` for the MDP).

    Sub-env ``i`` owns its random streams: ``reset(seed=s)`` gives sub-env ``i`` the seed
    ``s + i`` (or ``seed[i]`` for a list), so it replays a scalar ``TPMAdaptEnv`` reset with that
    seed, including the later episodes of its autoresets. Autoreset mode ``NEXT_STEP``: the step
    after an episode ends resets that sub-env and returns its first observation with reward 0
    (its action is ignored). Infos are dicts of arrays with ``_key`` masks.
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        config: EnvConfig | Mapping[str, Any] | None = None,
        render_mode: str | None = None,
        **kwargs: Any,
    ) -> None:
        if render_mode is not None:
            raise ValueError(f"no render modes, got render_mode={render_mode!r}")
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        self.config = EnvConfig.build(config, **kwargs)
        self.num_envs = num_envs
        self.core = TrackingCore(self.config, n_envs=num_envs)
        self.single_observation_space = spaces.Box(
            self.core.obs_low, self.core.obs_high, dtype=np.float32
        )
        self.single_action_space = spaces.Box(-1.0, 1.0, (self.core.action_dim,), dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._autoreset = np.zeros(num_envs, dtype=bool)

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        super().reset(seed=seed if isinstance(seed, int) or seed is None else None)
        N = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * N
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(N)]
        else:
            seeds = list(seed)
            if len(seeds) != N:
                raise ValueError(f"seed list must have {N} entries, got {len(seeds)}")
        self.core.reset(np.arange(N), seeds)
        self._autoreset[:] = False
        return self.core.observe(), {}

    def step(
        self, actions: NDArray[Any]
    ) -> tuple[
        NDArray[np.float32],
        NDArray[np.float64],
        NDArray[np.bool_],
        NDArray[np.bool_],
        dict[str, Any],
    ]:
        a = np.asarray(actions)
        if a.shape != (self.num_envs, self.core.action_dim):
            raise ActionError(
                f"actions must have shape ({self.num_envs}, {self.core.action_dim}), got {a.shape}"
            )
        restart = self._autoreset
        if restart.any():
            self.core.validate_action(a)  # a rejected action must not consume the autoresets
            self.core.reset(np.flatnonzero(restart), [None] * int(restart.sum()))
        result = self.core.step(a, active=~restart)
        obs, reward = result.obs, result.reward
        terminated, truncated = result.terminated, result.truncated
        if restart.any():
            reward[restart] = 0.0
            terminated[restart] = False
            truncated[restart] = False
        info: dict[str, Any] = {}
        stepped = ~restart
        for key, value in result.info.items():
            info[key] = value
            info[f"_{key}"] = stepped.copy()
        self._autoreset = terminated | truncated
        return obs, reward, terminated, truncated, info
