"""What ``train.py`` writes about its runs: the comparison each trained agent is evaluated in
and the reports of a seed (``OUT/seed_S/report.md``) and of a run (``OUT/report.md``,
``summary.json``'s statistics across seeds).

An agent is compared with the classics (:data:`BASELINES_COMPARED`) and with the strongest rules
its tracker admits (:data:`DETECTOR_RULES`), on the paper scenario and on held-out runs of the
randomized family, by the evaluation's own code (:func:`imm_gym.cli.comparison.evaluate`: common
random numbers, paired bootstrap CIs).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: The baselines every trained agent is compared with.
BASELINES_COMPARED = ("fixed", "tip-imm", "best-fixed")
#: The strongest rules, compared too where the tracker admits them (a linear bank; the learned
#: detector's network fitting it): an agent is judged against them, not only the classics.
DETECTOR_RULES = ("turn-rate-prior", "learned-prior")


def evaluated_scenarios(env_overrides: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The configuration the agent and the baselines run on in each scenario of
    :func:`train.evaluate_agent`: the first ``--env-config`` file's (its ``scenario`` aside) on the
    randomized family, and the same without ``vary`` on the paper scenario, whose targets fly at
    its own sampling period and speeds (the conditions a file draws per episode apply to the
    family's targets; the file's sensor and bank apply to both)."""
    family = {k: v for k, v in env_overrides.items() if k != "scenario"}
    return {"paper": {k: v for k, v in family.items() if k != "vary"}, "random": family}


def admitted_rules(base: Any) -> tuple[str, ...]:
    """The rules of :data:`DETECTOR_RULES` whose configuration the evaluated ``base`` (an
    EnvConfig) admits (their detector needs a linear bank; the learned one, distinct turn rates
    and as many models as its network)."""
    from baselines import REGISTRY
    from imm_gym.validation import ConfigError

    admitted = []
    for name in DETECTOR_RULES:
        try:
            REGISTRY[name].check(base)
        except ConfigError:
            continue
        admitted.append(name)
    return tuple(admitted)


def paired(rollouts: dict[str, Any], a: str, b: str) -> dict[str, float | None]:
    """``a``'s position ARMSE minus ``b``'s with its paired bootstrap CI, as the evaluation's
    differences (``low`` and ``high`` None for one run, where it is undefined)."""
    from imm_gym.cli.comparison import paired_difference

    return paired_difference(rollouts[a].squared_position_error, rollouts[b].squared_position_error)


def ci_text(d: dict[str, Any]) -> str:
    """A paired difference's 95 % CI, ``[low, high]`` in m, or ``undefined (1 run)``."""
    return "undefined (1 run)" if d["low"] is None else f"[{d['low']:+.3f}, {d['high']:+.3f}]"


def write_report(path: Path, results: dict[str, Any], header: list[str]) -> None:
    """A seed's ``report.md``: ``header``'s lines, then for each evaluated scenario of
    ``results`` (:func:`train.evaluate_agent`'s) the policies' position and velocity ARMSE and
    the learned agent's paired differences from the best fixed TPM, TIP-IMM and the detector
    rules run there."""
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
        c = r.get("clairvoyant", {})
        if "armse_pos" in c:
            lines.append(
                f"| clairvoyant ({c['role']}) | {c['armse_pos']:.3f} | {c['armse_pos_x']:.3f} | "
                f"{c['armse_pos_y']:.3f} | {c['armse_vel_x']:.3f} | {c['armse_vel_y']:.3f} |"
            )
        lines += ["", "Paired differences of position ARMSE (95 % bootstrap CI):", ""]
        for name, d in r["paired"]["differences"].items():
            relative = f"{100 * d['relative']:+.2f} %"
            lines.append(f"- {name} − best-fixed: {d['diff']:+.3f} m {ci_text(d)} ({relative})")
        for rule in ("tip-imm", *DETECTOR_RULES):
            d = r.get(f"vs_{rule.replace('-', '_')}")
            if d is not None:
                relative = f"{100 * d['relative']:+.2f} %"
                lines.append(f"- learned − {rule}: {d['diff']:+.3f} m {ci_text(d)} ({relative})")
        lines.append("")
    path.write_text("\n".join(lines) + "\n")


def describe_selection(selected: dict[str, Any]) -> str:
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


def across_seeds(seeds: dict[str, Any]) -> dict[str, Any]:
    """``summary.json``'s ``across_seeds``: per scenario, the learned agent's position ARMSE
    over the evaluated ``seeds`` (mean, sample standard deviation, each seed's) and its mean
    relative differences from the best fixed TPM and TIP-IMM."""
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
            "armse_pos_std": float(np.std(learned, ddof=1)) if len(learned) > 1 else None,
            "relative_vs_best_fixed_mean": float(np.mean(vs_best)),
            "relative_vs_tip_imm_mean": float(np.mean(vs_tip)),
            "per_seed_armse_pos": learned,
        }
    return out


def write_summary_report(path: Path, summary: dict[str, Any]) -> None:
    """A run's ``report.md``: its command and, per scenario, :func:`across_seeds`' figures."""
    lines = ["# Training summary", "", f"Command: `{summary['command']}`", ""]
    for scenario, s in summary["across_seeds"].items():
        spread = "one seed" if s["armse_pos_std"] is None else f"± {s['armse_pos_std']:.3f} m"
        lines += [
            f"## {scenario}",
            "",
            f"Learned position ARMSE over seeds: {s['armse_pos_mean']:.3f} m, {spread} (per "
            f"seed: {', '.join(f'{v:.3f}' for v in s['per_seed_armse_pos'])}); mean relative "
            f"difference vs best fixed {100 * s['relative_vs_best_fixed_mean']:+.2f} %, vs TIP-IMM "
            f"{100 * s['relative_vs_tip_imm_mean']:+.2f} %.",
            "",
        ]
    path.write_text("\n".join(lines))
