"""Scaling out on a two-node Ray cluster simulated on this machine (``make test-ray``).

Two nodes of one CPU each (``ray.cluster_utils.Cluster``): RLlib training with two env runners
puts one on each node, and the evaluation's two shards likewise. Skipped without Ray (the main
venv); the ``ray`` marker selects them.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

# ray.rllib, not ray: with tests/ on the path this very directory imports as a namespace "ray"
pytest.importorskip("ray.rllib")
import ray

pytestmark = pytest.mark.ray

ENV_ID = "imm_gym/TPMAdapt-v0"
#: a few small iterations: 2 runners x 8 sub-envs x 16 steps per iteration
SMALL = {"n_envs": 8, "n_steps": 16, "batch_size": 64, "n_epochs": 1}


@pytest.fixture(scope="module")
def cluster():
    """Two Ray nodes of one CPU each, this process connected to them."""
    from ray.cluster_utils import Cluster

    from agents.training import set_threads

    set_threads(1)
    c = Cluster(
        initialize_head=True,
        head_node_args={"num_cpus": 1, "include_dashboard": False},
    )
    c.add_node(num_cpus=1)
    c.wait_for_nodes()
    ray.init(address=c.address, include_dashboard=False, log_to_driver=False)
    yield c
    ray.shutdown()
    c.shutdown()


def test_evaluation_split_across_both_nodes_is_bit_identical(cluster):
    from agents import PRETRAINED
    from agents.ensemble import load_policy
    from imm_gym.cli.comparison import evaluate
    from imm_gym.evaluation.distributed import ShardPool

    pool = ShardPool()
    assert len(set(pool.nodes())) == 2, "the two shards should sit on the two nodes"
    agent = load_policy(PRETRAINED)
    kwargs = {
        "extra": {"learned": (agent, agent.env_overrides)},
        "reference": "fixed",
    }
    # 13 runs: chunks of 7 and 6, and a batch whose network output depends on its size; the
    # best fixed TPM's search: every stay's runs in one sharded batch, each from its own TPM
    policies = ["fixed", "tip-imm", "best-fixed"]
    single, single_runs = evaluate(policies, "random", 13, 5, **kwargs)
    try:
        split, split_runs = evaluate(policies, "random", 13, 5, make_core=pool.core, **kwargs)
    finally:
        pool.close()  # the CPUs go back to the cluster for the next test
    assert json.dumps(single, sort_keys=True) == json.dumps(split, sort_keys=True)
    for name, run in single_runs.items():
        for field in dataclasses.fields(run):
            a, b = getattr(run, field.name), getattr(split_runs[name], field.name)
            assert a.dtype == b.dtype and np.array_equal(a, b), (name, field.name)


def test_shard_pool_leaves_the_cpus_other_work_holds(cluster):
    """Another job's actor holds one of the two CPUs: the pool takes the free one (a shard on the
    held CPU would never start, and the first roll-out would wait forever), and a pool asked for
    both CPUs fails after its start timeout."""
    import time

    from imm_gym.evaluation.distributed import ShardPool
    from imm_gym.sim.core import TrackingCore
    from imm_gym.sim.env_config import EnvConfig

    @ray.remote(num_cpus=1)
    class Busy:
        def ping(self) -> int:
            return 1

    busy = Busy.remote()
    ray.get(busy.ping.remote())
    try:
        pool = ShardPool()
        try:
            assert len(pool.actors) == 1
            config = EnvConfig()
            sharded, local = pool.core(config, 3), TrackingCore(config, n_envs=3)
            for core in (sharded, local):
                core.reset(np.arange(3), [5, 6, 7])
            np.testing.assert_array_equal(sharded.observe(), local.observe())
        finally:
            pool.close()
        with pytest.raises(TimeoutError, match="1 of 2 evaluation shard"):
            ShardPool(2, start_timeout=5)
    finally:
        ray.kill(busy)
    deadline = time.monotonic() + 60  # the next tests have both CPUs again
    while ray.available_resources().get("CPU", 0) < 2 and time.monotonic() < deadline:
        time.sleep(0.5)


def test_more_env_runners_than_the_cluster_has_cpus_are_refused(
    cluster, tmp_path: Path, capsys, monkeypatch
):
    """Three runners on the two CPUs: refused after connecting, before any run directory (RLlib
    would wait forever for the third runner's CPU: here training is not reached)."""
    import train

    def reached(*args, **kwargs):
        raise AssertionError("training started: RLlib would wait forever for a third CPU")

    monkeypatch.setattr(train, "train_one_rllib", reached)
    config = tmp_path / "small.yml"
    config.write_text("".join(f"{k}: {v}\n" for k, v in SMALL.items()))
    argv = ["--engine", "rllib", "--ray-address", cluster.address, "--config", str(config)]
    with pytest.raises(SystemExit) as exc:
        train.main([*argv, "--env-runners", "3", "--no-eval", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--env-runners 3" in err and "[0, 2]" in err
    assert not (tmp_path / "run").exists()


def test_hetero_bank_evaluation_with_a_one_run_chunk_is_bit_identical(cluster):
    """3 runs on two shards: chunks of 2 and 1; the heterogeneous bank's mixture NIS of the run
    alone in its core equals its NIS among the others."""
    from imm_gym.cli.comparison import evaluate
    from imm_gym.evaluation.distributed import ShardPool

    pool = ShardPool()
    single, single_runs = evaluate(["fixed"], "paper", 3, 4, bank="hetero", clairvoyant=False)
    try:
        split, split_runs = evaluate(
            ["fixed"], "paper", 3, 4, bank="hetero", clairvoyant=False, make_core=pool.core
        )
    finally:
        pool.close()
    assert json.dumps(single, sort_keys=True) == json.dumps(split, sort_keys=True)
    for field in dataclasses.fields(single_runs["fixed"]):
        a, b = getattr(single_runs["fixed"], field.name), getattr(split_runs["fixed"], field.name)
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), field.name


def test_rllib_training_runners_on_both_nodes_with_distinct_seeds(
    cluster, tmp_path: Path, monkeypatch
):
    import train
    from agents import rllib
    from agents.policy import load_agent
    from agents.training import load_hyperparams
    from imm_gym.envs import PRESETS
    from imm_gym.seeding import RLLIB_SEED_BASE, rllib_seed
    from imm_gym.sim.env_config import EnvConfig

    parts: list = []  # each remote runner's env: its core's class, the parts' configs and slots
    export = rllib.export_agent

    def export_and_look(algo, *args, **kwargs):
        def look(runner):
            core = runner.env.unwrapped.core
            cores = getattr(core, "cores", [core])
            return type(core).__name__, [c.config for c in cores], [c.n_envs for c in cores]

        if not parts:  # at the first validation, while the runners run
            parts.extend(algo.env_runner_group.foreach_env_runner(look, local_env_runner=False))
        return export(algo, *args, **kwargs)

    monkeypatch.setattr(rllib, "export_agent", export_and_look)
    config = tmp_path / "small.yml"
    config.write_text("".join(f"{k}: {v}\n" for k, v in SMALL.items()))
    out = tmp_path / "run"
    code = train.main(
        [
            "--engine",
            "rllib",
            "--ray-address",
            cluster.address,
            "--env-runners",
            "2",
            "--config",
            str(config),
            "--timesteps",
            "600",
            "--validate-every",
            "256",
            "--validation-runs",
            "4",
            "--no-eval",
            "--no-progress",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    stats = json.loads((out / "seed_0" / "training.json").read_text())
    assert stats["engine"] == "rllib" and stats["timesteps"] >= 600
    seeds = stats["sub_env_seeds"]
    runners = seeds["runners"]
    assert sorted(r["runner"] for r in runners) == [1, 2]
    assert len({r["node"] for r in runners}) == 2, "one env runner on each node"
    assert seeds["count"] == 2 * SMALL["n_envs"] == seeds["distinct"]
    for r in runners:
        assert r["first"] == rllib_seed(0, r["runner"], 0, r["generation"]) >= RLLIB_SEED_BASE
    assert len(stats["validation"]) >= 2
    # the exported agent loads through the project's loader and acts
    policy = load_agent(out / "seed_0" / "agent")
    assert policy.frame_stack == 4 and policy.obs_mean is not None
    # the default entry's mixture is trained, not left out: every runner's sub-envs are split
    # between its two trackers, and the agent records the second
    params, _ = load_hyperparams(ENV_ID)
    expected = [
        EnvConfig.build({**PRESETS[ENV_ID], **kwargs})
        for kwargs in (params["env_kwargs"], params["env_mixture"][0]["env_kwargs"])
    ]
    assert len(parts) == 2
    for name, configs, slots in parts:
        assert name == "MixtureCore" and configs == expected and slots == [4, 4]
    assert len(policy.trained_across) == 1
    obs = np.zeros((3, policy.obs_size))
    actions, _ = policy.predict(obs)
    size = int(policy.model.action_space.shape[0])  # the default entry's action
    assert actions.shape == (3, size) and np.all(np.abs(actions) <= 1.0)


def test_an_iteration_without_samples_keeps_the_step_count_and_sampling_has_no_timeout():
    """A ``train()`` result without env runner metrics (RLlib's after an iteration that sampled
    nothing) leaves the step count where it was; and a runner's samples are waited for however
    long they take (the first compiles the numba kernels: minutes where they are not cached,
    past RLlib's default 60 s timeout, which returned such a result)."""
    from ray.rllib.utils.metrics import ENV_RUNNER_RESULTS, NUM_ENV_STEPS_SAMPLED_LIFETIME

    from agents import rllib
    from agents.training import load_hyperparams

    assert rllib.env_steps({"timers": {}}, 512) == 512
    sampled = {ENV_RUNNER_RESULTS: {NUM_ENV_STEPS_SAMPLED_LIFETIME: 640}}
    assert rllib.env_steps(sampled, 512) == 640
    params, _ = load_hyperparams(ENV_ID)
    assert rllib.ppo_config({**params, **SMALL}, ENV_ID, 0, 2, "ledger").sample_timeout_s is None


def test_training_stops_when_iterations_keep_sampling_nothing(cluster, tmp_path: Path, monkeypatch):
    """With no sample timeout, runners that keep failing (iterations without env runner
    metrics) would train forever: after ``IDLE_ITERATIONS`` such iterations in a row training
    stops with an error."""
    import train
    from agents import rllib

    class Idle:
        iterations = 0

        def train(self) -> dict:
            Idle.iterations += 1
            assert Idle.iterations <= rllib.IDLE_ITERATIONS, "training went on sampling nothing"
            return {}

        def stop(self) -> None:
            pass

    class Config:
        def build_algo(self) -> Idle:
            return Idle()

    monkeypatch.setattr(rllib, "ppo_config", lambda *args, **kwargs: Config())
    monkeypatch.setattr(rllib, "set_log_std", lambda algo, value: None)
    config = tmp_path / "small.yml"
    config.write_text("".join(f"{k}: {v}\n" for k, v in SMALL.items()))
    argv = ["--engine", "rllib", "--ray-address", cluster.address, "--config", str(config),
            "--timesteps", "600", "--validate-every", "0", "--no-eval", "--no-progress"]
    with pytest.raises(RuntimeError, match="iterations in a row sampled no environment step"):
        train.main([*argv, "--out", str(tmp_path / "run")])
    assert Idle.iterations == rllib.IDLE_ITERATIONS


def _stacks(frames: int, obs: np.ndarray) -> np.ndarray:
    """The stacked inputs ``LearnedPolicy`` feeds its network over one episode (no normalizer)."""
    from agents.policy import LearnedPolicy

    seen = []

    class Recorder:
        observation_space = type("Space", (), {"shape": (frames * obs.shape[1],)})

        def predict(self, x, deterministic=True):
            seen.append(x[0].copy())
            return np.zeros((1, 1)), None

    policy = LearnedPolicy(Recorder(), {}, frame_stack=frames)
    state = None
    for t, o in enumerate(obs):
        _, state = policy.predict(o[None], state, episode_start=np.array([t == 0]))
    return np.array(seen)


def test_frame_stack_connectors_stack_as_the_agent_loader():
    import gymnasium
    from ray.rllib.env.single_agent_episode import SingleAgentEpisode

    from agents.rllib import _frame_stack_connector

    frames, d = 4, 3
    obs = np.arange(6 * d, dtype=np.float32).reshape(6, d) + 1.0
    space = gymnasium.spaces.Box(-np.inf, np.inf, (d,), np.float32)
    expected = _stacks(frames, obs)
    for t in range(6):  # the env-to-module piece at each step of a running episode
        episode = SingleAgentEpisode(
            observations=list(obs[: t + 1]),
            observation_space=space,
            actions=[np.zeros(1)] * t,
            rewards=[0.0] * t,
            len_lookback_buffer=0,
        )
        batch = _frame_stack_connector(frames, False)(rl_module=None, batch={}, episodes=[episode])
        (items,) = batch["obs"].values()
        np.testing.assert_array_equal(items[0], expected[t])
    episode = SingleAgentEpisode(
        observations=list(obs),
        observation_space=space,
        actions=[np.zeros(1)] * 5,
        rewards=[0.0] * 5,
        len_lookback_buffer=0,
    ).to_numpy()
    batch = _frame_stack_connector(frames, True)(rl_module=None, batch={}, episodes=[episode])
    (items,) = batch["obs"].values()
    np.testing.assert_array_equal(np.concatenate(items), expected[:5])


def test_exported_agent_acts_as_the_rllib_module(cluster, tmp_path: Path):
    import torch
    from ray.rllib.connectors.env_to_module.mean_std_filter import MeanStdFilter

    from agents import rllib
    from agents.policy import load_agent
    from agents.training import load_hyperparams
    from imm_gym.seeding import rllib_seed

    params, _ = load_hyperparams(ENV_ID)
    params = {**params, **SMALL}
    ledger, name = rllib.start_ledger(7)
    algo = rllib.ppo_config(params, ENV_ID, 7, 0, name).build_algo()
    try:
        rllib.set_log_std(algo, -1.0)
        algo.train()
        rllib.export_agent(algo, tmp_path, params, ENV_ID, {"seed": 7})
        assert json.loads((tmp_path / "agent.json").read_text())["normalize"] is True
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # not loaded as an agent that predates the record
            policy = load_agent(tmp_path)
        runner = algo.env_runner_group.local_env_runner
        (filt,) = [p for p in runner._env_to_module.connectors if isinstance(p, MeanStdFilter)]
        assert filt._filters[None].running_stats.n > 0
        rng = np.random.default_rng(0)
        raw = rng.normal(size=(5, policy.obs_size)) * 3.0
        np.testing.assert_allclose(
            policy.normalize(raw), filt._filters[None](raw, update=False), rtol=0, atol=1e-5
        )
        x = rng.normal(size=(5, 4 * policy.obs_size)).astype(np.float32)
        with torch.no_grad():
            out = algo.get_module().forward_inference({"obs": torch.from_numpy(x)})
        size = int(policy.model.action_space.shape[0])  # then the log standard deviations
        mean = out["action_dist_inputs"][:, :size].numpy()
        actions, _ = policy.model.predict(x, deterministic=True)
        np.testing.assert_allclose(actions, np.clip(mean, -1.0, 1.0), rtol=0, atol=1e-6)
        log_std = dict(policy.model.named_parameters())["log_std"].detach().numpy()
        np.testing.assert_array_equal(log_std, algo.get_module().pi.log_std.detach().numpy())
        # a runner that builds its env again (as after a restart) gets new seeds
        first = list(runner.env.unwrapped.seeds)
        runner.make_env()
        assert runner.env.unwrapped.seeds == [rllib_seed(7, 0, i, 1) for i in range(len(first))]
        assert not set(first) & set(runner.env.unwrapped.seeds)
        records = ray.get(ledger.records.remote())
        assert [(r["runner"], r["generation"]) for r in records] == [(0, 0), (0, 1)]
    finally:
        algo.stop()


def wait_for_both_cpus() -> None:
    """Until the cluster's two CPUs are free again (a pool's ended actors return theirs)."""
    import time

    deadline = time.monotonic() + 60
    while ray.available_resources().get("CPU", 0) < 2 and time.monotonic() < deadline:
        time.sleep(0.5)
    assert ray.available_resources().get("CPU", 0) == 2, "a shard still holds its CPU"


def test_a_shard_that_fails_to_start_is_a_usage_error_naming_ray_and_the_cause(
    cluster, monkeypatch, capsys
):
    """The shards' class cannot be created on the nodes (as where imm_gym is not installed): the
    command stops with the usage error naming ``--ray``, the shard and the cause, and the pool's
    actors are ended (``ray.wait`` counts a failed start as ready: it passed, and the first step
    raised Ray's traceback)."""
    from imm_gym.cli.evaluate import main
    from imm_gym.evaluation import distributed

    class Unimportable(distributed.Shard):  # a local class: Ray sends it by value
        def __init__(self) -> None:
            raise ImportError("no imm_gym on this node")

    monkeypatch.setattr(distributed, "Shard", Unimportable)
    wait_for_both_cpus()  # the earlier tests' actors ended: a shard on each CPU
    with pytest.raises(SystemExit) as exc:
        main(["--policy", "fixed", "--runs", "2", "--quiet", "--no-clairvoyant", "--ray",
              cluster.address])
    err = capsys.readouterr().err
    assert exc.value.code == 2
    assert (f"--ray {cluster.address}: evaluation shard 0 of 2 failed to start: ImportError: "
            f"no imm_gym on this node") in err
    wait_for_both_cpus()


def test_a_shard_that_dies_mid_run_is_named_with_its_runs(cluster):
    from imm_gym.evaluation.distributed import ShardError, ShardPool
    from imm_gym.sim.core import TrackingCore
    from imm_gym.sim.env_config import EnvConfig

    config = EnvConfig()
    pool = ShardPool(2)
    try:
        core = pool.core(config, 3)  # chunks of runs 0..1 and 2..2
        core.reset(np.arange(3), [1, 2, 3])
        ray.kill(pool.actors[1])
        died = r"evaluation shard 1 of 2 \(runs 2\.\.2 of 3\) died: .*ray\.kill"
        with pytest.raises(ShardError, match=died):
            core.step(np.zeros((3, TrackingCore(config, n_envs=1).action_dim)))
        with pytest.raises(ShardError, match=died):
            core.reset(np.array([2]), [4])
    finally:
        pool.close()
    wait_for_both_cpus()


def test_sharded_core_refuses_what_the_core_refuses(cluster):
    """Surplus seeds, action rows or mask entries, a slot listed twice or outside the core and
    initial TPMs of another count are refused as the single-process core refuses them (the
    shards were sent their chunks' rows and the rest was dropped, or shard 0 reset before shard 1
    refused), before any shard is asked: both cores step on alike afterwards."""
    from imm_gym.evaluation.distributed import ShardPool
    from imm_gym.sim.actions import ActionError
    from imm_gym.sim.core import TrackingCore
    from imm_gym.sim.env_config import EnvConfig
    from imm_gym.validation import ConfigError

    config = EnvConfig()
    pool = ShardPool(2)
    try:
        sharded, local = pool.core(config, 3), TrackingCore(config, n_envs=3)
        dim = local.action_dim
        refused = [
            (lambda c: c.reset(np.arange(3), [1, 2, 3, 4]), ValueError, "4 seeds for 3 slots"),
            # a slot listed twice: shard 0's slot 0 reset before shard 1 refused its own twice
            (lambda c: c.reset(np.array([0, 2, 2]), [5, 6, 7]), ValueError,
             r"slots \[2\] listed more than once"),
            (lambda c: c.reset(np.arange(3), [5, 6, 7], np.full((2, 3, 3), 1 / 3)), ConfigError,
             r"initial_tpms must have shape \(3, 3, 3\)"),
            (lambda c: c.step(np.zeros((4, dim))), ActionError,
             rf"action must have shape \(3, {dim}\) .*got \(4, {dim}\)"),
            (lambda c: c.step(np.zeros((3, dim)), np.ones(4, dtype=bool)), ValueError,
             r"active must be a boolean mask of shape \(3,\), got bool of shape \(4,\)"),
        ]
        for core in (sharded, local):
            core.reset(np.arange(3), [1, 2, 3])
            for call, error, match in refused:
                with pytest.raises(error, match=match):
                    call(core)
            with pytest.raises(IndexError):
                core.reset(np.array([0, 5]), [7, 8])
        with pytest.raises(IndexError, match=r"slots must be in \[0, 2\], got \[5\]"):
            sharded.reset(np.array([0, 5]), [7, 8])
        action = np.zeros((3, dim))
        np.testing.assert_array_equal(sharded.step(action).obs, local.step(action).obs)
    finally:
        pool.close()
    wait_for_both_cpus()


def test_a_shard_that_dies_mid_evaluation_ends_the_command_in_one_line(
    cluster, monkeypatch, capsys
):
    """A shard whose process ends during the roll-out (its node went away): the command stops
    with one error line naming the shard and its runs, exit status 1, not Ray's traceback."""
    from imm_gym.cli.evaluate import main
    from imm_gym.evaluation import distributed

    class Dying(distributed.Shard):  # a local class: Ray sends it by value
        def step(self, actions, active):
            if self.core.k >= 3:
                os._exit(1)
            return super().step(actions, active)

    pools: list[distributed.ShardPool] = []
    start = distributed.ShardPool.__init__

    def kept(self, *args, **kwargs) -> None:
        start(self, *args, **kwargs)
        pools.append(self)

    monkeypatch.setattr(distributed, "Shard", Dying)
    monkeypatch.setattr(distributed.ShardPool, "__init__", kept)
    wait_for_both_cpus()
    try:
        with pytest.raises(SystemExit) as exc:
            main(["--policy", "fixed", "--runs", "2", "--quiet", "--no-clairvoyant", "--ray",
                  cluster.address])
    finally:
        for pool in pools:
            pool.close()
    err = capsys.readouterr().err
    assert exc.value.code == 1
    assert "Traceback" not in err
    assert re.search(r"^.*: error: evaluation shard [01] of 2 \(runs [01]\.\.[01] of 2\) died: ",
                     err, re.MULTILINE), err
    wait_for_both_cpus()


def test_evaluate_command_with_ray_writes_the_same_json(cluster, tmp_path: Path, monkeypatch):
    """Last in the file: the command's shard actors live until this process lets them go. With
    ``--ray`` each roll-out (one a policy) steps a core of shards, without it none does."""
    from imm_gym.cli.evaluate import main
    from imm_gym.evaluation.distributed import ShardedCore

    sharded: list[dict[str, int]] = []  # per core: its shards and the steps it took
    init, step = ShardedCore.__init__, ShardedCore.step

    def counted_init(self, actors, config, n_envs) -> None:
        init(self, actors, config, n_envs)
        self.counts = {"shards": len(self.actors), "steps": 0}
        sharded.append(self.counts)

    def counted_step(self, action, active=None):
        self.counts["steps"] += 1
        return step(self, action, active)

    monkeypatch.setattr(ShardedCore, "__init__", counted_init)
    monkeypatch.setattr(ShardedCore, "step", counted_step)
    args = ["--policy", "fixed", "--policy", "tip-imm", "--runs", "6", "--seed", "3", "--quiet"]
    main([*args, "--json", str(tmp_path / "one.json")])
    assert sharded == []
    main([*args, "--json", str(tmp_path / "ray.json"), "--ray", cluster.address])
    assert len(sharded) == 2, "one sharded core per policy's roll-out"
    assert all(c["shards"] >= 1 and c["steps"] >= 150 for c in sharded), sharded
    one, split = (json.loads((tmp_path / f).read_text()) for f in ("one.json", "ray.json"))
    del one["meta"]["command"], split["meta"]["command"]
    assert one == split
