"""The tables the command lines print (rich): Table 2's layout, the IMM behaviour beyond the
ARMSE, the paired differences, and the seed-system comparison."""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any

from imm_gym.papers.tip_imm import PAPER_TABLE2
from imm_gym.sim.env_config import EnvConfig

#: The filter of the paper's setting (EnvConfig's default: the SVD-UKF).
PAPER_FILTER = EnvConfig.filter

TABLE_COLUMNS = (
    ("armse_pos", "pos (m)"),
    ("armse_pos_x", "X (m)"),
    ("armse_pos_y", "Y (m)"),
    ("armse_vel_x", "vel X (m/s)"),
    ("armse_vel_y", "vel Y (m/s)"),
)


#: The IMM behaviour table: (key, header, format); a None value (nothing to score: no step with
#: a matching model, no two live steps in a row) prints as "—".
BEHAVIOUR_COLUMNS = (
    ("mode_accuracy", "mode acc.", "{:.1%}"),
    ("mode_prob_tv", "mode-prob. TV / step", "{:.4f}"),
    ("peak_error", "peak error (m)", "{:.3f}"),
    ("maneuver_response", "maneuver response (m)", "{:.3f}"),
)


def policy_label(name: str, row: dict[str, Any]) -> str:
    """The policy's name with the stays a fixed-TPM search found (``best-fixed (stay 0.6)``,
    ``best-fixed-rows (stays 0.995/0.5/0.5)``, one per model; ``turn-rate-prior (stay 0.333,
    share 0.25)``, with the detector's share)."""
    if "stay" in row and "share" in row:
        return f"{name} (stay {row['stay']:.3g}, share {row['share']:.3g})"
    if "stay" in row:
        return f"{name} (stay {row['stay']:.3g})"
    if "stays" in row:
        return f"{name} (stays {'/'.join(f'{s:.3g}' for s in row['stays'])})"
    return name


def paper_setting(meta: dict[str, Any]) -> bool:
    """Whether the results are on the paper's setting, beside which its Table 2 is printed: the
    paper scenario with the paper's bank and filter (EnvConfig's defaults), no configuration
    file."""
    return (
        meta["scenario"] == "paper"
        and not meta.get("env_config")
        and meta.get("bank", "paper") == "paper"
        and meta.get("filter") == PAPER_FILTER
    )


def bootstrap_line(meta: dict[str, Any]) -> str | None:
    """The paired bootstrap's settings (``meta["bootstrap"]["paired"]``) in one line."""
    paired = meta.get("bootstrap", {}).get("paired")
    if paired is None:
        return None
    return (
        f"Paired bootstrap: {paired['resamples']} resamples of the runs (the same runs for both "
        f"policies), seed {paired['seed']}, {paired['level']:.0%} percentile interval."
    )


def divergence_note(meta: dict[str, Any], rows: Iterable[dict[str, Any]]) -> str | None:
    """How the diverged runs are scored (``meta["divergence"]``), when a policy has one."""
    divergence = meta.get("divergence")
    if divergence is None or not any(row.get("diverged") for row in rows):
        return None
    return f"Diverged runs (error above {divergence['error_m']:g} m): {divergence['scored']}."


def _cell(row: dict[str, Any], key: str, fmt: str) -> str:
    value = row.get(key)
    return "—" if value is None else fmt.format(value)


def _percent(value: float | None) -> str:
    """A share as a percentage, "—" for None (no value to count)."""
    return "—" if value is None else f"{100 * value:.1f}%"


