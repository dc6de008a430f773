"""The main job: train PPO to adapt the IMM's TPM, then evaluate it against the baselines.

    python train.py                      # defaults: imm_gym/TPMAdapt-v0, seed 0, ~12 min on 2 cores
    python train.py --seed 0 1 2         # several training seeds: each reported, then mean ± std
    python train.py --timesteps 200000 --out runs/quick
    python train.py --resume runs/default/seed_0/checkpoints/latest

Each seed writes ``OUT/seed_S/``: ``agent/`` (model, normalizer, env overrides), ``best/``,
``checkpoints/``, ``tb/`` (TensorBoard), ``training.json``, ``results.json``, ``report.md`` and
``plots/``. Every ``--validate-every`` steps the live policy is scored on validation runs (seeds
from 50,000,000 on) and the best one is kept in ``best/``. ``agent/`` is the mean of the
policy's weights after every update from ``swa_start`` (a fraction of the budget) on when the
hyperparameters set it, as the default does; otherwise the validated best (model selection on
validation scenarios, never on the held-out ones). The evaluation compares the
agent with classical IMM, TIP-IMM and the best fixed TPM on (a) the paper scenario (100 runs,
seeds 0..99) and (b) held-out randomized scenarios (``--random-runs``, seeds 0..R-1; training
uses seeds from 100,000,000 on), with common random numbers and paired bootstrap CIs.
``OUT/summary.json`` and ``OUT/report.md`` gather the seeds. Ctrl-C saves a checkpoint and exits
cleanly.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from agents.training import set_threads

BASELINES_COMPARED = ("fixed", "tip-imm", "best-fixed")
ALGOS = ("ppo", "recurrent-ppo")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python train.py",
        description="Train a PPO agent to adapt the IMM's TPM, then evaluate it.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--env", default="imm_gym/TPMAdapt-v0", help="registered environment id")
    p.add_argument("--algo", default="ppo", choices=ALGOS)
    p.add_argument("--timesteps", type=int, help="training steps (default: the YAML entry's)")
    p.add_argument("--seed", type=int, nargs="+", default=[0], help="training seed(s)")
    p.add_argument(
        "--config", type=Path, help="YAML file with hyperparameters overriding the entry"
    )
    p.add_argument("--out", type=Path, default=Path("runs/default"), help="output directory")
    p.add_argument("--resume", type=Path, help="checkpoint directory to continue from")
    p.add_argument(
        "--checkpoint-every", type=int, default=250_000, help="steps between checkpoints"
    )
    p.add_argument(
        "--keep-checkpoints",
        action="store_true",
        help="keep every checkpoint as checkpoints/step_N (default: only checkpoints/latest)",
    )
    p.add_argument(
        "--validate-every",
        type=int,
        default=500_000,
        help="steps between validations that keep the best checkpoint (0: keep the last)",
    )
    p.add_argument(
        "--validation-runs", type=int, default=200, help="runs per validation (seeds 50,000,000+)"
    )
    p.add_argument("--paper-runs", type=int, default=100)
    p.add_argument("--random-runs", type=int, default=1000)
    p.add_argument("--no-eval", action="store_true", help="train only")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def check_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    import gymnasium as gym

    import imm_gym  # noqa: F401  (registers the ids)

    if args.env not in gym.registry:
        ids = sorted(k for k in gym.registry if k.startswith("imm_gym/"))
        parser.error(f"--env {args.env!r} is not registered; available: {ids}")
    if args.timesteps is not None and args.timesteps < 1:
        parser.error(f"--timesteps must be >= 1, got {args.timesteps}")
    if any(s < 0 for s in args.seed) or len(set(args.seed)) != len(args.seed):
        parser.error(f"--seed values must be distinct non-negative integers, got {args.seed}")
    if args.checkpoint_every < 1:
        parser.error(f"--checkpoint-every must be >= 1, got {args.checkpoint_every}")
    if args.validate_every < 0:
        parser.error(f"--validate-every must be >= 0, got {args.validate_every}")
    if args.validation_runs < 1:
        parser.error(f"--validation-runs must be >= 1, got {args.validation_runs}")
    if args.paper_runs < 1 or args.random_runs < 1:
        parser.error("--paper-runs and --random-runs must be >= 1")
    if args.config is not None and not args.config.is_file():
        parser.error(f"--config file {str(args.config)!r} does not exist")
    if args.resume is not None:
        if not (args.resume / "model.zip").is_file():
            parser.error(f"--resume {str(args.resume)!r} is not a checkpoint (model.zip missing)")
        if len(args.seed) != 1:
            parser.error("--resume continues one run: give a single --seed")


def hyperparams(args: argparse.Namespace) -> dict[str, Any]:
    import yaml

    from agents.training import load_hyperparams

    params = load_hyperparams(args.env, args.algo)
    if args.config is not None:
        extra = yaml.safe_load(args.config.read_text()) or {}
        env_kwargs = {**params.get("env_kwargs", {}), **extra.pop("env_kwargs", {})}
        params.update(extra)
        params["env_kwargs"] = env_kwargs
        if isinstance(params.get("policy_kwargs"), str):
            from agents.training import _eval_policy_kwargs

            params["policy_kwargs"] = _eval_policy_kwargs(params["policy_kwargs"])
    if args.timesteps is not None:
        params["n_timesteps"] = args.timesteps
    params["n_timesteps"] = int(params["n_timesteps"])
    return params


def train_one(args: argparse.Namespace, params: dict[str, Any], seed: int, run_dir: Path) -> Any:
    """Train (or resume) one seed; returns the trained agent's directory."""
    from stable_baselines3.common.callbacks import BaseCallback

    from agents.training import (
        WeightAverage,
        algo_kwargs,
        find_normalizer,
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
    )
    algo_cls = _algo_class(args.algo)
    ckpt_dir = run_dir / "checkpoints"
    critic_dims = critic_state_size(env.unwrapped.core.M) if critic_state else 0
    extra = {"env_id": args.env, "seed": seed, "critic_dims": critic_dims}
    if args.resume is not None:
        model = algo_cls.load(args.resume / "model.zip", env=env, device="cpu")
        _load_normalizer(find_normalizer(env), args.resume)
        done = model.num_timesteps
        print(f"resuming from {args.resume} at {done} steps")
    else:
        kwargs = algo_kwargs(params)
        policy = params["policy"]
        if critic_dims:
            from agents.asymmetric import AsymmetricActorCriticPolicy

            policy = AsymmetricActorCriticPolicy
            kwargs["policy_kwargs"] = {
                **kwargs.get("policy_kwargs", {}),
                "critic_dims": critic_dims,
                "frame_stack": frame_stack,
            }
        model = algo_cls(
            policy,
            env,
            seed=seed,
            device="cpu",
            verbose=0,
            tensorboard_log=str(run_dir / "tb"),
            **kwargs,
        )
        done = 0
    remaining = max(params["n_timesteps"] - done, 0)
    swa = None
    if params.get("swa_start") is not None:
        swa = WeightAverage(int(float(params["swa_start"]) * params["n_timesteps"]))
        if args.resume is not None:
            swa.load(args.resume)
    best_dir = run_dir / "best"
    best_file = best_dir / "validation.json"
    best = json.loads(best_file.read_text()) if best_file.is_file() else {"armse_pos": None}
    history: list[dict[str, float]] = best.get("history", [])

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

    def validate() -> None:
        """Score the live model on the validation runs; keep it in ``best/`` if it is the best."""
        armse = validation_score()
        history.append({"timesteps": int(model.num_timesteps), "armse_pos": armse})
        if best["armse_pos"] is None or armse < best["armse_pos"]:
            best.update(armse_pos=armse, timesteps=int(model.num_timesteps))
            save(best_dir)
        best["history"] = history
        best_dir.mkdir(parents=True, exist_ok=True)
        best_file.write_text(json.dumps(best, indent=2))

    class Checkpoint(BaseCallback):
        def __init__(self, every: int, validate_every: int) -> None:
            super().__init__()
            self.every, self.next = every, done + every
            self.validate_every = validate_every
            self.next_validation = done + validate_every

        def _on_rollout_start(self) -> None:
            if swa is not None:  # the weights after the previous update
                swa.update(model)

        def _on_training_end(self) -> None:
            if swa is not None:
                swa.update(model)

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next:
                self.next += self.every
                checkpoint("latest")
                if args.keep_checkpoints:
                    checkpoint(f"step_{self.num_timesteps}")
            if self.validate_every and self.num_timesteps >= self.next_validation:
                self.next_validation += self.validate_every
                validate()
            return True

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

    def checkpoint(name: str) -> None:
        """``checkpoints/NAME``: the live model and, once begun, the weight average."""
        save(ckpt_dir / name)
        if swa is not None:
            swa.save(ckpt_dir / name)

    start = time.perf_counter()
    try:
        model.learn(
            remaining,
            callback=Checkpoint(args.checkpoint_every, args.validate_every),
            progress_bar=not args.no_progress and sys.stderr.isatty(),
            reset_num_timesteps=args.resume is None,
            tb_log_name=f"{args.algo}_seed{seed}",
        )
    except KeyboardInterrupt:
        checkpoint("latest")
        print(
            f"\ninterrupted: checkpoint saved to {ckpt_dir / 'latest'} "
            f"({model.num_timesteps} steps); resume with --resume {ckpt_dir / 'latest'}"
        )
        raise SystemExit(130) from None
    seconds = time.perf_counter() - start
    checkpoint("latest")
    agent_dir = run_dir / "agent"
    if args.validate_every:
        validate()
    if swa is not None:
        swa.apply(model)
        selected = {"swa_start": swa.start, "snapshots": swa.snapshots}
        save(agent_dir, swa=selected)
        if args.validate_every:
            selected["armse_pos"] = validation_score()
    elif args.validate_every:
        if agent_dir.exists():
            shutil.rmtree(agent_dir)
        shutil.copytree(best_dir, agent_dir)
        selected = {k: v for k, v in best.items() if k != "history"}
    else:
        save(agent_dir)
        selected = {"timesteps": int(model.num_timesteps)}
    stats = {
        "timesteps": int(model.num_timesteps),
        "trained_this_call": remaining,
        "seconds": seconds,
        "fps": remaining / seconds if seconds > 0 else 0.0,
        "selected": selected,
        "validation": history,
    }
    (run_dir / "training.json").write_text(json.dumps(stats, indent=2))
    return agent_dir, stats


