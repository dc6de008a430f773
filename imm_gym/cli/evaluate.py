"""Monte-Carlo evaluation of TPM policies (command line: ``python -m imm_gym.evaluate``).

Every policy — a baseline by name or a saved stable-baselines3 model by path — runs through
:func:`imm_gym.evaluation.rollout.rollout` on the same R runs: same targets, same sensor noise
(common random numbers). The report follows the paper's Table 2 (position ARMSE overall / X / Y,
velocity ARMSE X / Y) and adds NIS/NEES consistency, mode-identification accuracy, the
mode-probability total variation, the peak error and the maneuver response, the clairvoyant
filter (a bound where no policy beats it, else a reference; skipped, with the reason, where it
cannot follow the scenario) and paired differences with 95 % bootstrap confidence intervals
against a reference policy. This module is the command line: it checks the arguments
(:mod:`imm_gym.cli.arguments`), runs :func:`imm_gym.cli.comparison.evaluate` (one
configuration) or :func:`imm_gym.cli.suite.evaluate_suite` (``--suite``) on the policies that
:mod:`imm_gym.cli.policies` resolves, and prints and writes the results.

Example::

    python -m imm_gym.evaluate --policy fixed --policy tip-imm --policy best-fixed \\
        --scenario paper --runs 100 --seed 0 --json out.json --plots figs/

``--json`` writes ``{"policies": {NAME: {"armse_pos": ..., "armse_pos_x": ..., "armse_pos_y": ...,
"armse_vel_x": ..., "armse_vel_y": ..., ...}}, "clairvoyant": {...}, "paired": {...},
"meta": {...}}``; with ``--runs 1`` the paired differences' confidence bounds ``low`` and
``high`` are null (undefined). ``--json`` and ``--plots`` are checked before anything is evaluated:
an output that cannot be written is a usage error (exit 2).

``--agent-seeds DIR DIR ...`` evaluates the training seeds of one agent, each as a policy, and
adds their interquartile means with stratified bootstrap CIs (:mod:`imm_gym.cli.seeds`; JSON
``"across_seeds"``).

The best fixed TPM is searched on training runs whose seeds (``seed + 1_000_000 + r``) never
overlap the evaluation seeds: ``--runs`` is at most 1 000 000, and ``--seed`` at most
:data:`~imm_gym.cli.arguments.MAX_SEED` (48 999 900), so that the evaluation and tuning seeds
stay below the agents' validation seeds (50 000 000+) and training slots (100 000 000+); outside,
a usage error.

``--ray [ADDR]`` runs the tracking of every roll-out (the best-fixed search's too) in chunks of
runs on a Ray cluster (:mod:`imm_gym.evaluation.distributed`; ``ADDR``: ``auto`` or
``HOST:PORT``, default Ray's: ``RAY_ADDRESS``, a running local cluster, else a new local
instance); every number is the single-process one. Ray is imported only then.

``--env-config FILE`` (YAML or JSON, :mod:`imm_gym.sim.config_file`) sets the EnvConfig of every
policy — baselines, the best-fixed search and trained agents —; ``--scenario``, when given,
replaces the file's scenario and ``--bank`` its bank and filter. A trained agent runs on the
evaluated tracker (sensor, bank, filter) with its own settings (action mode, features...); the
JSON gives its ``trained_on`` and ``evaluated_on`` trackers and ``tracker_differs`` (the fields that
differ, also said under the table), ``models_differ`` where the evaluated bank's models stand for
others than the trained banks' (said too: the agent reads them as its own), and ``meta.env_config``
the file and what it said, ``{"file": PATH, "overrides": {...}}`` (its EnvConfig overrides as
read, before ``--scenario`` and ``--bank``: the record re-runs with ``meta.command`` after the file
is edited; the overrides alone when called from Python; the paper's Table 2 rows are printed only
without one, on the paper scenario with the paper's bank and filter); an agent whose observation or
action size the evaluated configuration does not give is refused before any work.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from agents.policy import agent_directory
from baselines import REGISTRY
from imm_gym.cli.arguments import output_problem, seed_problem
from imm_gym.cli.comparison import (
    BANKS,
    OPTIONAL_PACKAGES,
    config_record,
    evaluate,
    evaluated_config,
    load_source,
)
from imm_gym.cli.provenance import record_json, versions
from imm_gym.cli.suite import evaluate_suite
from imm_gym.cli.tables import render_tables
from imm_gym.evaluation.distributed import ShardError
from imm_gym.evaluation.rollout import Rollout, evaluation_config, rollout, score
from imm_gym.papers.systems import SYSTEMS
from imm_gym.scenarios.catalog import SCENARIOS, SUITES
from imm_gym.sim.config_file import bank_name, expand_presets, read_env_config
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.tracking.tpm import stay_tpm
from imm_gym.validation import ConfigError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m imm_gym.evaluate",
        description="Monte-Carlo evaluation of TPM policies with common random numbers.",
    )
    parser.add_argument(
        "--policy",
        action="append",
        default=[],
        help="policy to evaluate (repeatable; at least one, or --agent-seeds): "
        + "; ".join(f"{name}: {entry.help}" for name, entry in REGISTRY.items()).replace("%", "%%")
        + "; pretrained: the shipped PPO policy (five seeds' mean action, banks of three models); "
        "pretrained-per-model: the shipped policy shared by the models (banks of any size); or a "
        "trained agent's or an ensemble's directory",
    )
    parser.add_argument(
        "--scenario",
        help=" | ".join((*SCENARIOS, "random"))
        + " | a scenario JSON file | seed002 | seed003 (the NCV/CT/CTRA IMM-EKF "
        "of seed 002, the CV/CA/CT bank of seed 003; policies fixed, bbsca, sca); default: "
        "the --env-config file's scenario, else paper",
    )
    parser.add_argument(
        "--suite",
        metavar="NAME|DIR",
        help="evaluate on every scenario of the suite ("
        + "; ".join(f"{k}: {', '.join(v)}" for k, v in SUITES.items())
        + "), each with its configuration file (imm_gym/scenarios/suite/NAME.yaml), or on every "
        "configuration file (.yaml, .yml, .json) of the directory DIR (e.g. examples/probes), "
        "and print one table with, per policy, the cases below, level with and above the "
        "reference; a policy that cannot run on a case (an agent that cannot read its tracker, "
        "a rule whose settings it does not admit) is not run there, and the table says so",
    )
    parser.add_argument(
        "--env-config",
        type=Path,
        metavar="FILE",
        help="YAML or JSON file of EnvConfig fields (scenario, family, sensor, bank, filter, "
        "...) every policy runs on; --scenario replaces its scenario, --bank its bank and filter",
    )
    parser.add_argument("--runs", type=int, default=100, help="Monte-Carlo runs (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="run r uses seed + r (default 0)")
    parser.add_argument("--reference", help="policy the paired differences are taken against")
    parser.add_argument(
        "--agent-seeds",
        nargs="+",
        default=[],
        metavar="DIR",
        help="training seeds of one agent (two or more directories): each is evaluated as a "
        "policy, and their interquartile means with stratified bootstrap CIs are added (position "
        "ARMSE, mode accuracy, relative difference against --reference; with --suite also over "
        "all scenarios; JSON: \"across_seeds\")",
    )
    parser.add_argument(
        "--bar",
        nargs="+",
        default=[],
        metavar="POLICY",
        help="with --suite: on each case the better of these policies (the lower position ARMSE "
        "on its runs; added to --policy if absent) is the bar every other policy is tallied "
        "against, with paired 95%% CIs (JSON: \"bar\" per case, \"tally\"); e.g. --bar "
        "tip-imm best-fixed (--agent-seeds' relative differences stay against --reference)",
    )
    parser.add_argument("--json", type=Path, help="write the results to this JSON file")
    parser.add_argument("--plots", type=Path, help="write PNG figures to this directory")
    parser.add_argument(
        "--tradeoff",
        type=Path,
        metavar="FILE",
        help="write a PNG of position ARMSE against mode accuracy: every policy beside the "
        "classical IMM at each stay of the best-fixed grid (1/3 ... 0.999), on the same runs "
        "(their scores also go to the JSON, under \"tradeoff\")",
    )
    parser.add_argument("--no-clairvoyant", action="store_true", help="skip the clairvoyant bound")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument(
        "--bank",
        help=" | ".join(BANK_PRESETS)
        + " (default: the --env-config file's bank, else paper; paper: CV, CT(±4°/s), "
        "SVD-UKF; hetero: the NCV/CT/CTRA IMM-EKF of seed 002; "
        "cv-ct-continuous: the paper's models with white-noise-acceleration intensities)",
    )
    parser.add_argument(
        "--tuned",
        action="append",
        default=[],
        metavar="POLICY=FILE",
        help="seed scenarios: load the tuned bank of bbsca/sca from FILE instead of tuning",
    )
    parser.add_argument(
        "--animate",
        type=Path,
        metavar="FILE",
        help="write an animation of run 0 (seed --seed), every policy side by side on the same "
        "target and noise: FILE.gif (Pillow) or FILE.mp4 (needs ffmpeg)",
    )
    parser.add_argument(
        "--ray",
        nargs="?",
        const="",
        metavar="ADDR",
        help="run the tracking in chunks of runs on a Ray cluster (pip install -e '.[ray]'): "
        "ADDR auto or HOST:PORT, default Ray's (RAY_ADDRESS, a running local cluster, else a "
        "new local instance); the same numbers as without",
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    args.argv = argv
    problem = seed_problem(args.seed, args.runs)
    if problem:
        parser.error(problem)
    outputs = (("--json", args.json, "file"), ("--plots", args.plots, "directory"),
               ("--tradeoff", args.tradeoff, "file"))
    for flag, path, kind in outputs:
        problem = None if path is None else output_problem(path, kind)
        if problem:
            parser.error(f"{flag} {str(path)!r}: {problem}")
    if args.tradeoff is not None and args.tradeoff.suffix.lower() != ".png":
        # matplotlib takes the format from the suffix: '.txt' failed after the evaluation
        parser.error(f"--tradeoff {str(args.tradeoff)!r}: the figure is a PNG, end it in .png")
    _check_animate(parser, args)
    if len(args.agent_seeds) == 1:
        parser.error("--agent-seeds needs two or more directories (one is a --policy)")
    # the directory the loader reads, resolved: 'dir', 'dir/', './dir' and 'dir/agent.json' are
    # one seed, whose IQM would have zero-width CIs
    seed_dirs = [agent_directory(d).resolve() for d in args.agent_seeds]
    if len(set(seed_dirs)) != len(seed_dirs):
        parser.error(f"--agent-seeds given a directory twice: {args.agent_seeds}")
    # a --policy or --reference naming a seed's directory otherwise spelled is that seed
    spelling = dict(zip(seed_dirs, args.agent_seeds, strict=True))
    args.policy = [spelling.get(agent_directory(p).resolve(), p) for p in args.policy]
    if args.reference is not None:
        args.reference = spelling.get(agent_directory(args.reference).resolve(), args.reference)
    if args.bar and args.suite is None:
        parser.error("--bar applies to --suite")
    if args.tuned and args.scenario not in SYSTEMS:
        parser.error(f"--tuned applies to --scenario {'|'.join(SYSTEMS)}")
    if args.reference is not None and args.reference in args.agent_seeds:
        parser.error(
            f"--reference {args.reference} is one of --agent-seeds: the seeds are compared with a "
            "policy outside them"
        )
    args.policy += [d for d in args.bar if d not in args.policy]
    args.policy += [d for d in args.agent_seeds if d not in args.policy]
    if not args.policy:
        parser.error("give at least one --policy (or --agent-seeds)")
    seeds_only = args.agent_seeds and args.policy[0] in args.agent_seeds
    if seeds_only and args.reference is None and args.scenario not in SYSTEMS:
        parser.error(
            "--agent-seeds needs a reference outside the seeds: give --reference NAME (a "
            "--policy of its own)"
        )
    if args.ray is not None and args.scenario in SYSTEMS:
        parser.error(f"--ray does not apply to --scenario {args.scenario}")
    make_core = _cores(parser, args.ray)
    try:
        return _run(parser, args, make_core)
    except ShardError as err:
        # a shard that died mid-run (its process or node ended): one line, not Ray's traceback
        parser.exit(1, f"{parser.prog}: error: {err}\n")


def _run(
    parser: argparse.ArgumentParser,
    args: argparse.Namespace,
    make_core: Callable[[EnvConfig, int], Any],
) -> int:
    """The checked command line's evaluation: a suite, a seed system, or one scenario's."""
    if args.suite is not None:
        return _main_suite(parser, args, make_core)
    if args.scenario in SYSTEMS:
        return _main_system(parser, args)
    try:
        file_config = None if args.env_config is None else read_env_config(args.env_config)
        overrides = _run_config(args, file_config)
        scenario = overrides.pop("scenario")
        results, rollouts = evaluate(
            args.policy,
            scenario,
            args.runs,
            args.seed,
            reference=args.reference,
            clairvoyant=not args.no_clairvoyant,
            progress=not args.quiet and sys.stderr.isatty(),
            env_config=overrides,
            make_core=make_core,
        )
    except ConfigError as err:
        parser.error(str(err))
    results["meta"]["bank"] = bank_name(overrides)
    results["meta"]["env_config"] = config_record(args.env_config, file_config)
    if args.scenario is not None:
        results["meta"]["scenario"] = args.scenario
    elif results["meta"]["scenario"] == "file":
        results["meta"]["scenario"] = str(args.env_config)
    if args.agent_seeds:
        from imm_gym.cli.seeds import across_seeds, render_seeds

        results["across_seeds"] = across_seeds(results, args.agent_seeds)
    if args.tradeoff:
        results["tradeoff"] = _tradeoff(args, scenario, overrides, results, make_core)
    # the JSON before the tables: a table that cannot be printed loses no result
    _record(results, args)
    render_tables(results)
    if args.agent_seeds:
        render_seeds(results["across_seeds"], results["meta"]["scenario"])
    if args.plots:
        from imm_gym.evaluation.plots import write_figures

        base = evaluated_config(scenario, overrides)
        for path in write_figures(rollouts, args.plots, results["meta"], base):
            print(f"wrote {path}")
    if args.animate:
        _write_animation(args, rollouts, file_config)
    return 0


def _tradeoff(
    args: argparse.Namespace,
    scenario: Any,
    overrides: Mapping[str, Any],
    results: dict[str, Any],
    make_core: Callable[[EnvConfig, int], Any],
) -> dict[str, Any]:
    """``--tradeoff FILE``: the classical IMM at every stay of
    :func:`baselines.best_fixed.stay_grid` on the evaluation's runs and configuration, the
    figure of ARMSE against mode accuracy (:func:`~imm_gym.evaluation.plots.tradeoff_figure`)
    and the points."""
    from baselines.best_fixed import stay_grid
    from baselines.fixed import FixedTPM
    from imm_gym.evaluation.plots import tradeoff_figure

    base = evaluated_config(scenario, overrides)
    keys = ("armse_pos", "mode_accuracy", "mode_prob_tv")
    M = len(base.bank)
    fixed = FixedTPM(M)
    stays = stay_grid(M)
    tpms = np.stack([stay_tpm(M, stay) for stay in stays])
    cfg = evaluation_config(base, fixed.env_overrides)
    run = rollout(fixed, cfg, args.runs, args.seed, make_core=make_core, initial_tpms=tpms)
    fixed_points = {}
    for stay, part in zip(stays, run.groups(len(stays)), strict=True):
        row = score(part)
        fixed_points[stay] = {k: row[k] for k in keys}
    points = {name: {k: row[k] for k in keys} for name, row in results["policies"].items()}
    path = tradeoff_figure(points, fixed_points, args.tradeoff, results["meta"])
    print(f"wrote {path}")
    return {"policies": points, "fixed": {f"{s:.6g}": v for s, v in fixed_points.items()}}


def _cores(parser: argparse.ArgumentParser, address: str | None) -> Callable[[EnvConfig, int], Any]:
    """The roll-outs' core: in this process, or with ``--ray`` a pool of shards on the cluster
    at ``address`` ("" for Ray's default) (:mod:`imm_gym.evaluation.distributed`), joined and
    started when the first roll-out builds its core: after every check of the arguments, the
    configuration and the policies. Ray not installed is a usage error here; a cluster that
    cannot be joined, or whose shards do not start, a ConfigError naming ``--ray`` then; a shard
    that dies later a :class:`~imm_gym.evaluation.distributed.ShardError`, which :func:`main`
    reports in one line (exit status 1)."""
    if address is None:
        return TrackingCore
    try:
        from ray import init  # noqa: F401  (installed; importing it starts nothing)
    except ImportError:
        parser.error("--ray needs Ray: pip install -e '.[ray]' (make install-ray)")
    from imm_gym.evaluation.distributed import ShardPool, connect

    pools: list[ShardPool] = []

    def make_core(config: EnvConfig, n_envs: int) -> Any:
        if not pools:
            try:
                connect(address or None)
                pools.append(ShardPool())
            except (ConnectionError, TimeoutError, RuntimeError, ValueError) as err:
                reason = (str(err).strip().splitlines() or [type(err).__name__])[0]
                raise ConfigError(f"--ray {address or '(Ray default)'}: {reason}") from None
        return pools[0].core(config, n_envs)

    return make_core


def _run_config(
    args: argparse.Namespace, file_config: Mapping[str, Any] | None
) -> dict[str, Any]:
    """The EnvConfig overrides of the command line: ``file_config`` (the ``--env-config``
    file's, read once by the caller), its scenario replaced by ``--scenario`` (``paper`` when
    neither gives one) and its bank and filter by ``--bank``'s preset."""
    overrides = dict(file_config or {})
    if args.scenario is not None:
        overrides["scenario"] = load_source(args.scenario)
    overrides.setdefault("scenario", "paper")
    if args.bank is not None:
        if args.bank not in BANKS:
            raise ConfigError(f"--bank must be one of {list(BANKS)}, got {args.bank!r}")
        overrides.pop("filter", None)
        overrides = {**overrides, **expand_presets({"bank": args.bank}, "--bank")}
    EnvConfig.build(overrides)
    return overrides


def _check_animate(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--animate FILE``, before any evaluation: an episode scenario, a ``.gif`` (or a ``.mp4``
    with ffmpeg installed) that can be written."""
    from imm_gym.evaluation.animation import check_animation_path

    if args.animate is None:
        return
    if args.scenario in SYSTEMS:
        parser.error(f"--animate does not apply to --scenario {args.scenario}")
    try:
        check_animation_path(args.animate)
    except ConfigError as err:
        parser.error(f"--animate: {err}")
    problem = output_problem(args.animate, "file")
    if problem:
        parser.error(f"--animate {str(args.animate)!r}: {problem}")


def _write_animation(
    args: argparse.Namespace, rollouts: dict[str, Rollout], file_config: Mapping[str, Any] | None
) -> None:
    """Run 0 of every policy's roll-out side by side (:mod:`imm_gym.evaluation.animation`) on
    the command line's configuration (``file_config``: the ``--env-config`` file's overrides)."""
    from imm_gym.evaluation.animation import write_animation

    base = EnvConfig.build(_run_config(args, file_config))
    frames = write_animation(rollouts, base, args.seed, args.animate)
    print(f"wrote {args.animate} ({frames} frames of seed {args.seed}: {', '.join(rollouts)})")


def _main_suite(
    parser: argparse.ArgumentParser,
    args: argparse.Namespace,
    make_core: Callable[[EnvConfig, int], Any],
) -> int:
    """``--suite NAME|DIR``: every case of the suite with its configuration file, one table."""
    from imm_gym.cli.tables import render_suite_table

    unused = {
        "--scenario": args.scenario,
        "--env-config": args.env_config,
        "--bank": args.bank,
        "--plots": args.plots,
        "--tradeoff": args.tradeoff,
        "--animate": args.animate,
        "--tuned": args.tuned,
    }
    for flag in (f for f, given in unused.items() if given):
        parser.error(f"{flag} does not apply to --suite (each scenario has its configuration)")
    try:
        results = evaluate_suite(
            args.policy,
            args.suite,
            args.runs,
            args.seed,
            reference=args.reference,
            clairvoyant=not args.no_clairvoyant,
            progress=not args.quiet and sys.stderr.isatty(),
            make_core=make_core,
            bar=args.bar,
        )
    except ConfigError as err:
        parser.error(str(err))
    if args.agent_seeds:
        from imm_gym.cli.seeds import render_seeds, suite_across_seeds

        results["across_seeds"] = suite_across_seeds(results, args.agent_seeds)
    _record(results, args)
    render_suite_table(results)
    if args.agent_seeds:
        render_seeds(results["across_seeds"])
    return 0


def _main_system(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """``--scenario seed002|seed003``: classical IMM-EKF and its BBSCA / SCA-tuned versions."""
    from imm_gym.cli.tables import render_system_tables
    from imm_gym.papers.tuned_comparison import evaluate_system

    unused = {
        "--bank": args.bank is not None,
        "--env-config": args.env_config,
        "--reference": args.reference,
        "--plots": args.plots,
        "--tradeoff": args.tradeoff,
        "--agent-seeds": args.agent_seeds,
    }
    for flag in (f for f, given in unused.items() if given):
        parser.error(f"{flag} does not apply to --scenario {args.scenario}")
    tuned: dict[str, str] = {}
    for item in args.tuned:
        policy, sep, path = item.partition("=")
        if not sep or not policy or not path:
            parser.error(f"--tuned must be POLICY=FILE (e.g. bbsca=tuned.json), got {item!r}")
        if policy in tuned:
            parser.error(f"--tuned {policy} given twice: {tuned[policy]!r} and {path!r}")
        tuned[policy] = path
    started = versions(*OPTIONAL_PACKAGES)  # the code that runs, as evaluate's meta.versions
    try:
        results = evaluate_system(args.scenario, args.policy, args.runs, args.seed, tuned)
    except ValueError as err:
        parser.error(str(err))
    results["meta"]["versions"] = started
    _record(results, args)
    render_system_tables(results)
    return 0


def _record(results: dict[str, Any], args: argparse.Namespace) -> None:
    """The command line :func:`main` parsed (``args.argv``, quoted for a shell) in the results'
    ``meta`` and, with ``--json``, the results written."""
    results["meta"]["command"] = f"python -m imm_gym.evaluate {shlex.join(args.argv)}"
    path = args.json
    if path:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(record_json(results))

