"""Monte-Carlo runs across a Ray cluster, bit for bit (``python -m imm_gym.evaluate --ray``).

The R runs of a roll-out (seeds ``seed .. seed + R - 1``) are split into C contiguous chunks,
chunk ``c`` holding runs ``start_c .. start_c + n_c - 1`` in a
:class:`~imm_gym.sim.core.TrackingCore` of ``n_c`` slots inside a Ray actor (a *shard*, spread
over the cluster's nodes). :class:`ShardedCore` stands in for the core of R slots in
:func:`~imm_gym.evaluation.rollout.rollout`: each step it sends every shard its rows of the
actions and concatenates the shards' observations, rewards, ends and infos in run order. The
policy acts where ``rollout`` runs, on the whole ``(R, ·)`` batch as in one process, so a policy
whose output depends on the batch (a network's matrix products do) still acts identically; a
slot's arithmetic does not depend on the other slots, so every number equals the
single-process roll-out's. What runs in parallel is the tracking (the IMM banks, the scenario
and noise draws), which dominates a roll-out; each step costs one round trip to the shards.

Ray is imported only by :func:`connect` and :class:`ShardPool`: the package imports and works
without it.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.actions import action_size, validate_action
from imm_gym.sim.core import StepResult, TrackingCore, checked_active, checked_reset
from imm_gym.sim.env_config import EnvConfig

CONNECT_TIMEOUT = 5.0
"""Seconds :func:`connect` waits for a ``HOST:PORT`` to accept a connection."""


class ShardError(RuntimeError):
    """A shard actor failed to start or died (its process or node ended); the message names the
    shard (its runs, once it holds some) and the cause, in one line."""


def unreachable(address: str | None, timeout: float = CONNECT_TIMEOUT) -> str | None:
    """Why nothing accepts a TCP connection at a ``HOST:PORT`` or ``ray://HOST:PORT`` address
    within ``timeout`` seconds, or None when something does or the address names no port
    (None, ``auto``, ``local``: Ray finds the cluster itself). Ray retries an address without a
    cluster for minutes before it gives up; this answers in seconds."""
    if address is None:
        return None
    hostport = address.removeprefix("ray://")
    if "://" in hostport or ":" not in hostport:
        return None
    host, _, port = hostport.rpartition(":")
    host = host.removeprefix("[").removesuffix("]")
    if not host or not port.isascii() or not port.isdigit() or not 1 <= int(port) <= 65535:
        return f"not HOST:PORT with a port in [1, 65535]: {address!r}"
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            return None
    except OSError as err:
        return f"nothing answers at {host}:{port} within {timeout:g} s ({err})"


def connect(address: str | None) -> None:
    """Join the Ray cluster at ``address`` (``auto``, ``HOST:PORT``), or with None Ray's default
    (``RAY_ADDRESS``, a running local cluster, else a new local instance); nothing if this
    process is connected already. Raises ConnectionError at once if nothing answers
    (:func:`unreachable`) at a ``HOST:PORT`` given or, for None and ``auto``, at the one Ray
    would join: ``RAY_ADDRESS`` when set and not empty, else the address the last ``ray start``
    on this machine left in Ray's temp directory (``ray_current_cluster``, which ``ray stop``
    removes)."""
    import ray

    if not ray.is_initialized():
        where, target = "", address
        if address in (None, "auto"):
            from ray._private.utils import get_ray_address_file, read_ray_address

            if os.environ.get("RAY_ADDRESS"):
                where, target = "RAY_ADDRESS: ", os.environ["RAY_ADDRESS"]
            else:
                file = get_ray_address_file(None)
                where = f"{file} (left by a `ray start`; `ray stop` removes it): "
                target = read_ray_address()
        reason = unreachable(target)
        if reason is not None:
            raise ConnectionError(where + reason)
        ray.init(address=address, include_dashboard=False, log_to_driver=False)


def chunk_sizes(runs: int, chunks: int) -> list[int]:
    """``runs`` split into at most ``chunks`` contiguous chunks differing by at most one run:
    the first ``runs mod C`` have ``floor(runs / C) + 1`` runs, the others ``floor(runs / C)``,
    ``C = min(chunks, runs)``."""
    if runs < 1 or chunks < 1:
        raise ValueError(f"runs and chunks must be >= 1, got {runs} and {chunks}")
    C = min(chunks, runs)
    return [runs // C + (1 if c < runs % C else 0) for c in range(C)]


def cause(err: Exception) -> str:
    """Why a Ray actor died, in one line: the last line of Ray's message to its first sentence
    (the exception the actor's creation raised, ``ImportError: ...``, or ``The actor is dead
    because its worker process has died``)."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    return (lines[-1].split(". ")[0] if lines else type(err).__name__).removesuffix(".")