def _algo_class(algo: str) -> Any:
    if algo == "recurrent-ppo":
        from sb3_contrib import RecurrentPPO

        return RecurrentPPO
    from stable_baselines3 import PPO

    return PPO


def _load_normalizer(norm: Any, directory: Path) -> None:
    import numpy as np

    file = directory / "vecnormalize.json"
    if norm is None or not file.is_file():
        return
    stats = json.loads(file.read_text())
    norm.obs_rms.mean = np.array(stats["mean"])
    norm.obs_rms.var = np.array(stats["var"])
    norm.obs_rms.count = stats["count"]


def evaluate_agent(agent_dir: Path, args: argparse.Namespace, run_dir: Path) -> dict[str, Any]:
    """Paper scenario and held-out random scenarios, learned agent vs the baselines."""
    from agents.policy import load_agent
    from imm_gym.cli.evaluate import evaluate
    from imm_gym.cli.tables import render_tables
    from imm_gym.evaluation.plots import write_figures

    policy = load_agent(agent_dir)
    out: dict[str, Any] = {}
    for scenario, runs in (("paper", args.paper_runs), ("random", args.random_runs)):
        results, rollouts = evaluate(
            BASELINES_COMPARED,
            scenario,
            runs,
            seed=0,
            reference="best-fixed",
            extra={"learned": (policy, policy.env_overrides)},
        )
        results["vs_tip_imm"] = _paired(rollouts, "learned", "tip-imm")
        results["meta"]["scenario"] = scenario
        render_tables(results)
        write_figures(rollouts, run_dir / "plots" / scenario, results["meta"])
        out[scenario] = results
    return out


