"""Monte-Carlo evaluation of TPM policies (command line: ``python -m imm_gym.evaluate``).

Every policy — a baseline by name or a saved stable-baselines3 model by path — runs through
:func:`imm_gym.evaluation.rollout.rollout` on the same R runs: same targets, same sensor noise
(common random numbers). The report follows the paper's Table 2 (position ARMSE overall / X / Y,
velocity ARMSE X / Y) and adds NIS/NEES consistency, mode-identification accuracy, the
mode-probability total variation, the peak error and the maneuver response, the clairvoyant
filter (a bound where no policy beats it, else a reference; skipped, with the reason, where it
cannot follow the scenario) and paired differences with 95 % bootstrap confidence intervals
against a reference policy.

Example::

    python -m imm_gym.evaluate --policy fixed --policy tip-imm --policy best-fixed \\
        --scenario paper --runs 100 --seed 0 --json out.json --plots figs/

``--json`` writes ``{"policies": {NAME: {"armse_pos": ..., "armse_pos_x": ..., "armse_pos_y": ...,
"armse_vel_x": ..., "armse_vel_y": ..., ...}}, "clairvoyant": {...}, "paired": {...},
"meta": {...}}``; with ``--runs 1`` the paired differences' confidence bounds ``low`` and
``high`` are null (undefined). ``--json`` and ``--plots`` are checked before anything is evaluated:
an output that cannot be written is a usage error (exit 2).

The best fixed TPM is searched on training runs whose seeds (``seed + 1_000_000 + r``) never
overlap the evaluation seeds.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from baselines import REGISTRY, Baseline, BuildContext
from imm_gym.cli.tables import render_tables
from imm_gym.evaluation.clairvoyant import clairvoyant_filter, clairvoyant_role, unsupported
from imm_gym.evaluation.metrics import maneuver_response, peak_error, tracking_errors
from imm_gym.evaluation.rollout import (
    Rollout,
    evaluation_config,
    paired_bootstrap,
    rollout,
    score,
)
from imm_gym.papers.systems import SYSTEMS
from imm_gym.scenarios.catalog import SCENARIOS
from imm_gym.scenarios.segments import Scenario, true_model_index
from imm_gym.seeding import TRAIN_SEED_OFFSET
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.validation import ConfigError, from_dict

#: ``--bank``: environment overrides of each bank.
BANKS = BANK_PRESETS
TRAIN_RUNS = 100


def load_source(name: str) -> str | Scenario:
    """``random``, a named scenario (:data:`imm_gym.scenarios.catalog.SCENARIOS`) or a JSON file
    holding a :class:`Scenario` (``segments`` list...)."""
    if name == "random" or name in SCENARIOS:
        return name
    path = Path(name)
    if not path.is_file():
        names = ", ".join(repr(n) for n in ("random", *SCENARIOS))
        raise ConfigError(f"--scenario must be {names} or a JSON file; {name!r} is neither")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ConfigError(f"scenario file {name}: not valid JSON ({err})") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"scenario file {name}: cannot read ({err})") from None
    try:
        return from_dict(Scenario, data, "scenario")
    except ConfigError as err:
        raise ConfigError(f"scenario file {name}: {err}") from None


def make_policy(
    name: str, base: EnvConfig, seed: int, train_runs: int = TRAIN_RUNS
) -> tuple[Any, dict[str, Any], dict[str, Any]]:
    """``(policy, env_overrides, notes)`` for a policy name or a saved SB3 model path.

    A registered baseline is built by its registry entry; a tuned one sees ``train_runs``
    training runs seeded ``seed + TRAIN_SEED_OFFSET + r``, scored by their position ARMSE.
    """
    if name in REGISTRY:
        train_seed = seed + TRAIN_SEED_OFFSET

        def train_armse(policy: Baseline) -> float:
            cfg = evaluation_config(base, policy.env_overrides)
            return score(rollout(policy, cfg, train_runs, train_seed))["armse_pos"]

        context = BuildContext(base, train_seed, train_runs, train_armse)
        policy, notes = REGISTRY[name].build(context)
        return policy, policy.env_overrides, notes
    if name == "pretrained":
        from agents import PRETRAINED

        return load_trained(PRETRAINED)
    path = Path(name)
    if path.suffix == ".zip" or path.is_dir() or path.exists():
        return load_trained(path)
    raise ConfigError(
        f"unknown policy {name!r}: use one of {list(REGISTRY)}, 'pretrained' or a "
        "trained agent's directory"
    )


def load_trained(path: Path) -> tuple[Any, dict[str, Any], dict[str, Any]]:
    """A trained agent (``agents.policy`` directory layout) and its environment overrides."""
    from agents.policy import load_agent

    try:
        policy = load_agent(path)
    except FileNotFoundError as err:
        raise ConfigError(str(err)) from None
    return policy, policy.env_overrides, {"path": str(path)}


def evaluate(
    policies: Sequence[str],
    scenario: str | Scenario,
    runs: int,
    seed: int,
    reference: str | None = None,
    clairvoyant: bool = True,
    progress: bool = False,
    extra: dict[str, tuple[Any, dict[str, Any]]] | None = None,
    bank: str = "paper",
) -> tuple[dict[str, Any], dict[str, Rollout]]:
    """Score ``policies`` on R common-random-number runs; see the module docstring.

    ``extra`` adds policy objects by name: ``{name: (policy, env_overrides)}`` (a freshly trained
    agent, say); they are evaluated first. ``bank``: ``paper`` (CV, CT(±4°/s), SVD-UKF) or
    ``hetero`` (NCV/CT/CTRA IMM-EKF, ``SONAR_HETERO_BANK``; no clairvoyant filter, said in the
    results). The clairvoyant row is labelled a bound or a reference, or skipped with the reason
    (:func:`clairvoyant_bound`).
    """
    if bank not in BANKS:
        raise ConfigError(f"--bank must be one of {list(BANKS)}, got {bank!r}")
    base = EnvConfig(scenario=scenario, **BANKS[bank])
    if len(set(policies)) != len(policies):
        raise ConfigError(f"--policy given twice: {list(policies)}")
    made = {name: (p, o, {}) for name, (p, o) in (extra or {}).items()}
    made.update({name: make_policy(name, base, seed) for name in policies})
    rollouts: dict[str, Rollout] = {}
    results: dict[str, Any] = {"policies": {}}
    bar = _progress_bar(len(made) * base.source.horizon, progress)
    for name, (policy, overrides, notes) in made.items():
        cfg = evaluation_config(base, overrides)
        done = [0]

        def tick(k: int, done: list[int] = done) -> None:
            bar.update(k - done[0])
            done[0] = k

        rollouts[name] = rollout(policy, cfg, runs, seed, progress=tick)
        results["policies"][name] = {**score(rollouts[name]), **notes}
    bar.close()
    ref = reference or ("fixed" if "fixed" in rollouts else next(iter(rollouts)))
    if ref not in rollouts:
        raise ConfigError(f"--reference {ref!r} is not among the evaluated policies")
    results["paired"] = {
        "reference": ref,
        "differences": {
            name: paired_difference(r.squared_position_error, rollouts[ref].squared_position_error)
            for name, r in rollouts.items()
            if name != ref
        },
    }
    if clairvoyant:
        results["clairvoyant"] = clairvoyant_bound(base, runs, seed, results["policies"])
    results["meta"] = {
        "scenario": scenario if isinstance(scenario, str) else "file",
        "runs": runs,
        "seed": seed,
        "seeds": f"{seed}..{seed + runs - 1}",
        "steps": base.source.horizon,
        "filter": base.filter,
        "bank": bank,
        "versions": _versions(),
    }
    return results, rollouts


def paired_difference(
    err2: NDArray[np.float64], err2_ref: NDArray[np.float64]
) -> dict[str, float | None]:
    """:func:`~imm_gym.evaluation.rollout.paired_bootstrap` of ``(R, K)`` squared errors against
    the reference's; with one run (R = 1) every resample is that run, so the confidence interval
    is undefined: ``low`` and ``high`` are None (JSON null)."""
    d: dict[str, float | None] = {**paired_bootstrap(err2, err2_ref)}
    if err2.shape[0] < 2:
        d["low"] = d["high"] = None
    return d


def clairvoyant_bound(
    base: EnvConfig, runs: int, seed: int, policies: dict[str, dict[str, Any]]
) -> dict[str, Any]:
    """The clairvoyant filter's errors on the same runs (same seeds, same draws) and its role.

    Returns:
        Its :func:`~imm_gym.evaluation.metrics.tracking_errors`, ``peak_error`` and
        ``maneuver_response``, with ``role`` ``"bound"`` or ``"reference"``, ``note`` and
        ``beaten_by`` (:func:`~imm_gym.evaluation.clairvoyant.clairvoyant_role` against
        ``policies``' scores); where the filter cannot follow the scenario or the bank
        (:func:`~imm_gym.evaluation.clairvoyant.unsupported`) only ``role`` ``"skipped"`` and
        the ``note`` saying why.
    """
    batch = draw_batch(base.source, base.sensor, runs, seed, base.velocity_std)
    reason = unsupported(batch.truth, base.bank)
    if reason is not None:
        return {"role": "skipped", "note": f"skipped: {reason}"}
    xs, _ = clairvoyant_filter(
        batch.truth,
        batch.measurements.z[:, 1:],
        base.sensor,
        base.bank,
        batch.x0,
        batch.P0,
        base.filter,
        batch.measurements.detected[:, 1:],
    )
    truth = batch.truth.states[:, 1:]
    errors = tracking_errors(xs, truth)
    true_model = true_model_index(batch.truth, base.bank)
    return {
        **errors,
        "peak_error": peak_error(xs, truth),
        "maneuver_response": maneuver_response(xs, truth, true_model),
        **clairvoyant_role(errors, policies),
    }


class _NoBar:
    def update(self, n: int) -> None:
        """No progress display."""

    def close(self) -> None:
        """No progress display."""


def _progress_bar(total: int, enabled: bool) -> Any:
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc="evaluating", unit="step", leave=False)


def _versions() -> dict[str, str]:
    import gymnasium
    import scipy

    from imm_gym import __version__

    return {
        "imm_gym": __version__,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "gymnasium": gymnasium.__version__,
        "python": platform.python_version(),
    }


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m imm_gym.evaluate",
        description="Monte-Carlo evaluation of TPM policies with common random numbers.",
    )
    parser.add_argument(
        "--policy",
        action="append",
        required=True,
        help="policy to evaluate (repeatable): "
        + "; ".join(f"{name}: {entry.help}" for name, entry in REGISTRY.items()).replace("%", "%%")
        + "; pretrained: the shipped PPO agent; or a trained agent's directory",
    )
    parser.add_argument(
        "--scenario",
        default="paper",
        help=" | ".join((*SCENARIOS, "random"))
        + " | a scenario JSON file | seed002 | seed003 (the NCV/CT/CTRA IMM-EKF "
        "of seed 002, the CV/CA/CT bank of seed 003; policies fixed, bbsca, sca)",
    )
    parser.add_argument("--runs", type=int, default=100, help="Monte-Carlo runs (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="run r uses seed + r (default 0)")
    parser.add_argument("--reference", help="policy the paired differences are taken against")
    parser.add_argument("--json", type=Path, help="write the results to this JSON file")
    parser.add_argument("--plots", type=Path, help="write PNG figures to this directory")
    parser.add_argument("--no-clairvoyant", action="store_true", help="skip the clairvoyant bound")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument(
        "--bank",
        default="paper",
        help=" | ".join(BANK_PRESETS)
        + " (paper: CV, CT(±4°/s), SVD-UKF; hetero: the NCV/CT/CTRA IMM-EKF of seed 002; "
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
    return parser


def output_problem(path: Path, kind: str) -> str | None:
    """Why ``path`` cannot receive the output ``kind`` (``"file"`` or ``"directory"``), or None.

    Checked before any evaluation runs, so an unwritable output costs nothing: ``path`` must not
    be an existing entry of the other kind, and a file must be created (a temporary one, removed
    at once) in it (a directory), next to it (a file) or in the nearest existing ancestor (where
    the missing directories will go).
    """
    if path.exists():
        if kind == "file" and path.is_dir():
            return "is a directory; give a file name"
        if kind == "directory" and not path.is_dir():
            return "exists and is not a directory"
    target = path if path.is_dir() else path.absolute().parent
    while not target.exists():
        target = target.parent
    if not target.is_dir():
        return f"{target} is not a directory"
    try:
        with tempfile.TemporaryFile(dir=target):
            pass
    except OSError as err:
        return f"cannot write in {target} ({err.strerror or err})"
    if path.is_file() and not os.access(path, os.W_OK):
        return "is not writable"
    return None


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error(f"--runs must be >= 1, got {args.runs}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    for flag, path, kind in (("--json", args.json, "file"), ("--plots", args.plots, "directory")):
        problem = None if path is None else output_problem(path, kind)
        if problem:
            parser.error(f"{flag} {str(path)!r}: {problem}")
    _check_animate(parser, args)
    if args.scenario in SYSTEMS:
        return _main_system(parser, args)
    try:
        results, rollouts = evaluate(
            args.policy,
            load_source(args.scenario),
            args.runs,
            args.seed,
            reference=args.reference,
            clairvoyant=not args.no_clairvoyant,
            progress=not args.quiet and sys.stderr.isatty(),
            bank=args.bank,
        )
    except ConfigError as err:
        parser.error(str(err))
    results["meta"]["scenario"] = args.scenario
    results["meta"]["command"] = " ".join(["python -m imm_gym.evaluate", *sys.argv[1:]])
    render_tables(results)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2))
    if args.plots:
        from imm_gym.evaluation.plots import write_figures

        for path in write_figures(rollouts, args.plots, results["meta"]):
            print(f"wrote {path}")
    if args.animate:
        _write_animation(args, rollouts)
    return 0


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


def _write_animation(args: argparse.Namespace, rollouts: dict[str, Rollout]) -> None:
    """Run 0 of every policy's roll-out side by side (:mod:`imm_gym.evaluation.animation`)."""
    from imm_gym.evaluation.animation import write_animation

    base = EnvConfig(scenario=load_source(args.scenario), **BANKS[args.bank])
    frames = write_animation(rollouts, base, args.seed, args.animate)
    print(f"wrote {args.animate} ({frames} frames of seed {args.seed}: {', '.join(rollouts)})")


def _main_system(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """``--scenario seed002|seed003``: classical IMM-EKF and its BBSCA / SCA-tuned versions."""
    from imm_gym.cli.tables import render_system_tables
    from imm_gym.papers.tuned_comparison import evaluate_system

    unused = {"--bank": args.bank != "paper", "--reference": args.reference, "--plots": args.plots}
    for flag in (f for f, given in unused.items() if given):
        parser.error(f"{flag} does not apply to --scenario {args.scenario}")
    tuned: dict[str, str] = {}
    for item in args.tuned:
        policy, sep, path = item.partition("=")
        if not sep or not policy or not path:
            parser.error(f"--tuned must be POLICY=FILE (e.g. bbsca=tuned.json), got {item!r}")
        tuned[policy] = path
    try:
        results = evaluate_system(args.scenario, args.policy, args.runs, args.seed, tuned)
    except ValueError as err:
        parser.error(str(err))
    results["meta"]["command"] = " ".join(["python -m imm_gym.evaluate", *sys.argv[1:]])
    render_system_tables(results)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2))
    return 0


