"""What ``python train.py`` settles before any work: its command line (:func:`build_parser`),
the arguments checked (:func:`check_args`: usage errors, status 2, before a directory is made or
a step is trained) and the run's hyperparameters they resolve (:func:`hyperparams`: the YAML
entry of ``--env``, or another id's on its preset, a ``--config`` file over it, the
``--env-config`` files' trackers, or a ``--resume`` checkpoint's, checked against every
configuration they train on).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

from agents.policy import ALGOS
from agents.training import DEFAULT_ENTRY, MAX_SEED

ENGINES = ("sb3", "rllib")
#: Where a run is written without ``--out`` (and without ``--resume``: then the checkpoint's run).
DEFAULT_OUT = Path("runs/default")


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows an option's default where it has one (not for the None of "see the help")."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None:
            return action.help
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python train.py",
        description="Train a PPO agent to adapt the IMM's TPM, then evaluate it.",
        formatter_class=_HelpFormatter,
    )
    p.add_argument(
        "--env",
        help=f"registered imm_gym environment id ({DEFAULT_ENTRY}; with --resume the "
        "checkpoint's); an id without a hyperparameter entry of its own trains on its preset with "
        "the default entry's hyperparameters and agent settings (not its trackers, targets and "
        "mixture)",
    )
    p.add_argument("--algo", choices=ALGOS, help="algorithm (ppo; with --resume the checkpoint's)")
    p.add_argument("--timesteps", type=int, help="training steps (default: the YAML entry's)")
    p.add_argument(
        "--seed",
        type=int,
        nargs="+",
        help=f"training seed(s), each in [0, {MAX_SEED}] (0; with --resume the checkpoint's)",
    )
    p.add_argument(
        "--config",
        type=Path,
        help="YAML file with hyperparameters overriding the entry (its env_kwargs and "
        "policy_kwargs key by key), its env_kwargs' reward and agent settings over every part of "
        "the entry's env_mixture too unless it gives env_mixture (with --resume: only the "
        "budget, n_timesteps)",
    )
    p.add_argument(
        "--env-config",
        type=Path,
        nargs="+",
        metavar="FILE",
        help="YAML or JSON file of EnvConfig fields (scenario, family, sensor, bank, filter, ...) "
        "applied over the entry's env_kwargs and recorded in the agent; several files: training "
        "across trackers, each file's configuration on its share of the slots (--env-shares; "
        "the first file's is recorded, validated and evaluated)",
    )
    p.add_argument(
        "--env-shares",
        type=float,
        nargs="+",
        metavar="W",
        help="with several --env-config files: each file's weight in the slots (default: equal)",
    )
    p.add_argument(
        "--out",
        type=Path,
        help=f"output directory (default: {DEFAULT_OUT}; with --resume, the run the checkpoint "
        "belongs to: OUT of OUT/seed_S/checkpoints/NAME); an OUT/seed_S/ of a seed to train is "
        "refused, but for the resumed run's own",
    )
    p.add_argument(
        "--resume",
        type=Path,
        help="checkpoint directory to continue from (OUT/seed_S/checkpoints/latest or step_N); "
        "the run is written back to OUT unless --out is given",
    )
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
        help="steps between validations, the best validated policy kept in best/ (0: none). "
        "With --engine sb3 the agent is the weight average when the hyperparameters set "
        "swa_start (the default entry does); otherwise the best validated policy (with 0: the "
        "last)",
    )
    p.add_argument(
        "--validation-runs",
        type=int,
        default=200,
        help="runs per validation (seeds 50,000,000+; at most 50,000,000: below the training "
        "seeds)",
    )
    p.add_argument(
        "--paper-runs",
        type=int,
        default=100,
        help="runs of the paper scenario in the evaluation after training (seeds 0..N-1; one "
        "run gives no confidence intervals)",
    )
    p.add_argument(
        "--random-runs",
        type=int,
        default=1000,
        help="held-out runs of the randomized family (the first --env-config file's) in the "
        "evaluation after training (seeds 0..R-1; training uses seeds from 100,000,000 on)",
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=1,
        metavar="N",
        help="train (and evaluate) N seeds at a time, each in its own process (one torch thread "
        "each; a seed's agent is the one it gets alone); with N > 1 no progress bar",
    )
    p.add_argument("--no-eval", action="store_true", help="train only")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--engine",
        choices=ENGINES,
        default="sb3",
        help="sb3: stable-baselines3 in this process; rllib: Ray RLlib's PPO (needs the ray "
        "optional group; no resumable checkpoints)",
    )
    p.add_argument(
        "--ray-address",
        metavar="ADDR",
        help="--engine rllib: the Ray cluster to join (auto, or HOST:PORT of `ray start --head`);"
        " default: a local Ray instance",
    )
    p.add_argument(
        "--env-runners",
        type=int,
        default=1,
        metavar="K",
        help="--engine rllib: env runners sampling in parallel, one CPU each (0: the driver "
        "samples; at most the Ray cluster's CPUs)",
    )
    return p


def check_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict[str, Any] | None:
    """Reject bad arguments (usage error, status 2) before any work; fill in ``--env``,
    ``--algo``, ``--seed`` and ``--out`` (from the checkpoint with ``--resume``). Returns the
    checkpoint's checked ``resume.json``, or None."""
    from agents.checkpoint import read_checkpoint
    from imm_gym.envs import PRESETS
    from imm_gym.validation import ConfigError

    resume = None
    if args.resume is not None:
        try:
            resume = read_checkpoint(args.resume)
        except ConfigError as err:
            parser.error(f"--resume {err}")
        for name, value, recorded in (
            ("--env", args.env, resume["env_id"]),
            ("--algo", args.algo, resume["algo"]),
            ("--seed", args.seed, [resume["seed"]]),
        ):
            if value is not None and value != recorded:
                shown = " ".join(map(str, value)) if isinstance(value, list) else value
                was = " ".join(map(str, recorded)) if isinstance(recorded, list) else recorded
                parser.error(
                    f"--resume {str(args.resume)!r} continues a run started with {name} {was}; "
                    f"got {name} {shown} (leave {name} out to continue it)"
                )
        args.env, args.algo, args.seed = resume["env_id"], resume["algo"], [resume["seed"]]
        if args.out is None:
            args.out = checkpoint_run(args.resume, resume["seed"])
            if args.out is None:
                parser.error(
                    f"--resume {str(args.resume)!r} is not in a run directory "
                    f"(OUT/seed_{resume['seed']}/checkpoints/NAME): give --out"
                )
    args.out = DEFAULT_OUT if args.out is None else args.out
    args.env = DEFAULT_ENTRY if args.env is None else args.env
    args.algo = "ppo" if args.algo is None else args.algo
    args.seed = [0] if args.seed is None else args.seed
    ids = sorted(PRESETS)
    if not args.env.startswith("imm_gym/"):
        parser.error(f"--env {args.env!r} is not an imm_gym environment; available: {ids}")
    if args.env not in PRESETS:
        parser.error(f"--env {args.env!r} is not registered; available: {ids}")
    if args.timesteps is not None and args.timesteps < 1:
        parser.error(f"--timesteps must be >= 1, got {args.timesteps}")
    if not all(0 <= s <= MAX_SEED for s in args.seed) or len(set(args.seed)) != len(args.seed):
        parser.error(
            f"--seed values must be distinct integers in [0, {MAX_SEED}] (2**32 - 1: numpy's "
            f"global generator is seeded with each), got {' '.join(map(str, args.seed))}"
        )
    if args.jobs < 1:
        parser.error(f"--jobs must be >= 1, got {args.jobs}")
    if args.jobs > 1 and args.engine == "rllib":
        parser.error("--jobs is for --engine sb3; RLlib runs its own workers (--env-runners)")
    if args.checkpoint_every < 1:
        parser.error(f"--checkpoint-every must be >= 1, got {args.checkpoint_every}")
    if args.validate_every < 0:
        parser.error(f"--validate-every must be >= 0, got {args.validate_every}")
    check_runs(parser, args)
    if args.config is not None and not args.config.is_file():
        parser.error(f"--config file {str(args.config)!r} does not exist")
    if args.engine == "rllib":
        if args.resume is not None:
            parser.error("--resume continues SB3 runs; --engine rllib writes no checkpoints")
        if args.algo != "ppo":
            parser.error(f"--engine rllib trains --algo ppo, got --algo {args.algo}")
        if args.env_runners < 0:
            parser.error(f"--env-runners must be >= 0, got {args.env_runners}")
        try:
            import ray  # noqa: F401
        except ImportError:
            parser.error("--engine rllib needs Ray: pip install -e '.[ray]' (make install-ray)")
    elif args.ray_address is not None or args.env_runners != 1:
        parser.error("--ray-address and --env-runners apply to --engine rllib")
    args.env_overrides, args.env_mixture = {}, []
    if resume is not None and resume["evaluation_config"] is not None:
        # the files the run was started with, which --resume needs not be given again
        args.env_overrides = dict(resume["evaluation_config"])
    files = args.env_config or []
    if args.env_shares is not None:
        if len(files) < 2 or len(args.env_shares) != len(files):
            parser.error(
                f"--env-shares gives one weight per --env-config file (two or more files); got "
                f"{len(args.env_shares)} weights for {len(files)} file(s)"
            )
        if not all(0.0 < w < float("inf") for w in args.env_shares):
            parser.error(f"--env-shares must be positive numbers, got {args.env_shares}")
    if files:
        from imm_gym.sim.config_file import read_env_config

        try:
            overrides = [read_env_config(f) for f in files]
        except ConfigError as err:
            parser.error(f"--env-config {err}")
        weights = args.env_shares or [1.0] * len(files)
        shares = [w / sum(weights) for w in weights]
        args.env_overrides = overrides[0]
        args.env_mixture = [
            {"env_kwargs": o, "share": w} for o, w in zip(overrides[1:], shares[1:], strict=True)
        ]
    check_out(parser, args)
    return resume