def _paired(rollouts: dict[str, Any], a: str, b: str) -> dict[str, float]:
    from imm_gym.evaluation.rollout import paired_bootstrap

    return paired_bootstrap(rollouts[a].squared_position_error, rollouts[b].squared_position_error)


def write_report(path: Path, results: dict[str, Any], header: list[str]) -> None:
    lines = [*header, ""]
    for scenario in ("paper", "random"):
        if scenario not in results:
            continue
        r = results[scenario]
        meta = r["meta"]
        lines += [
            f"## {scenario} scenario — {meta['runs']} runs, seeds {meta['seeds']}",
            "",
            "| policy | pos ARMSE (m) | X (m) | Y (m) | vel X (m/s) | vel Y (m/s) |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for name, row in r["policies"].items():
            lines.append(
                f"| {name} | {row['armse_pos']:.3f} | {row['armse_pos_x']:.3f} | "
                f"{row['armse_pos_y']:.3f} | {row['armse_vel_x']:.3f} | "
                f"{row['armse_vel_y']:.3f} |"
            )
        c = r["clairvoyant"]
        lines.append(
            f"| clairvoyant (bound) | {c['armse_pos']:.3f} | {c['armse_pos_x']:.3f} | "
            f"{c['armse_pos_y']:.3f} | {c['armse_vel_x']:.3f} | {c['armse_vel_y']:.3f} |"
        )
        lines += ["", "Paired differences of position ARMSE (95 % bootstrap CI):", ""]
        for name, d in r["paired"]["differences"].items():
            lines.append(
                f"- {name} − best-fixed: {d['diff']:+.3f} m [{d['low']:+.3f}, "
                f"{d['high']:+.3f}] ({100 * d['relative']:+.2f} %)"
            )
        d = r["vs_tip_imm"]
        lines += [
            f"- learned − tip-imm: {d['diff']:+.3f} m [{d['low']:+.3f}, {d['high']:+.3f}] "
            f"({100 * d['relative']:+.2f} %)",
            "",
        ]
    path.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    check_args(parser, args)
    set_threads(1)
    params = hyperparams(args)
    if params.get("critic_state") and args.algo != "ppo":
        parser.error(f"critic_state: true needs --algo ppo, got --algo {args.algo}")
    swa_start = params.get("swa_start")
    is_number = isinstance(swa_start, (int, float)) and not isinstance(swa_start, bool)
    if swa_start is not None and not (is_number and 0 <= swa_start < 1):
        parser.error(f"swa_start must be a fraction of the budget in [0, 1), got {swa_start!r}")
    args.out.mkdir(parents=True, exist_ok=True)
    command = " ".join(["python train.py", *(argv if argv is not None else sys.argv[1:])])
    versions = _versions()
    summary: dict[str, Any] = {"command": command, "versions": versions, "seeds": {}}
    for seed in args.seed:
        run_dir = args.out / f"seed_{seed}"
        run_dir.mkdir(parents=True, exist_ok=True)
        from agents.training import jsonable

        (run_dir / "config.json").write_text(
            json.dumps(
                {"env": args.env, "algo": args.algo, "seed": seed, "hyperparams": jsonable(params)},
                indent=2,
                default=str,
            )
        )
        agent_dir, stats = train_one(args, params, seed, run_dir)
        print(
            f"seed {seed}: {stats['timesteps']} steps in {stats['seconds']:.0f} s "
            f"({stats['fps']:.0f} steps/s)"
        )
        entry: dict[str, Any] = {"training": stats}
        if not args.no_eval:
            results = evaluate_agent(agent_dir, args, run_dir)
            entry.update(results)
            (run_dir / "results.json").write_text(json.dumps(results, indent=2))
            write_report(
                run_dir / "report.md",
                results,
                [
                    f"# {args.algo.upper()} on {args.env}, seed {seed}",
                    "",
                    f"Command: `{command}`. Training: {stats['timesteps']} steps in "
                    f"{stats['seconds']:.0f} s ({stats['fps']:.0f} steps/s, SB3 on 1 thread).",
                    f"Agent: {_describe_selection(stats['selected'])}.",
                    f"Versions: {versions}.",
                ],
            )
        summary["seeds"][str(seed)] = entry
    if not args.no_eval:
        summary["across_seeds"] = _across_seeds(summary["seeds"])
        _write_summary_report(args.out / "report.md", summary)
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"wrote {args.out}")
    return 0