def render_tables(results: dict[str, Any]) -> None:
    """Print the Table-2 layout (the clairvoyant row labelled by its role, its note below), the
    IMM behaviour (mode accuracy, mode-probability total variation, peak error, maneuver
    response) and the paired differences with rich; names, scenarios and notes are printed as
    given (escaped: ``runs/ppo[lr=3e-4]/agent`` is not read as rich markup)."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    meta = results["meta"]
    console = Console(width=None if sys.stdout.isatty() else 150)
    table = Table(
        title=escape(
            f"ARMSE, scenario '{meta['scenario']}', {meta['runs']} runs (seeds {meta['seeds']}), "
            f"{meta['steps']} steps, {meta['filter'].upper()}"
        )
    )
    table.add_column("policy")
    for _, label in TABLE_COLUMNS:
        table.add_column(label, justify="right")
    for label in ("NIS ≤ χ²95", "NEES ≤ χ²95", "mode acc.", "diverged"):
        table.add_column(label, justify="right")
    for name, r in results["policies"].items():
        label = escape(policy_label(name, r))
        table.add_row(
            label,
            *(f"{r[k]:.4f}" for k, _ in TABLE_COLUMNS),
            _percent(r["nis"]["inside"]),
            _percent(r["nees"]["inside"]),
            _percent(r["mode_accuracy"]),
            str(r["diverged"]),
        )
    c = results.get("clairvoyant")
    if c is not None:
        if c["role"] != "skipped":
            label = f"clairvoyant ({c['role']})"
            cells = (f"{c[k]:.4f}" for k, _ in TABLE_COLUMNS)
            table.add_row(label, *cells, "", "", "", str(c["diverged"]), style="dim")
        if c["role"] != "bound":
            table.caption = escape(c["note"])
    if paper_setting(meta):
        for name, r in PAPER_TABLE2.items():
            table.add_row(name, *(f"{r[k]:.4f}" for k, _ in TABLE_COLUMNS), style="dim")
    console.print(table)
    note = divergence_note(meta, results["policies"].values())
    if note:
        console.print(escape(note))
    behaviour = Table(
        title="IMM behaviour: mode-probability total variation ½·Σ|μ(k) − μ(k−1)| per step, "
        "mean of each run's peak position error, position RMSE over the 10 steps from each "
        "change of the true model (a maneuver's start or end)"
    )
    behaviour.add_column("policy")
    for _, label, _ in BEHAVIOUR_COLUMNS:
        behaviour.add_column(label, justify="right")
    for name, r in results["policies"].items():
        behaviour.add_row(escape(name), *(_cell(r, k, fmt) for k, _, fmt in BEHAVIOUR_COLUMNS))
    if c is not None and c["role"] != "skipped":
        behaviour.add_row(
            "clairvoyant", *(_cell(c, k, fmt) for k, _, fmt in BEHAVIOUR_COLUMNS), style="dim"
        )
    console.print(behaviour)
    for name, r in results["policies"].items():
        if r.get("tracker_differs"):
            fields = r["tracker_differs"]
            console.print(
                escape(
                    f"{name} was trained on another tracker than the evaluated one "
                    f"({', '.join(fields)} {'differs' if len(fields) == 1 else 'differ'}: see "
                    "trained_on and evaluated_on in the JSON)"
                )
            )
        if r.get("models_differ"):
            console.print(escape(models_differ_note(name, r["models_differ"])))
    paired = results["paired"]
    if paired["differences"]:
        diff = Table(
            title=escape(
                f"Position ARMSE minus {paired['reference']}'s, 95% paired bootstrap CI"
            )
        )
        for col in ("policy", "difference (m)", "95% CI (m)", "relative"):
            diff.add_column(col, justify="right" if col != "policy" else "left")
        for name, d in paired["differences"].items():
            diff.add_row(
                escape(name),
                f"{d['diff']:+.3f}",
                "undefined (1 run)" if d["low"] is None else f"[{d['low']:+.3f}, {d['high']:+.3f}]",
                f"{100 * d['relative']:+.2f}%",
            )
        console.print(diff)
        line = bootstrap_line(meta)
        if line:
            console.print(line)


def render_suite_table(results: dict[str, Any]) -> None:
    """Print one table of a suite's evaluation: a row per case and policy with the position
    ARMSE, the mode accuracy, the share of NEES values at or below the one-sided 95 % bound of
    χ²(4), the diverged runs and the paired difference of the position ARMSE against the
    reference with its 95 % bootstrap CI; the clairvoyant row by its role; a policy not run on a
    case, and why. Then each policy's tally against the bar, else the reference
    (:func:`~imm_gym.cli.suite.suite_tally`). Names, scenarios and notes are printed as given
    (escaped, not read as rich markup)."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    meta = results["meta"]
    console = Console(width=None if sys.stdout.isatty() else 150)
    table = Table(
        title=escape(
            f"Suite '{meta['suite']}', {meta['runs']} runs (seeds {meta['seeds']}) per case, "
            "each with its configuration file"
        )
    )
    for col in ("scenario", "policy", "pos ARMSE (m)", "mode acc.", "NEES ≤ χ²95", "diverged"):
        table.add_column(col, justify="left" if col in ("scenario", "policy") else "right")
    table.add_column("Δ vs reference (m), 95% CI", justify="right")
    for scenario, r in results["scenarios"].items():
        paired = r["paired"]
        steps = escape(f"{scenario} ({r['meta']['steps']} steps)")
        bar = r.get("bar", {}).get("policy")
        for i, (name, row) in enumerate(r["policies"].items()):
            d = paired["differences"].get(name)
            if d is None:
                delta = escape(f"reference ({name})")
            elif d["low"] is None:
                delta = f"{d['diff']:+.2f}"
            else:
                delta = f"{d['diff']:+.2f} [{d['low']:+.2f}, {d['high']:+.2f}]"
            table.add_row(
                steps if i == 0 else "",
                escape(policy_label(name, row) + (" — the bar" if name == bar else "")),
                f"{row['armse_pos']:.2f}",
                _percent(row["mode_accuracy"]),
                _percent(row["nees"]["inside"]),
                str(row["diverged"]),
                delta,
                end_section=False,
            )
        for name, reason in r.get("skipped", {}).items():
            table.add_row("", escape(name), *["—"] * 4, escape(f"not run: {reason}"), style="dim")
        c = r.get("clairvoyant")
        if c is not None and c["role"] != "skipped":
            table.add_row(
                "", f"clairvoyant ({c['role']})", f"{c['armse_pos']:.2f}", *[""] * 4, style="dim"
            )
        table.add_section()
    moved = sorted(
        {
            name
            for r in results["scenarios"].values()
            for name, row in r["policies"].items()
            if row.get("tracker_differs")
        }
    )
    if moved:
        table.caption = escape(
            f"{', '.join(moved)}: trained on another tracker than some scenarios' (JSON: "
            "trained_on, evaluated_on, tracker_differs)"
        )
    console.print(table)
    for scenario, r in results["scenarios"].items():
        for name, row in r["policies"].items():
            if row.get("models_differ"):
                console.print(
                    escape(f"{scenario}: " + models_differ_note(name, row["models_differ"]))
                )
        note = divergence_note(r["meta"], r["policies"].values())
        if note:
            console.print(escape(f"{scenario}: {note}"))
    line = bootstrap_line(meta)
    if line:
        console.print(line)
    n = len(results["scenarios"])
    for name, cases in results.get("tally", {}).items():
        counts = ", ".join(f"{key} on {len(cases[key])}" for key in ("below", "level", "above"))
        against = (
            f"the better of {' and '.join(meta['bar'])}" if meta.get("bar") else meta["reference"]
        )
        line = f"{name} against {against} ({n} cases, paired 95% CIs): {counts}"
        if cases["skipped"]:
            line += f"; not run on {len(cases['skipped'])}"
        console.print(escape(line))