class Shard:
    """The body of a shard actor: a :class:`TrackingCore` of the chunk's slots."""

    def __init__(self) -> None:
        self.core: TrackingCore | None = None

    def build(self, config: EnvConfig, n_envs: int) -> tuple[int, int, int]:
        """A fresh core of ``n_envs`` slots; returns its horizon, number of models and
        measurement size."""
        self.core = TrackingCore(config, n_envs=n_envs)
        return self.core.horizon, self.core.M, self.core.z.shape[-1]

    def reset(
        self,
        indices: NDArray[np.int64],
        seeds: list[int | None],
        initial_tpms: NDArray[np.float64] | None = None,
    ) -> tuple[
        NDArray[np.float64],
        NDArray[np.int64],
        NDArray[np.float64],
        NDArray[np.bool_],
        NDArray[np.float32],
    ]:
        """:meth:`TrackingCore.reset`; returns the truth, the true models, the measurements and
        their detection flags, and the observation."""
        assert self.core is not None
        self.core.reset(indices, seeds, initial_tpms)
        c = self.core
        return c.truth, c.true_model, c.z, c.detected, c.observe()

    def step(self, actions: NDArray[Any], active: NDArray[np.bool_] | None) -> StepResult:
        """:meth:`TrackingCore.step` of the chunk's slots."""
        assert self.core is not None
        return self.core.step(actions, active=active)

    def node(self) -> str:
        """The id of the Ray node this shard runs on."""
        import ray

        return ray.get_runtime_context().get_node_id()


class ShardPool:
    """Shard actors on the connected Ray cluster, reused by every roll-out of an evaluation.

    Args:
        shards: the number of actors (one CPU each, so at most the cluster's CPUs), default the
            cluster's free CPUs (at least 1: CPUs other work holds are left to it); they are
            spread over the nodes.
        start_timeout: seconds to wait for every actor to start.

    Raises:
        ValueError: ``shards`` outside ``[1, the cluster's CPUs]``.
        ShardError: an actor failed to start (its node cannot import imm_gym, say); the
            message names it and the cause, and the pool's actors are ended.
        TimeoutError: an actor did not start within ``start_timeout`` (other work holds the
            CPUs it needs, or its node is slow to start a worker); the pool's actors are ended.
    """

    def __init__(self, shards: int | None = None, start_timeout: float = 60.0) -> None:
        import ray

        cpus = int(ray.cluster_resources().get("CPU", 0))
        free = int(ray.available_resources().get("CPU", 0))
        n = max(free, 1) if shards is None else shards
        if not 1 <= n <= cpus:
            raise ValueError(f"shards must be in [1, {cpus}] (the cluster's CPUs), got {n}")
        actor = ray.remote(num_cpus=1)(Shard).options(scheduling_strategy="SPREAD")
        self.actors = [actor.remote() for _ in range(n)]
        calls = [a.node.remote() for a in self.actors]
        started, _ = ray.wait(calls, num_returns=n, timeout=start_timeout)
        for i, call in enumerate(calls):
            if call in started:  # ready: started, or failed to (its error is ready too)
                try:
                    ray.get(call)
                except ray.exceptions.RayActorError as err:
                    self.close()
                    raise ShardError(
                        f"evaluation shard {i} of {n} failed to start: {cause(err)}"
                    ) from None
        if len(started) < n:
            self.close()
            raise TimeoutError(
                f"{n - len(started)} of {n} evaluation shard(s) (one CPU each) did not start "
                f"within {start_timeout:g} s: other work holds the Ray cluster's CPUs ({free} of "
                f"{cpus} free when the shards were asked for), or a node is slow to start a worker "
                f"(its log under Ray's session directory says which)"
            )

    def core(self, config: EnvConfig, n_envs: int) -> ShardedCore:
        """A :class:`ShardedCore` of ``n_envs`` slots over the pool (the ``make_core`` of
        :func:`~imm_gym.evaluation.rollout.rollout`)."""
        return ShardedCore(self.actors, config, n_envs)

    def close(self) -> None:
        """End the actors (their CPUs return to the cluster)."""
        import ray

        for actor in self.actors:
            ray.kill(actor)
        self.actors = []

    def nodes(self) -> list[str]:
        """The node id of each actor."""
        import ray

        return ray.get([a.node.remote() for a in self.actors])


