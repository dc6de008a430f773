"""``distributed.ShardedCore`` over shards held in this process (no Ray): the runs split into
contiguous chunks, each chunk a core of its own, give the core of all the runs bit for bit, also
with fewer runs than shards (``--runs 1`` on a cluster of two CPUs)."""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest

from imm_gym.evaluation.distributed import Shard, ShardedCore, cause, chunk_sizes
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig


class _Call:
    """A method of a shard as a Ray actor's: ``method.remote(...)`` runs it at once."""

    def __init__(self, method) -> None:
        self.remote = method


class _InProcess:
    """A shard actor stand-in: the :class:`Shard` body in this process."""

    def __init__(self) -> None:
        body = Shard()
        self.shard = body
        for name in ("build", "reset", "step"):
            setattr(self, name, _Call(getattr(body, name)))


@pytest.fixture
def local_ray(monkeypatch: pytest.MonkeyPatch) -> None:
    """``import ray`` inside :class:`ShardedCore` gives a stand-in whose ``get`` returns the
    (already computed) result."""
    died = type("RayActorError", (Exception,), {})
    exceptions = types.SimpleNamespace(RayActorError=died)
    ray = types.SimpleNamespace(get=lambda x: x, exceptions=exceptions)
    monkeypatch.setitem(sys.modules, "ray", ray)


@pytest.mark.parametrize(
    ("runs", "chunks", "sizes"),
    # by hand: the first runs mod C chunks one run more; never an empty chunk
    [(13, 2, [7, 6]), (10, 4, [3, 3, 2, 2]), (3, 2, [2, 1]), (1, 2, [1]), (2, 5, [1, 1]),
     (4, 1, [4])],
)
def test_chunk_sizes_split_the_runs_into_nearly_equal_contiguous_chunks(runs, chunks, sizes):
    assert chunk_sizes(runs, chunks) == sizes


@pytest.mark.parametrize(("runs", "shards"), [(1, 2), (2, 3), (5, 2)])
def test_the_sharded_core_steps_as_one_core(local_ray, runs, shards) -> None:
    """Resets (all slots, then one), steps (an action per slot, a mask) and the infos of the
    sharded core equal those of one core of ``runs`` slots; the shards beyond the runs hold
    none. Missed detections (a sensor detecting 80 %) and a TPM of each slot's own at a reset
    reach every chunk."""
    config = EnvConfig(sensor={"detection_prob": 0.8, "outlier_prob": 0.2})
    actors = [_InProcess() for _ in range(shards)]
    sharded = ShardedCore(actors, config, runs)
    local = TrackingCore(config, n_envs=runs)
    assert len(sharded.actors) == min(runs, shards)
    assert all(a.shard.core is None for a in actors[runs:])
    seeds = [11 + 3 * i for i in range(runs)]
    for core in (sharded, local):
        core.reset(np.arange(runs), seeds)
    np.testing.assert_array_equal(sharded.observe(), local.observe())
    for name in ("truth", "true_model", "z", "detected"):
        np.testing.assert_array_equal(getattr(sharded, name), getattr(local, name), name)
    rng = np.random.default_rng(4)
    for k in range(6):
        action = rng.uniform(-1.0, 1.0, (runs, local.action_dim))
        active = None if k % 2 == 0 else np.arange(runs) % 2 == 0
        a, b = sharded.step(action, active), local.step(action, active)
        for field in ("obs", "reward", "terminated", "truncated"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), field)
        assert a.info.keys() == b.info.keys()
        for key in b.info:
            np.testing.assert_array_equal(a.info[key], b.info[key], key)
    last = runs - 1  # the last slot alone starts again, in the last chunk
    for core in (sharded, local):
        core.reset(np.array([last]), [99])
    np.testing.assert_array_equal(sharded.observe(), local.observe())
    np.testing.assert_array_equal(sharded.truth, local.truth)
    # every slot again, each from its own TPM: stays 0.5 .. 0.9, the rest shared equally
    M = local.M
    stays = np.linspace(0.5, 0.9, runs)
    off = (1.0 - stays)[:, None, None] / (M - 1) * (1.0 - np.eye(M))
    tpms = off + stays[:, None, None] * np.eye(M)
    for core in (sharded, local):
        core.reset(np.arange(runs), [7 + i for i in range(runs)], tpms)
    for _ in range(20):
        action = rng.uniform(-1.0, 1.0, (runs, local.action_dim))
        a, b = sharded.step(action), local.step(action)
        np.testing.assert_array_equal(a.obs, b.obs)
        np.testing.assert_array_equal(a.reward, b.reward)
    assert not sharded.detected.all()
    np.testing.assert_array_equal(sharded.detected, local.detected)
    np.testing.assert_array_equal(sharded.z, local.z)


@pytest.mark.parametrize(
    ("message", "said"),
    [
        # Ray's message of an actor whose creation raised: the traceback, then the exception
        (
            "The actor died because of an error raised in its creation task, "
            "ray::Shard.__init__() (pid=7, ip=10.0.0.2)\n  File \"x.py\", line 3, in __init__\n"
            "ImportError: no imm_gym on this node. Check the node's environment.\n",
            "ImportError: no imm_gym on this node",
        ),
        (
            "The actor is dead because its worker process has died. Worker exit type: "
            "SYSTEM_ERROR Worker exit detail: the node ended.",
            "The actor is dead because its worker process has died",
        ),
        ("ended.", "ended"),
        ("", "RayActorError"),
    ],
)
def test_the_cause_of_a_dead_shard_is_the_first_sentence_of_rays_last_line(message, said):
    error = type("RayActorError", (Exception,), {})(message)
    assert cause(error) == said