SYSTEM_COLUMNS = (
    ("pos_rmse", "pos RMSE (m)", "{:.4f}"),
    ("pos_mae", "MAE (m)", "{:.4f}"),
    ("pos_max", "max (m)", "{:.3f}"),
    ("fde", "FDE (m)", "{:.4f}"),
    ("vel_rmse", "vel RMSE (m/s)", "{:.4f}"),
    ("yaw_rmse_deg", "yaw RMSE (°)", "{:.3f}"),
    ("nis_inside", "NIS ≤ χ²95", "{:.1%}"),
    ("nis_mean", "mean NIS", "{:.3f}"),
    ("nees_inside", "NEES ≤ χ²95", "{:.1%}"),
    ("nees_mean", "mean NEES", "{:.3f}"),
    ("innovation_mse", "innov. MSE J", "{:.4f}"),
)


#: Under the seed-scenario table when a run failed (:func:`render_system_tables`).
FAILED_NOTE = (
    "failed: runs whose filter failed (an innovation covariance not positive definite, or a "
    "non-finite estimate; JSON: failed). Their outputs are NaN, so the errors and means over them "
    "are nan and NIS/NEES ≤ χ²95 count their NaN steps as outside the bound."
)


def render_system_tables(results: dict[str, object]) -> None:
    """Print the seed-scenario table (seed 002's paper row beside it) with rich; policy names
    printed as given (escaped, not read as rich markup). Where a policy has a failed run
    (``failed`` > 0), a column gives each policy's failed runs out of the runs and a note under
    the table says what a failed run does to the other columns (:data:`FAILED_NOTE`)."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    meta: dict[str, object] = results["meta"]  # type: ignore[assignment]
    console = Console(width=None if sys.stdout.isatty() else 180)
    table = Table(
        title=f"scenario '{meta['scenario']}', {meta['runs']} runs (seeds {meta['seeds']}), "
        f"{meta['steps']} steps, IMM-EKF"
    )
    table.add_column("policy")
    for _, label, _ in SYSTEM_COLUMNS:
        table.add_column(label, justify="right")
    rows = dict(results["policies"])  # type: ignore[call-overload]
    failed = any(r.get("failed") for r in rows.values())
    if failed:
        table.add_column("failed", justify="right")
        table.caption = FAILED_NOTE
    paper = results.get("paper") or {}
    for name, r in rows.items():
        cells = [_cell(r, k, fmt) for k, _, fmt in SYSTEM_COLUMNS]
        if failed:
            cells.append(f"{r.get('failed', 0)}/{meta['runs']}")
        table.add_row(escape(name), *cells)
    if paper:
        table.add_row(
            "seed 002 paper (their trajectory)",
            *(fmt.format(paper[k]) if k in paper else "—" for k, _, fmt in SYSTEM_COLUMNS),
            *(["—"] if failed else []),
            style="dim",
        )
    console.print(table)


def models_differ_note(name: str, roles: dict[str, list[str]]) -> str:
    """One line: the policy reads the evaluated bank's models as the ones it was trained on."""
    return (
        f"{name} reads the evaluated bank's models ({', '.join(roles['evaluated'])}) as those it "
        f"was trained on ({', '.join(roles['trained'])})"
    )
