"""The main job: train PPO to adapt the IMM's TPM, then evaluate it against the baselines.

    python train.py                      # defaults: imm_gym/TPMAdapt-v0, seed 0 (minutes: below)
    python train.py --seed 0 1 2         # several training seeds: each reported, then mean ± std
    python train.py --seed 0 1 2 3 4 --jobs 2 --no-eval   # two seeds at a time: the shipped policy
    python train.py --timesteps 200000 --out runs/quick
    python train.py --resume runs/default/seed_0/checkpoints/latest
    python train.py --env-config examples/my_tracker.yaml --timesteps 200000
    python train.py --engine rllib --env-runners 2 --timesteps 200000   # Ray RLlib (pip .[ray])

How long the default run takes depends on the machine and on what else runs on it: the README's
"Learning a TPM policy" gives the times measured.

Each seed writes ``OUT/seed_S/``: ``agent/`` (network, normalizer, env overrides), ``best/``,
``checkpoints/``, ``tb/`` (TensorBoard), ``training.json``, ``results.json``, ``report.md`` and
``plots/``. Every ``--validate-every`` steps the live policy is scored on validation runs (seeds
from 50,000,000 on) and the best one is kept in ``best/``. ``agent/`` is the mean of the
policy's weights after every update from ``swa_start`` (a fraction of the budget) on when the
hyperparameters set it, as the default does; otherwise the validated best (model selection on
validation scenarios, never on the held-out ones). The evaluation compares the
agent with classical IMM, TIP-IMM and the best fixed TPM on (a) the paper scenario (100 runs,
seeds 0..99) and (b) held-out randomized scenarios (``--random-runs``, seeds 0..R-1; training
uses seeds from 100,000,000 on), with common random numbers and paired bootstrap CIs.
``OUT/summary.json`` and ``OUT/report.md`` gather the seeds; with several seeds,
``OUT/ensemble/`` names their agents as one policy acting on the mean of their actions
(:mod:`agents.ensemble`; ``python -m imm_gym.evaluate --policy OUT/ensemble``). ``--jobs N`` trains
N seeds at a time, each in its own spawned process with one torch thread (a seed's agent is the
one it gets alone); Ctrl-C or SIGTERM to the job reaches every worker.

``--env-config FILE`` (YAML or JSON of EnvConfig fields, :mod:`imm_gym.sim.config_file`) trains on
that configuration instead of the entry's trackers: its fields are applied over what the entry's
``env_kwargs`` say the agent is (:data:`imm_gym.sim.mixture.AGENT_FIELDS`: its observation, action
and reward; the entry's trackers, targets and ``env_mixture`` are left out) and recorded with them
in the checkpoint and in the agent's ``env.json`` (what ``python -m imm_gym.evaluate`` reports as
the agent's ``trained_on``); the evaluation after training runs the paper scenario and the held-out
randomized family (the file's ``family``) on the file's tracker. Several files train across
trackers: each file's configuration takes its share of the training slots (``--env-shares``, equal
by default; :class:`imm_gym.sim.mixture.MixtureCore`), recorded as ``env_mixture`` in the
hyperparameters (a resumed run continues with it); the files must agree on what the policy reads
and writes (:data:`imm_gym.sim.mixture.POLICY_FIELDS`), and the first file's configuration is the
agent's ``env.json``, its validation and its evaluation.

``--env ID`` of an id without a hyperparameter entry of its own (every one but the default's)
trains on that id's preset: the default entry's hyperparameters and what it trains the agent as
(its ``AGENT_FIELDS``), the preset's fields over them and its observation features after the
entry's; the entry's trackers, targets and ``env_mixture`` are left out, as for ``--env-config``,
and the evaluation runs on the preset's tracker.

``--engine rllib`` trains with Ray RLlib's PPO instead (:mod:`agents.rllib`: ``--env-runners K``
runners each stepping the native vector env, on a local Ray instance or the cluster at
``--ray-address``); the agent is exported to the same data files, validated and evaluated
the same way. It writes no resumable checkpoints (``--resume`` is SB3's), and trains without the
asymmetric critic and the weight average (said when it starts; README, "Scaling out").

Ctrl-C (or SIGTERM) never loses training: the signal only sets a flag, checked after every
environment step, upon which ``checkpoints/latest`` is saved and the job exits with status 130
(143). ``--resume`` continues a checkpoint as the run it came from (:mod:`agents.checkpoint`): its
hyperparameters, its seed (another ``--seed`` is refused), its step count, optimizer, normalizer
and weight average, and each training slot's random streams where they stopped; it writes to
that run's directory (``OUT`` of ``OUT/seed_S/checkpoints/NAME``) unless ``--out`` says
otherwise. Agents and checkpoints are data only (JSON and safetensors): nothing is unpickled.
Without a progress bar (``--no-progress``, or output not to a terminal) a line per checkpoint and
validation gives the step, steps/s, the validation ARMSE and the time left.

The command line, its checks and the hyperparameters it resolves are :mod:`agents.train_setup`;
this script trains, evaluates and reports.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import signal
import sys
import time
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any, NoReturn

from agents.checkpoint import read_validation
from agents.report import (
    BASELINES_COMPARED,
    across_seeds,
    admitted_rules,
    describe_selection,
    evaluated_scenarios,
    paired,
    write_report,
    write_summary_report,
)
from agents.train_setup import build_parser, check_args, hyperparams
from agents.training import set_threads
from imm_gym.cli.provenance import record_json, versions


class StopRequest:
    """Ctrl-C (SIGINT) and SIGTERM as a request honoured between environment steps.

    The handler only records the signal: no exception is raised wherever it lands (inside the
    compiled environment step a ``KeyboardInterrupt`` would surface as ``SystemError`` and skip
    the checkpoint). Training checks :attr:`requested` after every step, then saves
    ``checkpoints/latest`` and exits with ``128 + signal`` (130 for Ctrl-C); the evaluation
    checks it between scenarios and seeds. Further signals while stopping are ignored.

    Args:
        parent: in a worker process of ``--jobs``, the parent's request — a shared integer, the
            signal number the parent received (0 until then) — honoured as the worker's own.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, parent: Any = None) -> None:
        self.signum: int | None = None
        self.parent = parent
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> StopRequest:
        for sig in self.SIGNALS:
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is None:
            self.signum = signum
            # os.write, not print: safe wherever the main thread was interrupted
            os.write(2, b"\nstopping at the next safe point...\n")

    @property
    def requested(self) -> bool:
        if self.signum is None and self.parent is not None and self.parent.value:
            self.signum = int(self.parent.value)
        return self.signum is not None

    def exit(self, message: str) -> NoReturn:
        """Print ``message`` and exit with ``128 + signal``."""
        assert self.signum is not None
        say(message)
        raise SystemExit(128 + self.signum)


