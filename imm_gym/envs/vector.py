"""The natively batched Gymnasium vector environment: :class:`TPMAdaptVectorEnv`."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

from imm_gym.envs.render import CoreRenderer, scenario_title
from imm_gym.sim.actions import ActionError
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.render import RENDER_FPS
from imm_gym.validation import ConfigError


class TPMAdaptVectorEnv(VectorEnv):
    """N TPM-adaptation episodes in one batched core (see :class:`TPMAdaptEnv` for the MDP and
    the configuration's arguments: ``config``, ``preset``, keyword fields).

    Sub-env ``i`` owns its random streams: ``reset(seed=s)`` gives sub-env ``i`` the seed
    ``s + i`` (or ``seed[i]`` for a sequence of ``num_envs`` seeds, each None or a non-negative
    integer; None: it continues its streams), so it replays a scalar ``TPMAdaptEnv`` reset with
    that seed, including the later episodes of its autoresets. Any other seed (a float, a
    string, a bool, a negative integer, a sequence of another length) raises ``ValueError``
    naming ``seed`` before any sub-env is reset. Autoreset mode ``NEXT_STEP``: the step
    after an episode ends resets that sub-env and returns its first observation with reward 0.
    Its row of ``actions`` is not applied, whatever finite values it holds, but it is checked
    with the others (where Gymnasium's ``SyncVectorEnv`` does not look at it): a NaN or inf
    there raises ``ActionError`` as anywhere, and then no sub-env steps or resets (the autoreset
    is still due at the next step). Infos are dicts of arrays with ``_key`` masks, as Gymnasium's
    ``SyncVectorEnv`` over :class:`TPMAdaptEnv` gives them: ``reset`` gives the scalar env's
    reset info (``true_state``, ``tpm``) of the sub-envs it resets; ``step`` the scalar env's
    step info of the sub-envs that stepped, and for a sub-env that autoresets its new
    episode's reset info (``true_state``, ``tpm``), its other keys masked False (a key is absent
    where no sub-env gives it). Entries whose mask is False are meaningless.

    ``render_mode="rgb_array"``: ``render()`` returns a tuple of frames, one per sub-env of
    ``render_envs`` (indices, read once from any iterable, at least one; default: all of them,
    as Gymnasium's vector envs do; ``render_envs=[0]`` draws sub-env 0 only, a picture costs
    milliseconds), each the picture :class:`~imm_gym.envs.tpm_adapt.TPMAdaptEnv` draws. For a
    window, wrap the env in ``gymnasium.wrappers.vector.HumanRendering`` (which tiles a frame per
    sub-env: leave ``render_envs`` at all of them) or use the scalar env's ``"human"`` mode.
    """

    metadata = {
        "render_modes": ["rgb_array"],
        "render_fps": RENDER_FPS,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        config: EnvConfig | Mapping[str, Any] | None = None,
        render_mode: str | None = None,
        render_envs: Iterable[int] | None = None,
        preset: Mapping[str, Any] | None = None,
        **kwargs: Any,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, "
                f"got {render_mode!r}"
            )
        if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        num_envs = int(num_envs)
        envs = _render_envs(render_envs, num_envs)
        self.config = EnvConfig.build(config, preset, **kwargs)
        self.num_envs = num_envs
        self.core = TrackingCore(self.config, n_envs=num_envs)
        self.single_observation_space = spaces.Box(
            self.core.obs_low, self.core.obs_high, dtype=np.float32
        )
        self.single_action_space = spaces.Box(-1.0, 1.0, (self.core.action_dim,), dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._autoreset = np.zeros(num_envs, dtype=bool)
        self.render_mode = render_mode
        self.render_envs = envs
        self._renderer = (
            None
            if render_mode is None
            else CoreRenderer(
                self.core, title=scenario_title(self.config.scenario) + ", sub-env {slot}"
            )
        )

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        seeds = _sub_env_seeds(seed, self.num_envs)
        super().reset(seed=seeds[0] if _is_seed(seed) else None)
        N = self.num_envs
        slots = _masked_slots(options or {}, N)
        self.core.reset(slots, [seeds[i] for i in slots])
        self._autoreset[slots] = False
        if self._renderer is not None:
            self._renderer.start(slots)
        info: dict[str, Any] = {}
        self._add_reset_info(info, slots, self.core.reset_info(slots))
        return self.core.observe(), info

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
        restarted = np.flatnonzero(restart)
        if restarted.size:
            self.core.validate_action(a)  # a rejected action must not consume the autoresets
            self.core.reset(restarted, [None] * restarted.size)
            first = self.core.reset_info(restarted)
        result = self.core.step(a, active=~restart)
        if self._renderer is not None:
            self._renderer.start(np.flatnonzero(restart))
            self._renderer.record(result.info, ~restart)
        obs, reward = result.obs, result.reward
        terminated, truncated = result.terminated, result.truncated
        if restart.any():
            reward[restart] = 0.0
            terminated[restart] = False
            truncated[restart] = False
        info: dict[str, Any] = {}
        stepped = ~restart
        if restarted.size < self.num_envs:  # a key only where some sub-env gives it
            for key, value in result.info.items():
                info[key] = value
                info[f"_{key}"] = stepped.copy()
        if restarted.size:  # the new episodes' reset info, as the scalar env's reset gives it
            self._add_reset_info(info, restarted, first)
        self._autoreset = terminated | truncated
        return obs, reward, terminated, truncated, info

    def _add_reset_info(
        self, info: dict[str, Any], slots: NDArray[np.int64], first: dict[str, NDArray[Any]]
    ) -> None:
        """Put the reset info ``first`` of the sub-envs ``slots`` (the core's
        :meth:`~imm_gym.sim.core.TrackingCore.reset_info`, what :meth:`TPMAdaptEnv.reset
        <imm_gym.envs.tpm_adapt.TPMAdaptEnv.reset>` gives) into ``info``, their masks set, as
        Gymnasium's ``SyncVectorEnv`` adds a sub-env's info: arrays of zeros where a key is
        new."""
        N = self.num_envs
        for key, value in first.items():
            if key not in info:
                info[key] = np.zeros((N, *value.shape[1:]), dtype=value.dtype)
                info[f"_{key}"] = np.zeros(N, dtype=bool)
            info[key][slots] = value
            info[f"_{key}"][slots] = True

    def render(self) -> tuple[NDArray[np.uint8], ...] | None:
        """The pictures of the sub-envs ``render_envs`` (all by default, as Gymnasium's
        ``SyncVectorEnv`` returns them): a tuple of ``(H, W, 3)`` ``uint8`` frames, drawn as
        :meth:`TPMAdaptEnv.render <imm_gym.envs.tpm_adapt.TPMAdaptEnv.render>` draws one."""
        if self._renderer is None:
            gym.logger.warn(
                "render() called without a render mode: make the env with "
                "render_mode='rgb_array'"
            )
            return None
        return tuple(self._renderer.frame(i) for i in self.render_envs)

    def close_extras(self, **kwargs: Any) -> None:
        """Release the render figure, if any (none if the constructor failed before it)."""
        renderer = getattr(self, "_renderer", None)
        if renderer is not None:
            renderer.close()


def _is_seed(value: Any) -> bool:
    """An integer seed (a bool is not one); its sign is checked where it is used."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _sub_env_seeds(seed: Any, num_envs: int) -> list[int | None]:
    """Each sub-env's seed: None for every one, ``seed + i`` for an integer, or the entries of a
    sequence of ``num_envs`` seeds (each None or a non-negative integer).

    Raises:
        ValueError: naming ``seed`` and what it may be.
    """
    allowed = (
        f"None, a non-negative integer (sub-env i gets seed + i) or a sequence of {num_envs} "
        "seeds, one per sub-env, each None or a non-negative integer"
    )
    if seed is None:
        return [None] * num_envs
    if _is_seed(seed):
        if seed < 0:
            raise ValueError(f"seed must be {allowed}; got {seed!r}")
        return [int(seed) + i for i in range(num_envs)]
    if isinstance(seed, (str, bytes)) or not (
        isinstance(seed, Sequence) or (isinstance(seed, np.ndarray) and seed.ndim == 1)
    ):
        raise ValueError(f"seed must be {allowed}; got {seed!r}")
    seeds = list(seed)
    if len(seeds) != num_envs:
        raise ValueError(f"seed must be {allowed}; got a sequence of {len(seeds)} entries")
    for i, s in enumerate(seeds):
        if s is not None and not (_is_seed(s) and s >= 0):
            raise ValueError(f"seed[{i}] must be None or a non-negative integer, got {s!r}")
    return [None if s is None else int(s) for s in seeds]


def _render_envs(render_envs: Any, num_envs: int) -> tuple[int, ...]:
    """The sub-envs ``render_envs`` selects, read once (a generator is one): all of them for
    None, else its indices in ``[0, num_envs)`` (integers, numpy's too, not bools).

    Raises:
        ConfigError: naming ``render_envs``, for a selection of no sub-env or an entry that is no
            such index.
    """
    if render_envs is None:
        return tuple(range(num_envs))
    allowed = f"indices in [0, {num_envs})"
    try:
        envs = tuple(render_envs)
    except TypeError:
        raise ConfigError(f"render_envs must be {allowed}, got {render_envs!r}") from None
    if not envs:
        raise ConfigError("render_envs must select at least one sub-env (None: all), got none")
    if not all(
        isinstance(i, (int, np.integer)) and not isinstance(i, bool) and 0 <= i < num_envs
        for i in envs
    ):
        raise ConfigError(f"render_envs must be {allowed}, got {envs!r}")
    return tuple(int(i) for i in envs)


def _masked_slots(options: Mapping[str, Any], num_envs: int) -> NDArray[np.int64]:
    """The sub-envs ``options["reset_mask"]`` selects (all of them without the key), checked as
    Gymnasium's ``SyncVectorEnv`` checks it: a boolean array of ``num_envs`` entries, one true."""
    if "reset_mask" not in options:
        return np.arange(num_envs)
    mask = options["reset_mask"]
    if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_:
        raise TypeError(
            f"options['reset_mask'] must be a numpy array of dtype bool, got {type(mask).__name__}"
            + (f" of dtype {mask.dtype}" if isinstance(mask, np.ndarray) else "")
        )
    if mask.shape != (num_envs,):
        raise ValueError(
            f"options['reset_mask'] must have shape ({num_envs},), got {mask.shape}"
        )
    if not mask.any():
        raise ValueError("options['reset_mask'] must select at least one sub-env (all False)")
    return np.flatnonzero(mask)
