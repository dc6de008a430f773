"""Where a TPM policy gains or loses against another: the position error split by the true
motion, and the TPM's stays while each motion lasts.

One ARMSE per scenario hides where it comes from. This scores policies with the evaluation's own
code on the same runs of each scenario of the benchmark suite (common random numbers,
:func:`imm_gym.cli.comparison.evaluate`) and prints, per policy:

* the RMS position error over the steps whose true motion is each model of the bank
  (:math:`\\sqrt{\\operatorname{mean}_{r,k:\\, m^*_{rk} = j} \\lVert \\hat p_{rk} - p_{rk}
  \\rVert^2}`; straight flight is the CV model, a turn the CT model of its sign), and
* the median over those steps of each row's stay probability :math:`\\pi_{ii}` of the TPM the
  step used: how sticky the policy keeps each model while the target flies straight or turns.

``--window N`` adds, per scenario, the same over the episode's time: for each window of ``N``
steps, each policy's ARMSE over the window's steps (the mean over them of each step's RMS error
over runs, as the ARMSE is over all the steps: the windows' values weighted by their lengths —
the last window may be shorter — average back to the ARMSE), the true motion of the window's
steps, and the median stay of the first model (straight flight in the built-in banks): where in
the episode a policy gains or loses, say at a maneuver's onset or on a long straight leg.

``--zero DIR`` adds a trained agent's zero action (its settings, the action all zeros): the TPM
its ``stay`` action moves from, so the table shows what the policy adds to its base::

    python examples/error_by_mode.py --policy best-fixed --policy pretrained \\
        --zero agents/pretrained --runs 100 --seed 0 [--window 10]
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from baselines import REGISTRY
from imm_gym import EnvConfig, TrackingCore
from imm_gym.cli.comparison import evaluate
from imm_gym.cli.policies import load_trained, make_policy
from imm_gym.cli.suite import suite_configs
from imm_gym.evaluation.rollout import Rollout, armse_from_squared


class ZeroAction:
    """The all-zero action of an agent with ``size`` entries (its base TPM, in ``stay`` mode)."""

    def __init__(self, size: int) -> None:
        self.size = size

    def predict(
        self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        return np.zeros((obs.shape[0], self.size)), None


def by_mode(run: Rollout) -> dict[str, Any]:
    """``{"armse", "rms" (M,), "stays" (M, M)}``: the ARMSE, the RMS position error over the
    steps of each true model (NaN where none), and the median stay of each row (columns) over
    the steps of each true model (rows)."""
    error = run.squared_position_error
    stays = np.diagonal(run.tpm, axis1=-2, axis2=-1)
    M = stays.shape[-1]
    rms = np.full(M, np.nan)
    median = np.full((M, M), np.nan)
    for j in range(M):
        steps = run.true_model == j
        if steps.any():
            rms[j] = float(np.sqrt(error[steps].mean()))
            median[j] = np.median(stays[steps], axis=0)
    return {"armse": armse_from_squared(error), "rms": rms, "stays": median}


def by_time(run: Rollout, window: int) -> dict[str, Any]:
    """``{"start" (W,), "end" (W,), "armse" (W,), "steps" (W, M), "stay" (W,)}`` over windows
    of ``window`` steps (the last may be shorter): each window's first step and the step after
    its last (indices of the roll-out's steps: index 0 is the first filter step, k = 1, after
    the track's start at k = 0), the ARMSE over its
    steps :math:`\\operatorname{mean}_{k \\in w} \\sqrt{\\operatorname{mean}_r e_{rk}^2}`,
    the count of its (run, step) pairs whose true model is each model, and the median of the
    first row's stay :math:`\\pi_{11}` over all its (run, step) pairs."""
    rms = np.sqrt(run.squared_position_error.mean(axis=0))
    stay = np.diagonal(run.tpm, axis1=-2, axis2=-1)[..., 0]
    M = run.tpm.shape[-1]
    starts = np.arange(0, rms.shape[0], window)
    return {
        "start": starts,
        "end": np.minimum(starts + window, rms.shape[0]),
        "armse": np.array([rms[a:a + window].mean() for a in starts]),
        "steps": np.stack([np.bincount(run.true_model[:, a:a + window].ravel(), minlength=M)
                           for a in starts]),
        "stay": np.array([np.median(stay[:, a:a + window]) for a in starts]),
    }


def score(
    policies: Sequence[str], zero: Sequence[str], scenarios: Sequence[str], runs: int, seed: int,
    window: int = 0,
) -> dict[str, dict[str, dict[str, Any]]]:
    """``{scenario: {policy: by_mode(...)}}`` on runs ``seed .. seed + runs - 1`` of each
    scenario's suite configuration; ``zero``'s agents as ``"zero of DIR"``; with ``window > 0``
    each entry also holds ``"time"``, :func:`by_time` of that window."""
    configs = suite_configs("benchmark")
    extra = {}
    for path in zero:
        _, overrides, _ = load_trained(path, EnvConfig.build({}))  # type: ignore[arg-type]
        size = TrackingCore(EnvConfig.build(overrides), 1).action_dim
        extra[f"zero of {path}"] = (ZeroAction(size), overrides)
    results: dict[str, dict[str, dict[str, Any]]] = {}
    for name in scenarios:
        config = configs[name]
        _, rollouts = evaluate(list(policies), config.get("scenario", "random"), runs, seed,
                               clairvoyant=False, extra=extra, env_config=config)
        results[name] = {policy: by_mode(run) for policy, run in rollouts.items()}
        if window > 0:
            for policy, run in rollouts.items():
                results[name][policy]["time"] = by_time(run, window)
    return results


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("--policy", action="append", default=[], help="as evaluate's (repeatable)")
    p.add_argument("--zero", action="append", default=[], metavar="DIR",
                   help="a trained agent whose zero action is scored too (repeatable)")
    p.add_argument("--scenario", action="append", default=[],
                   help="a scenario of the benchmark suite (repeatable; default: all)")
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--window", type=int, default=0, metavar="N",
                   help="also the ARMSE and the first model's stay over windows of N steps")
    args = p.parse_args(argv)
    if args.runs < 1:
        p.error(f"--runs must be >= 1, got {args.runs}")
    if args.seed < 0:
        p.error(f"--seed must be >= 0, got {args.seed}")
    if args.window < 0:
        p.error(f"--window must be a number of steps >= 1 (0: no time table), got {args.window}")
    suite = list(suite_configs("benchmark"))
    unknown = [s for s in args.scenario if s not in suite]
    if unknown:
        p.error(f"--scenario must be one of {suite}, got {unknown}")
    scenarios = args.scenario or suite
    policies = args.policy or ["best-fixed"]
    if len(set(policies)) != len(policies):
        p.error(f"--policy given twice: {policies}")
    base = EnvConfig.build({})
    for name in policies:  # a rule is built on each scenario's runs; an agent is loaded here
        if name not in REGISTRY:
            try:
                make_policy(name, base, args.seed)
            except ValueError as err:  # ConfigError among them
                p.error(f"--policy: {err}")
    for path in args.zero:
        try:
            load_trained(Path(path), base)
        except ValueError as err:
            p.error(f"--zero: {err}")
    results = score(policies, args.zero, scenarios, args.runs, args.seed, args.window)
    print("| scenario | policy | ARMSE (m) | RMS error on each true model (m) "
          "| median stays (row 1..M) on each true model |")
    print("|---|---|---|---|---|")
    for name, policies in results.items():
        for policy, r in policies.items():
            rms = " / ".join("–" if np.isnan(e) else f"{e:.2f}" for e in r["rms"])
            stays = "; ".join(
                "–" if np.isnan(row).all() else " ".join(f"{s:.3f}" for s in row)
                for row in r["stays"]
            )
            print(f"| {name} | {policy} | {r['armse']:.2f} | {rms} | {stays} |")
    if args.window > 0:
        for name, policies in results.items():
            print_time_table(name, policies)


def print_time_table(name: str, policies: dict[str, dict[str, Any]]) -> None:
    """One scenario's :func:`by_time` table: a row per window, each policy's ARMSE / first
    stay."""
    first = next(iter(policies.values()))["time"]
    print(f"\n{name}: ARMSE (m) / median stay of the first model, by window of the episode\n")
    print("| steps | true model (run-steps per model) | " + " | ".join(policies) + " |")
    print("|---" * (2 + len(policies)) + "|")
    for w, (start, end) in enumerate(zip(first["start"], first["end"], strict=True)):
        span = f"{start + 1}–{end}"  # the steps k of the window (k = 0: the track's start)
        cells = " | ".join(f"{p['time']['armse'][w]:.2f} / {p['time']['stay'][w]:.3f}"
                           for p in policies.values())
        steps = " ".join(str(c) for c in first["steps"][w])
        print(f"| {span} | {steps} | {cells} |")


if __name__ == "__main__":
    main()