def train_one(
    args: argparse.Namespace,
    params: dict[str, Any],
    seed: int,
    run_dir: Path,
    resume: dict[str, Any] | None,
    stop: StopRequest,
) -> Any:
    """Train (or resume) one seed; returns the trained agent's directory and the statistics."""
    from stable_baselines3.common.callbacks import BaseCallback

    from agents.checkpoint import restore, save_checkpoint
    from agents.training import (
        WeightAverage,
        algo_kwargs,
        build_algorithm,
        jsonable,
        make_training_env,
        save_agent,
        validation_armse,
    )
    from imm_gym.sim.core import critic_state_size

    env_kwargs = dict(params.get("env_kwargs", {}))
    frame_stack = int(params.get("frame_stack", 1))
    gamma = float(params.get("gamma", 0.99))
    critic_state = bool(params.get("critic_state", False))
    env = make_training_env(
        args.env,
        int(params["n_envs"]),
        seed,
        env_kwargs,
        bool(params.get("normalize", False)),
        frame_stack,
        gamma,
        critic_state,
        params.get("env_mixture", ()),
        tie_models=params["policy"] == "PerModelPolicy",
    )
    algo_cls = _algo_class(args.algo)
    ckpt_dir = run_dir / "checkpoints"
    critic_dims = critic_state_size(env.unwrapped.core.M) if critic_state else 0
    extra = {"env_id": args.env, "seed": seed, "critic_dims": critic_dims, **trained_across(params)}
    run = {
        "algo": args.algo,
        "env_id": args.env,
        "seed": seed,
        "hyperparams": jsonable(params),
        "evaluation_config": jsonable(args.env_overrides) if args.env_overrides else None,
    }
    kwargs = algo_kwargs(params)
    policy = params["policy"]
    if policy == "PerModelPolicy":
        from agents.per_model import PerModelActorCriticPolicy

        policy = PerModelActorCriticPolicy
        config = env.unwrapped.config
        kwargs["policy_kwargs"] = {
            **kwargs.get("policy_kwargs", {}),
            "obs_features": list(config.obs_features),
            "dim_z": config.sensor.dim_z,
            "critic_dims": critic_dims,
            "frame_stack": frame_stack,
        }
    elif critic_dims:
        from agents.asymmetric import AsymmetricActorCriticPolicy

        policy = AsymmetricActorCriticPolicy
        kwargs["policy_kwargs"] = {
            **kwargs.get("policy_kwargs", {}),
            "critic_dims": critic_dims,
            "frame_stack": frame_stack,
        }
    model = build_algorithm(
        algo_cls, policy, env, seed, verbose=0, tensorboard_log=str(run_dir / "tb"), **kwargs
    )
    swa = None
    if params.get("swa_start") is not None:
        swa = WeightAverage(int(float(params["swa_start"]) * params["n_timesteps"]))
    if resume is not None:
        restore(args.resume, resume, model, env, swa)
        print(f"resuming from {args.resume} at {model.num_timesteps} steps", flush=True)
    done = model.num_timesteps
    total = params["n_timesteps"]
    remaining = max(total - done, 0)
    say(f"seed {seed}: training {args.algo} on {args.env} from step {done:,} to {total:,}")
    best_dir = run_dir / "best"
    best_file = best_dir / "validation.json"
    best: dict[str, Any] = {"armse_pos": None}
    if resume is not None and best_file.is_file():  # the run's own, continued
        best = read_validation(best_file)
        if best.get("timesteps", 0) > done:  # kept after the checkpoint: not in this run's past
            best = {"armse_pos": None, "history": best.get("history", [])}
    history: list[dict[str, float]] = [
        v for v in best.get("history", []) if v["timesteps"] <= done
    ]
    progress_bar = not args.no_progress and sys.stderr.isatty()

    def validation_score() -> float:
        """The live model's position ARMSE on the validation runs."""
        return validation_armse(
            model,
            env,
            args.env,
            env_kwargs,
            frame_stack,
            args.algo,
            args.validation_runs,
            critic_dims,
        )

    def validate() -> float:
        """Score the live model on the validation runs; keep it in ``best/`` if it is the best."""
        armse = validation_score()
        history.append({"timesteps": int(model.num_timesteps), "armse_pos": armse})
        if best["armse_pos"] is None or armse < best["armse_pos"]:
            best.update(armse_pos=armse, timesteps=int(model.num_timesteps))
            save(best_dir)
        best["history"] = history
        best_dir.mkdir(parents=True, exist_ok=True)
        best_file.write_text(json.dumps(best, indent=2))
        return armse

    class Checkpoint(BaseCallback):
        """Checkpoints and validations on schedule, the weight average, the stop request.

        The schedule runs after each update (at the start of the next rollout, and at the end
        of training): the checkpoint or validation of step N holds the weights of the update
        that reached N, never those of the rollout before it."""

        def __init__(self, every: int, validate_every: int) -> None:
            super().__init__()
            self.every, self.next = every, done + every
            self.validate_every = validate_every
            self.next_validation = done + validate_every
            self.start = time.perf_counter()

        def _on_rollout_start(self) -> None:
            if swa is not None:  # the weights after the previous update
                swa.update(model)
            self.on_schedule()

        def _on_training_end(self) -> None:
            if swa is not None:
                swa.update(model)
            if not stop.requested:
                self.on_schedule()

        def _on_step(self) -> bool:
            return not stop.requested

        def on_schedule(self) -> None:
            """The checkpoint and the validation due at the live step count, if any."""
            steps = int(model.num_timesteps)
            saved, armse = False, None
            if steps >= self.next:
                while self.next <= steps:
                    self.next += self.every
                checkpoint("latest")
                if args.keep_checkpoints:
                    checkpoint(f"step_{steps}")
                saved = True
            if self.validate_every and steps >= self.next_validation:
                while self.next_validation <= steps:
                    self.next_validation += self.validate_every
                armse = validate()
            if (saved or armse is not None) and not progress_bar:
                elapsed = time.perf_counter() - self.start
                say(f"seed {seed}: {progress_line(steps, done, total, elapsed, armse)}")

    def save(directory: Path, **more: Any) -> None:
        save_agent(
            directory,
            model,
            env,
            env_kwargs,
            args.algo,
            frame_stack,
            {**extra, "num_timesteps": int(model.num_timesteps), **more},
        )

    written: set[str] = set()  # the checkpoints this run wrote (not an earlier run's, resumed)

    def checkpoint(name: str) -> None:
        """``checkpoints/NAME``: the agent and everything ``--resume`` needs."""
        meta = {**extra, "num_timesteps": int(model.num_timesteps)}
        save_checkpoint(ckpt_dir / name, model, env, run, meta, swa)
        written.add(name)

    start = time.perf_counter()
    model.learn(
        remaining,
        callback=Checkpoint(args.checkpoint_every, args.validate_every),
        progress_bar=progress_bar,
        reset_num_timesteps=args.resume is None,
        tb_log_name=f"{args.algo}_seed{seed}",
    )
    seconds = time.perf_counter() - start
    trained = int(model.num_timesteps) - done  # whole rollouts: at least the steps asked for
    checkpoint("latest")
    if stop.requested:
        latest = ckpt_dir / "latest"
        stop.exit(
            f"interrupted: checkpoint saved to {latest} ({model.num_timesteps} steps); "
            f"continue with: python train.py --resume {latest}"
        )
    final = f"step_{model.num_timesteps}"
    if args.keep_checkpoints and final not in written:  # a budget between checkpoint steps
        checkpoint(final)  # over a step_N left by the run this one resumed from, if any
    agent_dir = run_dir / "agent"
    if args.validate_every and not (history and history[-1]["timesteps"] == model.num_timesteps):
        validate()  # the end, where the schedule did not validate it
    if swa is not None:
        swa.apply(model)
        selected = {"swa_start": swa.start, "snapshots": swa.snapshots}
        save(agent_dir, swa=selected)
        if args.validate_every:
            selected["armse_pos"] = validation_score()
    elif args.validate_every:
        selected = adopt_best(best_dir, agent_dir, best)
    else:
        save(agent_dir)
        selected = {"timesteps": int(model.num_timesteps)}
    stats = {
        "timesteps": int(model.num_timesteps),
        "trained_this_call": trained,
        "seconds": seconds,
        "fps": trained / seconds if seconds > 0 else 0.0,
        "selected": selected,
        "validation": history,
    }
    (run_dir / "training.json").write_text(json.dumps(stats, indent=2))
    return agent_dir, stats