def check_runs(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse (usage error) run counts whose seeds would reach another range
    (:mod:`imm_gym.seeding`): the evaluation's ``0 .. R - 1`` below the tuners' training seeds
    (:data:`imm_gym.cli.arguments.MAX_RUNS`), the validation's ``VALIDATION_SEED_BASE + r``
    below the agents' training slots (``TRAIN_SEED_BASE``)."""
    from imm_gym.cli.arguments import MAX_RUNS
    from imm_gym.seeding import TRAIN_SEED_BASE, VALIDATION_SEED_BASE

    most = TRAIN_SEED_BASE - VALIDATION_SEED_BASE
    if not 1 <= args.validation_runs <= most:
        parser.error(
            f"--validation-runs must be in [1, {most}], got {args.validation_runs}: the "
            f"validation seeds {VALIDATION_SEED_BASE} + r stay below the training seeds "
            f"({TRAIN_SEED_BASE}+)"
        )
    for flag, runs in (("--paper-runs", args.paper_runs), ("--random-runs", args.random_runs)):
        if not 1 <= runs <= MAX_RUNS:
            parser.error(
                f"{flag} must be in [1, {MAX_RUNS}], got {runs}: the evaluation seeds 0 .. "
                f"{flag[2:].upper().replace('-', '_')} - 1 stay below the tuners' training seeds "
                f"({MAX_RUNS}+)"
            )


def check_out(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse (usage error) an ``--out`` that is not a directory, or that holds ``seed_S/`` for a
    seed to be trained — unless it is the run a ``--resume`` checkpoint belongs to: a new run
    written there would pick up the earlier run's state (its ``best/`` validation record, which
    would select its network as the new agent) and leave its files (``report.md``,
    ``results.json``) beside the new agent."""
    out = args.out
    existing = next((p for p in (out, *out.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        parser.error(
            f"--out {str(out)!r}: {str(existing)!r} is a file, not a directory; give a directory "
            "(absent, or holding other runs)"
        )
    resumed = None if args.resume is None else Path(os.path.abspath(args.resume)).parent.parent
    for seed in args.seed:
        run = out / f"seed_{seed}"
        if not run.exists() or (resumed is not None and run.resolve() == resumed.resolve()):
            continue
        latest = run / "checkpoints" / "latest"
        resume = (
            f"; to continue that run: python train.py --resume {latest}"
            if (latest / "resume.json").is_file() and args.resume is None
            else ""
        )
        parser.error(
            f"--out {str(out)!r} already holds {run} (an earlier run; a new one would pick up its "
            f"state): give another --out, or remove {run}{resume}"
        )


def on_preset(params: dict[str, Any], env_id: str) -> dict[str, Any]:
    """Another id's hyperparameter entry ``params`` for ``env_id``, which has none: its trackers,
    targets and mixture (written for its own id's environment) give way to ``env_id``'s preset,
    applied over what the entry trains the agent as (its
    :data:`~imm_gym.sim.mixture.AGENT_FIELDS`), the preset's observation features after the
    entry's — so that the run trains on the environment it names (``TPMAdaptPaper-v0``: the
    paper scenario; ``TPMAdaptParallel-v0``: the parallel bank, observed too; ``TPMAdaptHetero-v0``:
    the heterogeneous bank)."""
    from agents.training import jsonable
    from imm_gym.envs import PRESETS

    kept = _agent_fields(params.get("env_kwargs", {}))
    preset = jsonable(PRESETS[env_id])
    env_kwargs = {**kept, **preset}
    if "obs_features" in kept and "obs_features" in preset:
        features = list(kept["obs_features"])
        env_kwargs["obs_features"] = features + [
            f for f in preset["obs_features"] if f not in features
        ]
    params = {k: v for k, v in params.items() if k != "env_mixture"}
    return {**params, "env_kwargs": env_kwargs}


def with_config(params: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    """The hyperparameters ``params`` with a ``--config`` file's checked ``extra`` over them: its
    ``env_kwargs`` and ``policy_kwargs`` key by key over the entry's (one level: a key given,
    such as ``net_arch``, replaces the entry's whole; the entry's other keys stay), and those
    saying what the agent is trained as
    (:data:`~imm_gym.sim.mixture.AGENT_FIELDS`: a reward, what the policy reads and writes) over
    every part of the entry's ``env_mixture`` too — its trackers and targets, which the parts are
    there to vary, stay each part's own — unless the file gives its own ``env_mixture``, which is
    then taken as it stands."""
    extra = dict(extra)
    changes = extra.pop("env_kwargs", {})
    updated = {**params, **extra}
    if changes or "env_kwargs" in params:  # none added where neither gives one
        updated["env_kwargs"] = {**params.get("env_kwargs", {}), **changes}
    if "policy_kwargs" in extra:
        updated["policy_kwargs"] = {**params.get("policy_kwargs", {}), **extra["policy_kwargs"]}
    shared = _agent_fields(changes)
    if shared and "env_mixture" not in extra and "env_mixture" in params:
        updated["env_mixture"] = [
            {**part, "env_kwargs": {**part["env_kwargs"], **shared}}
            for part in params["env_mixture"]
        ]
    return updated


def _agent_fields(kwargs: dict[str, Any]) -> dict[str, Any]:
    """The fields of ``kwargs`` that say what the agent is trained as
    (:data:`imm_gym.sim.mixture.AGENT_FIELDS`)."""
    from imm_gym.sim.mixture import AGENT_FIELDS

    return {k: v for k, v in kwargs.items() if k in AGENT_FIELDS}


def checkpoint_run(checkpoint: Path, seed: int) -> Path | None:
    """The run directory ``OUT`` a checkpoint ``OUT/seed_S/checkpoints/NAME`` of seed ``S``
    belongs to (relative to the working directory where it lies below it), or None where the
    checkpoint lies elsewhere."""
    path = Path(os.path.abspath(checkpoint))
    if path.parent.name != "checkpoints" or path.parent.parent.name != f"seed_{seed}":
        return None
    out = path.parents[2]
    try:
        return out.relative_to(Path.cwd())
    except ValueError:
        return out


def hyperparams(args: argparse.Namespace, resume: dict[str, Any] | None) -> dict[str, Any]:
    """The run's checked hyperparameters: the YAML entry of ``--env`` (or the default entry,
    which is said) updated by ``--config``, or the checkpoint's with ``--resume`` (a ``--config``
    may then change only the budget); ``--timesteps`` sets the budget.

    Raises:
        ConfigError: a file is malformed, ``--config`` changes a resumed run, or a resumed run's
            budget is not above the checkpoint's step count.
    """
    from agents.training import (
        check_batches,
        check_hyperparams,
        check_input_size,
        check_policy,
        jsonable,
        load_hyperparams,
        read_yaml,
    )
    from imm_gym.envs import PRESETS
    from imm_gym.sim.env_config import EnvConfig
    from imm_gym.sim.mixture import check_parts
    from imm_gym.validation import ConfigError

    budget_from = "the checkpoint"
    if resume is not None:
        params = dict(resume["hyperparams"])
    else:
        params, entry = load_hyperparams(args.env, args.algo)
        if entry != args.env:
            params = on_preset(params, args.env)
            if not args.env_config:  # the evaluation after training runs on the preset's tracker
                args.env_overrides = jsonable(PRESETS[args.env])
            print(
                f"no hyperparameter entry for {args.env}: using the {entry} entry on its "
                f"preset ({', '.join(PRESETS[args.env])}; the entry's trackers, targets and "
                "mixture left out, what it trains the agent as kept, the preset's observation "
                "features added to the entry's)",
                flush=True,
            )
    if args.config is not None:
        extra = check_hyperparams(
            str(args.config), read_yaml(args.config), args.algo, complete=False
        )
        updated = with_config(params, extra)
        budget_from = "--config" if "n_timesteps" in extra else budget_from
        if resume is not None:
            changed = sorted(
                k
                for k in set(updated) | set(params)
                if k != "n_timesteps" and updated.get(k) != params.get(k)
            )
            if changed:
                raise ConfigError(
                    f"--config {args.config} changes {changed} of the resumed run; --resume "
                    "continues with the checkpoint's hyperparameters (only the budget, "
                    "n_timesteps or --timesteps, may change)"
                )
        params = updated
    if args.timesteps is not None:
        params["n_timesteps"] = args.timesteps
    if resume is not None and params["n_timesteps"] <= resume["num_timesteps"]:
        given = (
            f"--timesteps {args.timesteps}"
            if args.timesteps is not None
            else f"the budget {params['n_timesteps']} (n_timesteps of {budget_from})"
        )
        raise ConfigError(
            f"{given} is not above the {resume['num_timesteps']} steps the checkpoint "
            f"{args.resume} was trained for: --resume trains on to a larger budget (give "
            f"--timesteps N with N > {resume['num_timesteps']})"
        )
    if args.env_config:
        files = [args.env_overrides, *(part["env_kwargs"] for part in args.env_mixture)]
        shares = [part["share"] for part in args.env_mixture]
        if resume is not None:
            # a start with these files recorded each part as the agent settings it kept from the
            # entry (those the file does not set) with the file's fields over them
            recorded = [params.get("env_kwargs", {})]
            recorded += [part["env_kwargs"] for part in params.get("env_mixture", [])]
            differ = [
                str(name)
                for name, file, kwargs in zip(args.env_config, files, recorded, strict=False)
                if jsonable({**_agent_fields(kwargs), **file}) != jsonable(kwargs)
            ]
            recorded_shares = [part["share"] for part in params.get("env_mixture", [])]
            reasons = [f"{name} is not the configuration the run recorded" for name in differ]
            if len(files) != len(recorded):
                reasons.append(f"{len(files)} file(s) for its {len(recorded)} configuration(s)")
            elif shares != recorded_shares:
                reasons.append(f"shares {shares} of the further files, not {recorded_shares}")
            if reasons:
                raise ConfigError(
                    f"--env-config {' '.join(map(str, args.env_config))} changes the environment "
                    f"of the resumed run ({'; '.join(reasons)}); --resume continues with the "
                    "checkpoint's (give the files and --env-shares it was started with, or leave "
                    "--env-config out)"
                )
        else:
            # the files replace the entry's trackers and targets (and its mixture): only what the
            # agent is trained as stays from the entry
            kept = _agent_fields(params.get("env_kwargs", {}))
            params = {k: v for k, v in params.items() if k != "env_mixture"}
            params["env_kwargs"] = jsonable({**kept, **files[0]})
            if args.env_mixture:
                params["env_mixture"] = [
                    {"env_kwargs": jsonable({**kept, **file}), "share": share}
                    for file, share in zip(files[1:], shares, strict=True)
                ]
    parts = [("env_kwargs", params.get("env_kwargs", {}))] + [
        (f"env_mixture[{i}].env_kwargs", part["env_kwargs"])
        for i, part in enumerate(params.get("env_mixture", []))
    ]
    configs = []
    for where, kwargs in parts:
        try:
            configs.append(EnvConfig.build({**PRESETS[args.env], **kwargs}))
        except ConfigError as err:
            raise ConfigError(f"{where} of the hyperparameters: {err}") from None
    check_parts(configs)
    check_policy(params, configs)
    check_input_size(params, configs[0])
    check_batches(params)
    return params