class ShardedCore:
    """A :class:`TrackingCore` of ``n_envs`` slots as contiguous chunks held by shard actors
    (module docstring): the attributes and methods :func:`~imm_gym.evaluation.rollout.rollout`
    uses (``horizon``, ``M``, ``truth``, ``true_model``, ``z``, ``detected``, ``reset``,
    ``observe``, ``step``), with the same values in the same order.

    Args:
        actors: shard actors (:class:`ShardPool`); the first ``C`` hold a chunk each.
        config: the environment configuration.
        n_envs: R, the number of slots.

    Raises:
        ShardError: a shard died (its process or node ended); the message names the shard,
            its runs and the cause.
    """

    def __init__(self, actors: list[Any], config: EnvConfig, n_envs: int) -> None:
        import ray

        self._ray = ray
        sizes = chunk_sizes(n_envs, len(actors))
        self.actors = actors[: len(sizes)]
        self.bounds = np.cumsum([0, *sizes])
        self.n_envs = n_envs
        built = self._get(
            [a.build.remote(config, n) for a, n in zip(self.actors, sizes, strict=True)],
            range(len(sizes)),
        )
        self.horizon, self.M, m = built[0]
        self.action_dim = action_size(config.action_mode, self.M)
        self.truth = np.zeros((n_envs, self.horizon + 1, 4))
        self.true_model = np.full((n_envs, self.horizon), -1, dtype=np.int64)
        self.z = np.zeros((n_envs, self.horizon + 1, m))
        self.detected = np.ones((n_envs, self.horizon + 1), dtype=bool)
        self._obs: NDArray[np.float32] | None = None

    def _get(self, calls: list[Any], shards: Iterable[int]) -> list[Any]:
        """The results of ``calls``, one to each of ``shards`` (indices into ``actors``); a
        shard that died is a :class:`ShardError` naming it, its runs and the cause."""
        results = []
        for c, call in zip(shards, calls, strict=True):
            try:
                results.append(self._ray.get(call))
            except self._ray.exceptions.RayActorError as err:
                a, b = self.bounds[c], self.bounds[c + 1]
                raise ShardError(
                    f"evaluation shard {c} of {len(self.actors)} (runs {a}..{b - 1} of "
                    f"{self.n_envs}) died: {cause(err)}"
                ) from None
        return results

    def _parts(self, values: NDArray[Any]) -> list[NDArray[Any]]:
        return [values[a:b] for a, b in zip(self.bounds[:-1], self.bounds[1:], strict=True)]

    def reset(
        self,
        indices: NDArray[np.int64],
        seeds: list[int | None],
        initial_tpms: NDArray[np.float64] | None = None,
    ) -> None:
        """Start new episodes in the slots ``indices`` (global), each shard its own
        (:meth:`TrackingCore.reset`).

        Raises:
            ConfigError, ValueError, IndexError: as :meth:`TrackingCore.reset`
                (:func:`~imm_gym.sim.core.checked_reset`), before any shard resets.
        """
        indices, initial_tpms = checked_reset(indices, seeds, initial_tpms, self.n_envs, self.M)
        if indices.size == 0:
            return
        calls, shards = [], []
        for c, (a, b) in enumerate(zip(self.bounds[:-1], self.bounds[1:], strict=True)):
            mine = (indices >= a) & (indices < b)
            if mine.any():
                local = indices[mine] - a
                tpms = None if initial_tpms is None else initial_tpms[mine]
                calls.append(
                    self.actors[c].reset.remote(
                        local, [seeds[i] for i in np.flatnonzero(mine)], tpms
                    )
                )
                shards.append(c)
        for c, (truth, true_model, z, detected, obs) in zip(
            shards, self._get(calls, shards), strict=True
        ):
            a = self.bounds[c]
            self.truth[a : a + len(truth)] = truth
            self.true_model[a : a + len(true_model)] = true_model
            self.z[a : a + len(z)] = z
            self.detected[a : a + len(detected)] = detected
            if self._obs is None:
                self._obs = np.zeros((self.n_envs, obs.shape[1]), dtype=obs.dtype)
            self._obs[a : a + len(obs)] = obs

    def observe(self) -> NDArray[np.float32]:
        """The observation of every slot (after :meth:`reset` or :meth:`step`)."""
        if self._obs is None:
            raise RuntimeError("observe() before reset()")
        return self._obs.copy()

    def step(self, action: NDArray[Any], active: NDArray[np.bool_] | None = None) -> StepResult:
        """One step of every slot; the shards' results concatenated in run order.

        Raises:
            ActionError: ``action`` not finite real numbers of shape ``(n_envs, action_dim)``
                (as :meth:`TrackingCore.step`).
            ValueError: ``active`` not a boolean mask of shape ``(n_envs,)``.
        """
        actions = self._parts(validate_action(action, self.n_envs, self.action_dim))
        active = checked_active(active, self.n_envs)
        actives = [None] * len(actions) if active is None else self._parts(active)
        results = self._get(
            [s.step.remote(x, m) for s, x, m in zip(self.actors, actions, actives, strict=True)],
            range(len(self.actors)),
        )
        info = {key: np.concatenate([r.info[key] for r in results]) for key in results[0].info}
        out = StepResult(
            np.concatenate([r.obs for r in results]),
            np.concatenate([r.reward for r in results]),
            np.concatenate([r.terminated for r in results]),
            np.concatenate([r.truncated for r in results]),
            info,
        )
        self._obs = out.obs
        return out