def trained_across(params: dict[str, Any]) -> dict[str, Any]:
    """``agent.json``'s ``trained_across``: the tracker of each further part of the mixture
    (``env_mixture``), none without one."""
    from agents.training import jsonable
    from imm_gym.sim.config_file import tracker_of

    parts = params.get("env_mixture", [])
    if not parts:
        return {}
    return {"trained_across": [jsonable(tracker_of(part["env_kwargs"])) for part in parts]}


def connect_ray(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--engine rllib``: join the Ray cluster at ``--ray-address`` (default: start a local
    instance; nothing if this process is connected already) before any run directory is made.
    Usage errors: an address Ray cannot connect to, and more ``--env-runners`` than the cluster
    has CPUs (each runner is an actor of one CPU; the learner runs in this process and takes
    none of them), for which RLlib would wait forever."""
    import ray

    from imm_gym.evaluation.distributed import connect

    if not ray.is_initialized():
        try:
            connect(args.ray_address)
        except (ConnectionError, ValueError, RuntimeError) as err:
            reason = (str(err).strip().splitlines() or [type(err).__name__])[0]
            if isinstance(err, ConnectionError):  # the address Ray would join answers not
                given = "" if args.ray_address is None else f"--ray-address {args.ray_address!r}: "
                parser.error(f"{given}cannot connect to Ray ({reason})")
            if args.ray_address is None:
                parser.error(f"cannot start a local Ray instance ({reason}); give --ray-address")
            parser.error(f"--ray-address {args.ray_address!r}: cannot connect to Ray ({reason})")
    cpus = int(ray.cluster_resources().get("CPU", 0))
    if args.env_runners > cpus:
        parser.error(
            f"--env-runners {args.env_runners}: each env runner takes one of the Ray cluster's "
            f"{cpus} CPU(s) (the learner runs in this process); give --env-runners in "
            f"[0, {cpus}]"
        )


def train_one_rllib(
    args: argparse.Namespace,
    params: dict[str, Any],
    seed: int,
    run_dir: Path,
    stop: StopRequest,
) -> Any:
    """Train one seed with RLlib's PPO (:mod:`agents.rllib`); returns the agent's directory and
    the statistics, as :func:`train_one`. Every ``--validate-every`` steps the policy is exported
    and scored on the validation runs, the best kept in ``best/``; ``agent/`` is that best (the
    last policy with ``--validate-every 0``)."""
    import tempfile

    import ray

    from agents import rllib
    from agents.policy import load_agent
    from agents.training import VALIDATION_SEED_BASE
    from imm_gym.envs import PRESETS
    from imm_gym.evaluation.rollout import evaluation_config, rollout, score
    from imm_gym.sim.env_config import EnvConfig

    for key, instead in rllib.not_ported(params).items():
        print(f"--engine rllib: {key} not ported: {instead}", flush=True)
    ledger, ledger_name = rllib.start_ledger(seed)
    algo = rllib.ppo_config(params, args.env, seed, args.env_runners, ledger_name).build_algo()
    log_std = params.get("policy_kwargs", {}).get("log_std_init")
    if log_std is not None:
        rllib.set_log_std(algo, float(log_std))
    total = int(params["n_timesteps"])
    best_dir, agent_dir = run_dir / "best", run_dir / "agent"
    best: dict[str, Any] = {"armse_pos": None}
    history: list[dict[str, float]] = []
    steps = 0

    def export(directory: Path) -> None:
        rllib.export_agent(
            algo,
            directory,
            params,
            args.env,
            {"seed": seed, **trained_across(params), "num_timesteps": steps},
        )

    def validate() -> float:
        """Export the live policy, score it on the validation runs, keep it if the best."""
        with tempfile.TemporaryDirectory(dir=run_dir) as tmp:
            export(Path(tmp))
            policy = load_agent(tmp)
            config = evaluation_config(EnvConfig.build(PRESETS[args.env]), policy.env_overrides)
            runs = args.validation_runs
            armse = float(score(rollout(policy, config, runs, VALIDATION_SEED_BASE))["armse_pos"])
            history.append({"timesteps": steps, "armse_pos": armse})
            if best["armse_pos"] is None or armse < best["armse_pos"]:
                best.update(armse_pos=armse, timesteps=steps)
                if best_dir.exists():
                    shutil.rmtree(best_dir)
                shutil.copytree(tmp, best_dir)
        (best_dir / "validation.json").write_text(json.dumps({**best, "history": history}))
        return armse

    say(
        f"seed {seed}: training ppo on {args.env} with RLlib, {args.env_runners} env runner(s), "
        f"to {total:,} steps"
    )
    start = time.perf_counter()
    next_validation = args.validate_every
    idle = 0  # iterations in a row that sampled nothing (every remote runner failed)
    while steps < total and not stop.requested:
        before, steps = steps, rllib.env_steps(algo.train(), steps)
        idle = idle + 1 if steps == before else 0
        if idle == rllib.IDLE_ITERATIONS:
            algo.stop()
            raise RuntimeError(
                f"seed {seed}: {idle} RLlib iterations in a row sampled no environment step "
                f"(at {steps:,} steps): the env runners keep failing; their logs are Ray's"
            )
        armse = None
        if args.validate_every and steps >= next_validation:
            next_validation += args.validate_every
            armse = validate()
        if armse is not None or not args.no_progress:
            elapsed = time.perf_counter() - start
            say(f"seed {seed}: {progress_line(steps, 0, total, elapsed, armse)}")
    seconds = time.perf_counter() - start
    if stop.requested:
        export(agent_dir)
        algo.stop()
        stop.exit(f"interrupted at {steps:,} steps: the last policy is in {agent_dir}")
    if args.validate_every:
        if not history or history[-1]["timesteps"] != steps:
            validate()
        selected = adopt_best(best_dir, agent_dir, best)
    else:
        export(agent_dir)
        selected = {"timesteps": steps}
    assignments = ray.get(ledger.records.remote())
    seeds = [s for a in assignments for s in a["seeds"]]
    algo.stop()
    stats = {
        "engine": "rllib",
        "env_runners": args.env_runners,
        "timesteps": steps,
        "trained_this_call": steps,
        "seconds": seconds,
        "fps": steps / seconds if seconds > 0 else 0.0,
        "selected": selected,
        "validation": history,
        "not_ported": rllib.not_ported(params),
        "sub_env_seeds": {
            "count": len(seeds),
            "distinct": len(set(seeds)),
            "runners": [
                {k: a[k] for k in ("runner", "generation", "node")} | {"first": a["seeds"][0]}
                for a in assignments
            ],
        },
    }
    (run_dir / "training.json").write_text(json.dumps(stats, indent=2))
    return agent_dir, stats


def adopt_best(best_dir: Path, agent_dir: Path, best: dict[str, Any]) -> dict[str, Any]:
    """The validated best checkpoint becomes the agent (``best_dir`` copied over ``agent_dir``);
    returns what was selected (its validation record without the history)."""
    if agent_dir.exists():
        shutil.rmtree(agent_dir)
    shutil.copytree(best_dir, agent_dir)
    return {k: v for k, v in best.items() if k != "history"}


def say(line: str) -> None:
    """Print ``line`` in one write and flush: lines of seeds trained side by side (``--jobs``)
    stay whole even where stdout is unbuffered (``print`` writes the text and the newline
    apart)."""
    sys.stdout.write(f"{line}\n")
    sys.stdout.flush()


def progress_line(step: int, start: int, total: int, seconds: float, armse: float | None) -> str:
    """``step 250,000/4,000,000, 7,350 steps/s, validation ARMSE 17.912 m, 8 min 30 s left``:
    the rate since this call began (validations included) and the time left at that rate."""
    rate = (step - start) / seconds if seconds > 0 else 0.0
    left = (total - step) / rate if rate > 0 else float("inf")
    validation = "" if armse is None else f", validation ARMSE {armse:.3f} m"
    return f"step {step:,}/{total:,}, {rate:,.0f} steps/s{validation}, {_duration(left)} left"


def _duration(seconds: float) -> str:
    """``45 s``, ``8 min 30 s``, ``2 h 05 min``; ``?`` before a rate is known."""
    if not seconds < float("inf"):
        return "?"
    s = max(round(seconds), 0)
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


def _algo_class(algo: str) -> Any:
    if algo == "recurrent-ppo":
        from sb3_contrib import RecurrentPPO

        return RecurrentPPO
    from stable_baselines3 import PPO

    return PPO


def evaluate_agent(
    agent_dir: Path, args: argparse.Namespace, run_dir: Path, stop: StopRequest
) -> dict[str, Any]:
    """Paper scenario and held-out random scenarios, learned agent vs the baselines (and the
    detector rules the tracker admits) on the first configuration (what the agent is trained as
    is its own: :func:`imm_gym.cli.comparison.evaluate`); a stop request is honoured before each
    scenario (the agent is saved by then)."""
    from agents.policy import load_agent
    from imm_gym.cli.comparison import evaluate, evaluated_config
    from imm_gym.cli.tables import render_tables
    from imm_gym.evaluation.plots import write_figures

    policy = load_agent(agent_dir)
    configs = evaluated_scenarios(args.env_overrides)
    out: dict[str, Any] = {}
    for scenario, runs in (("paper", args.paper_runs), ("random", args.random_runs)):
        env_config = configs[scenario]
        if stop.requested:
            stop.exit(
                f"interrupted before evaluating on the {scenario} scenario; the trained agent "
                f"is {agent_dir} (python -m imm_gym.evaluate --policy {agent_dir} ...)"
            )
        rules = admitted_rules(evaluated_config(scenario, env_config))
        results, rollouts = evaluate(
            (*BASELINES_COMPARED, *rules),
            scenario,
            runs,
            seed=0,
            reference="best-fixed",
            extra={"learned": (policy, policy.env_overrides)},
            env_config=env_config,
        )
        results["vs_tip_imm"] = paired(rollouts, "learned", "tip-imm")
        for rule in rules:
            results[f"vs_{rule.replace('-', '_')}"] = paired(rollouts, "learned", rule)
        results["meta"]["scenario"] = scenario
        dropped = sorted(set(args.env_overrides) - set(env_config) - {"scenario"})
        if dropped:
            results["meta"]["not_applied"] = dropped
        render_tables(results)
        write_figures(
            rollouts, run_dir / "plots" / scenario, results["meta"],
            evaluated_config(scenario, env_config),
        )
        out[scenario] = results
    return out


def run_seed(
    args: argparse.Namespace,
    params: dict[str, Any],
    seed: int,
    resume: dict[str, Any] | None,
    command: str,
    versions: dict[str, str],
    stop: StopRequest,
) -> tuple[Path, dict[str, Any]]:
    """Train (or resume) one seed and, unless ``--no-eval``, evaluate it, writing
    ``OUT/seed_S/``; returns the agent's directory and the seed's entry of ``summary.json``.

    Raises:
        ConfigError: a checkpoint to resume does not fit the model.
    """
    from agents.training import jsonable

    run_dir = args.out / f"seed_{seed}"
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(
        json.dumps(
            {"env": args.env, "algo": args.algo, "seed": seed, "hyperparams": jsonable(params)},
            indent=2,
        )
    )
    if args.engine == "rllib":
        agent_dir, stats = train_one_rllib(args, params, seed, run_dir, stop)
    else:
        agent_dir, stats = train_one(args, params, seed, run_dir, resume, stop)
    say(f"seed {seed}: {training_line(stats)}")
    entry: dict[str, Any] = {"training": stats}
    if args.no_eval:  # a resumed run's earlier evaluation described the agent just replaced
        stale = [run_dir / name for name in ("results.json", "report.md", "plots")]
        for path in [p for p in stale if p.exists()]:
            if path.is_dir():
                shutil.rmtree(path)
            else:
                path.unlink()
            say(f"seed {seed}: removed {path}: it evaluated the agent this run replaced")
    else:
        results = evaluate_agent(agent_dir, args, run_dir, stop)
        entry.update(results)
        (run_dir / "results.json").write_text(record_json(results))
        write_report(
            run_dir / "report.md",
            results,
            [
                f"# {args.algo.upper()} on {args.env}, seed {seed}",
                "",
                f"Command: `{command}`. Training: {training_line(stats, _engine(args))}.",
                f"Agent: {describe_selection(stats['selected'])}.",
                f"Versions: {versions}.",
            ],
        )
    return agent_dir, entry


def training_line(stats: dict[str, Any], engine: str | None = None) -> str:
    """``256 steps in 3 s (85 steps/s, ENGINE); 768 steps in all, resumed at step 512``: the
    steps this call trained in its seconds, and the run's total where it resumed a checkpoint
    (``stats``: ``training.json``'s)."""
    trained, total = stats["trained_this_call"], stats["timesteps"]
    rate = f"{stats['fps']:,.0f} steps/s" + ("" if engine is None else f", {engine}")
    line = f"{trained:,} steps in {stats['seconds']:.0f} s ({rate})"
    if trained != total:
        line += f"; {total:,} steps in all, resumed at step {total - trained:,}"
    return line


#: In a worker process of ``--jobs``: the parent's stop request (see :class:`StopRequest`).
_PARENT_STOP: Any = None


def _start_worker(parent_stop: Any) -> None:
    """A ``--jobs`` worker: one torch thread; Ctrl-C ignored until a seed's :class:`StopRequest`
    handles it (it reaches the parent too, which passes it on through ``parent_stop``)."""
    global _PARENT_STOP
    _PARENT_STOP = parent_stop
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    set_threads(1)


def _run_seed_in_worker(
    args: argparse.Namespace,
    params: dict[str, Any],
    seed: int,
    command: str,
    versions: dict[str, str],
) -> tuple[Path, dict[str, Any]]:
    """:func:`run_seed` in a worker process of ``--jobs``, stopping when the parent is asked to
    (a seed already queued when it was does not start)."""
    if _PARENT_STOP is not None and _PARENT_STOP.value:
        raise SystemExit(128 + _PARENT_STOP.value)
    with StopRequest(parent=_PARENT_STOP) as stop:
        return run_seed(args, params, seed, None, command, versions, stop)


def run_seeds_in_parallel(
    args: argparse.Namespace,
    params: dict[str, Any],
    command: str,
    versions: dict[str, str],
    stop: StopRequest,
) -> dict[int, tuple[Path, dict[str, Any]]]:
    """``--jobs N``: :func:`run_seed` for every seed, N processes at a time (spawned, so each
    starts as a lone run does and its agent is the one it gets alone). Ctrl-C reaches the workers
    too: each saves its checkpoint; seeds not started are not started, and the job exits with
    ``128 + signal`` once the workers have stopped. Returns ``{seed: (agent_dir, entry)}`` in the
    order of ``--seed``."""
    import multiprocessing
    from concurrent.futures import CancelledError, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    args = argparse.Namespace(**{**vars(args), "no_progress": True})
    context = multiprocessing.get_context("spawn")
    parent_stop = context.RawValue("i", 0)
    with ProcessPoolExecutor(
        max_workers=min(args.jobs, len(args.seed)),
        mp_context=context,
        initializer=_start_worker,
        initargs=(parent_stop,),
    ) as pool:
        futures = {
            seed: pool.submit(_run_seed_in_worker, args, params, seed, command, versions)
            for seed in args.seed
        }
        pending = set(futures.values())
        while pending:
            _, pending = wait(pending, timeout=0.5)
            if stop.requested and not parent_stop.value:
                parent_stop.value = stop.signum
                for future in pending:
                    future.cancel()
    trained: dict[int, tuple[Path, dict[str, Any]]] = {}
    unfinished: list[int] = []
    for seed, future in futures.items():
        try:
            trained[seed] = future.result()
        except (CancelledError, SystemExit, BrokenProcessPool):
            unfinished.append(seed)  # not started, or stopped after saving its checkpoint
    if unfinished:
        done = ", ".join(map(str, trained)) or "none"
        message = f"seeds trained: {done}; not finished: {unfinished}"
        if stop.requested:
            stop.exit(f"interrupted: {message}")
        raise SystemExit(f"a worker process died: {message}")
    return trained


def main(argv: list[str] | None = None) -> int:
    from imm_gym.validation import ConfigError

    parser = build_parser()
    args = parser.parse_args(argv)
    resume = check_args(parser, args)
    set_threads(1)
    try:
        params = hyperparams(args, resume)
        if args.engine == "rllib":
            from agents.rllib import check_params

            check_params(params, args.env_runners)
    except ConfigError as err:
        parser.error(str(err))
    if args.engine == "rllib":
        connect_ray(parser, args)
    args.out.mkdir(parents=True, exist_ok=True)
    command = "python train.py " + shlex.join(argv if argv is not None else sys.argv[1:])
    versions = _versions(args.engine, args.algo)
    with StopRequest() as stop:
        try:
            if args.jobs > 1 and len(args.seed) > 1:
                trained = run_seeds_in_parallel(args, params, command, versions, stop)
            else:
                trained = {}
                for seed in args.seed:
                    if stop.requested:
                        stop.exit(f"interrupted before training seed {seed}")
                    trained[seed] = run_seed(args, params, seed, resume, command, versions, stop)
        except ConfigError as err:  # a checkpoint that does not fit the model
            parser.error(str(err))
    seeds = {str(seed): entry for seed, (_, entry) in trained.items()}
    write_summary(args, seeds if resume is None else with_earlier_seeds(args.out, seeds),
                  command, versions)
    print(f"wrote {args.out}")
    return 0


def with_earlier_seeds(out: Path, seeds: dict[str, Any]) -> dict[str, Any]:
    """The seeds of ``OUT/summary.json`` whose agents are still in ``OUT/seed_S/agent``, with
    ``seeds`` (a resumed seed's entry) in place of their own, in the order of the seeds: what
    a resumed run writes back, so that the other seeds of a multi-seed run stay reported."""
    try:
        earlier = json.loads((out / "summary.json").read_text())["seeds"]
        kept = {
            key: entry
            for key, entry in earlier.items()
            if key.isdigit() and (out / f"seed_{key}" / "agent").is_dir()
        }
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return seeds  # no earlier summary (or not one of ours): this seed alone
    merged = {**kept, **seeds}
    return {key: merged[key] for key in sorted(merged, key=int)}


def write_summary(
    args: argparse.Namespace, seeds: dict[str, Any], command: str, versions: dict[str, str]
) -> None:
    """``OUT/summary.json`` of ``seeds`` (their ``summary.json`` entries by seed): with several,
    ``OUT/ensemble/`` of their agents; where every seed was evaluated, the statistics across
    them and ``OUT/report.md``, else no ``OUT/report.md`` (an earlier one gathered seeds this
    summary no longer holds as evaluated: a resumed or added seed's ``--no-eval``)."""
    summary: dict[str, Any] = {"command": command, "versions": versions, "seeds": seeds}
    if len(seeds) > 1:
        from agents.ensemble import write_ensemble

        members = [args.out / f"seed_{key}" / "agent" for key in seeds]
        file = write_ensemble(args.out / "ensemble", members)
        summary["ensemble"] = str(file.parent)
        print(
            f"wrote {file.parent}: the {len(members)} seeds' agents acting on the mean of "
            f"their actions (python -m imm_gym.evaluate --policy {file.parent})"
        )
    if all("paper" in entry for entry in seeds.values()):
        summary["across_seeds"] = across_seeds(seeds)
        write_summary_report(args.out / "report.md", summary)
    elif (args.out / "report.md").is_file():
        (args.out / "report.md").unlink()
        print(f"removed {args.out / 'report.md'}: it gathered seeds evaluated before this run")
    (args.out / "summary.json").write_text(record_json(summary))


def _engine(args: argparse.Namespace) -> str:
    """How the report says the agent was trained."""
    if args.engine == "rllib":
        return f"RLlib PPO, {args.env_runners} env runner(s)"
    return "SB3 on 1 thread"


def _versions(engine: str = "sb3", algo: str = "ppo") -> dict[str, str]:
    """The versions a run's results depend on (:func:`imm_gym.cli.provenance.versions`): the
    training libraries', sb3-contrib's for ``recurrent-ppo`` and Ray's for ``--engine rllib``."""
    libraries = ["stable-baselines3", "torch", "numba"]
    if algo == "recurrent-ppo":
        libraries.append("sb3-contrib")
    if engine == "rllib":
        libraries.append("ray")
    return versions(*libraries)


if __name__ == "__main__":
    raise SystemExit(main())