def _describe_selection(selected: dict[str, Any]) -> str:
    """How the evaluated policy was obtained, from ``training.json``'s ``selected``."""
    score = selected.get("armse_pos")
    validation = "" if score is None else f", validation ARMSE {score:.3f} m"
    if "swa_start" in selected:
        return (
            f"the mean of the weights after every update from step {selected['swa_start']} on "
            f"({selected['snapshots']} updates){validation}"
        )
    if score is not None:
        return f"the best validated checkpoint, at step {selected['timesteps']}{validation}"
    return f"the last iterate, at step {selected['timesteps']}"


def _across_seeds(seeds: dict[str, Any]) -> dict[str, Any]:
    import numpy as np

    out: dict[str, Any] = {}
    for scenario in ("paper", "random"):
        learned = [s[scenario]["policies"]["learned"]["armse_pos"] for s in seeds.values()]
        vs_best = [
            s[scenario]["paired"]["differences"]["learned"]["relative"] for s in seeds.values()
        ]
        vs_tip = [s[scenario]["vs_tip_imm"]["relative"] for s in seeds.values()]
        out[scenario] = {
            "armse_pos_mean": float(np.mean(learned)),
            "armse_pos_std": float(np.std(learned, ddof=1)) if len(learned) > 1 else 0.0,
            "relative_vs_best_fixed_mean": float(np.mean(vs_best)),
            "relative_vs_tip_imm_mean": float(np.mean(vs_tip)),
            "per_seed_armse_pos": learned,
        }
    return out


def _write_summary_report(path: Path, summary: dict[str, Any]) -> None:
    lines = ["# Training summary", "", f"Command: `{summary['command']}`", ""]
    for scenario, s in summary["across_seeds"].items():
        lines += [
            f"## {scenario}",
            "",
            f"Learned position ARMSE over seeds: {s['armse_pos_mean']:.3f} ± "
            f"{s['armse_pos_std']:.3f} m (per seed: "
            f"{', '.join(f'{v:.3f}' for v in s['per_seed_armse_pos'])}); mean relative difference "
            f"vs best fixed {100 * s['relative_vs_best_fixed_mean']:+.2f} %, vs TIP-IMM "
            f"{100 * s['relative_vs_tip_imm_mean']:+.2f} %.",
            "",
        ]
    path.write_text("\n".join(lines))


def _versions() -> dict[str, str]:
    import gymnasium
    import numpy
    import stable_baselines3
    import torch

    return {
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "gymnasium": gymnasium.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "torch": torch.__version__,
    }


if __name__ == "__main__":
    raise SystemExit(main())
