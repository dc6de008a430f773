"""Training seeds of one agent, aggregated (``python -m imm_gym.evaluate --agent-seeds DIR ...``).

Each seed is evaluated as a policy of its own (its row in the tables, the same runs as every
other policy); this adds, per scenario, the interquartile mean over the seeds of the position
ARMSE, the mode accuracy and the relative paired difference of the position ARMSE against the
reference policy, each with a stratified bootstrap 95 % CI
(:func:`imm_gym.evaluation.metrics.stratified_bootstrap_iqm`, Agarwal et al. 2021) and, over the
scenarios of a suite, the IQM of the relative differences (every scenario a task: seeds are
resampled within each). The IQM of n values drops ``floor(n / 4)`` of them at each end and
averages the others (:func:`~imm_gym.evaluation.metrics.interquartile_mean`: the middle 3 of 5
seeds, all of 2 or 3); its CI says how much the training seed moves the agent, not the
Monte-Carlo noise (the paired CIs of each seed's row say that).
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from imm_gym.evaluation.metrics import (
    IQM_LEVEL,
    IQM_RESAMPLES,
    IQM_SEED,
    stratified_bootstrap_iqm,
)

#: Per-scenario quantities aggregated over the seeds (keys of the JSON): a seed's position ARMSE
#: and mode accuracy (its row), its relative paired difference against the reference.
QUANTITIES = ("armse_pos", "mode_accuracy", "relative_vs_reference")


def _per_seed(result: Mapping[str, Any], seeds: Sequence[str]) -> dict[str, list[float | None]]:
    """Each quantity of :data:`QUANTITIES` for every seed of one scenario's result (a mode
    accuracy None where no step's true model is in the bank).

    Raises:
        ValueError: a seed without a paired difference against the reference (the reference
            itself, say: the command refuses it), which no value stands for.
    """
    rows = result["policies"]
    paired = result["paired"]
    values: dict[str, list[float | None]] = {q: [] for q in QUANTITIES}
    for name in seeds:
        values["armse_pos"].append(float(rows[name]["armse_pos"]))
        accuracy = rows[name]["mode_accuracy"]
        values["mode_accuracy"].append(None if accuracy is None else float(accuracy))
        d = paired["differences"].get(name)
        if d is None:
            raise ValueError(
                f"seed {name} has no paired difference against the reference "
                f"{paired['reference']!r}: the seeds are compared with a policy outside them"
            )
        values["relative_vs_reference"].append(float(d["relative"]))
    return values


def across_seeds(result: Mapping[str, Any], seeds: Sequence[str]) -> dict[str, Any]:
    """One scenario: per quantity the seeds' values and their IQM with its stratified bootstrap
    CI (``{"per_seed": [...], "iqm": ..., "low": ..., "high": ...}``; the three None where a
    seed has no value), the reference's name and the seeds."""
    out: dict[str, Any] = {"seeds": list(seeds), "reference": result["paired"]["reference"]}
    for key, values in _per_seed(result, seeds).items():
        if any(v is None for v in values):
            out[key] = {"per_seed": values, "iqm": None, "low": None, "high": None}
        else:
            out[key] = {"per_seed": values, **stratified_bootstrap_iqm(np.asarray(values))}
    return out


def suite_across_seeds(results: Mapping[str, Any], seeds: Sequence[str]) -> dict[str, Any]:
    """A suite: :func:`across_seeds` of every scenario the seeds ran on (``not_run``: those
    their network cannot read, a bank of another size) and the IQM over those scenarios and the
    seeds of the relative difference against the reference (``reference``: ``--reference``'s
    paired differences, also with ``--bar``, whose bar may be another policy on some cases),
    stratified by scenario. Where no scenario ran every seed there is no such IQM:
    ``relative_vs_reference`` is None and ``note`` says why (never a NaN)."""
    ran = {
        name: r
        for name, r in results["scenarios"].items()
        if all(seed in r["policies"] for seed in seeds)
    }
    per_scenario = {name: across_seeds(r, seeds) for name, r in ran.items()}
    summary: dict[str, Any] = {
        "seeds": list(seeds),
        "reference": next((s["reference"] for s in per_scenario.values()), None),
        "scenarios": per_scenario,
        "not_run": [name for name in results["scenarios"] if name not in ran],
        "relative_vs_reference": None,
    }
    if not per_scenario:
        summary["note"] = (
            "no scenario ran every seed (their networks read trackers of different sizes): no "
            "IQM over the suite"
        )
        return summary
    relative = np.array([s["relative_vs_reference"]["per_seed"] for s in per_scenario.values()])
    summary["relative_vs_reference"] = stratified_bootstrap_iqm(relative)
    return summary


def render_seeds(summary: Mapping[str, Any], scenario: str = "") -> None:
    """Print the aggregate of :func:`across_seeds` (one scenario, named ``scenario``;
    ``{"scenarios": ...}`` absent) or :func:`suite_across_seeds` as a table with rich."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    suite = "scenarios" in summary
    scenarios = summary["scenarios"] if suite else {scenario: summary}
    n = len(summary["seeds"])
    console = Console(width=None if sys.stdout.isatty() else 150)
    # text in square brackets is rich markup: escaped, or '[stratified ...]' (a tag) is dropped
    table = Table(
        title=escape(f"Over {n} training seeds: interquartile mean [stratified bootstrap 95% CI]")
    )
    for col in ("scenario", "pos ARMSE (m)", "mode acc.", "Δ vs reference"):
        table.add_column(col, justify="left" if col == "scenario" else "right")
    for name, s in scenarios.items():
        a, m, r = s["armse_pos"], s["mode_accuracy"], s["relative_vs_reference"]
        table.add_row(
            escape(name or "—"),
            f"{a['iqm']:.2f} [{a['low']:.2f}, {a['high']:.2f}]",
            "—" if m["iqm"] is None
            else f"{100 * m['iqm']:.1f}% [{100 * m['low']:.1f}, {100 * m['high']:.1f}]",
            f"{100 * r['iqm']:+.2f}% [{100 * r['low']:+.2f}, {100 * r['high']:+.2f}] "
            f"({escape(s['reference'])})",
        )
    pooled = summary.get("relative_vs_reference") if suite else None
    if suite and pooled is None:
        table.caption = escape(f"{summary.get('note', 'no IQM over the suite')}; not run on "
                               f"{', '.join(summary['not_run'])}")
    elif pooled is not None:
        table.caption = (
            f"all scenarios, relative Δ vs the reference, {escape(summary['reference'])}: "
            f"{100 * pooled['iqm']:+.2f}% [{100 * pooled['low']:+.2f}, {100 * pooled['high']:+.2f}]"
        )
        if summary.get("not_run"):
            table.caption += f"; not run on {escape(', '.join(summary['not_run']))}"
    console.print(table)
    console.print(
        f"Stratified bootstrap: {IQM_RESAMPLES} resamples of the seeds within each scenario, "
        f"seed {IQM_SEED}, {IQM_LEVEL:.0%} percentile interval."
    )
