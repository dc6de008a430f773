"""Figures like the TIP-IMM paper's: trajectory with estimates, model probabilities, RMSE(t)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from imm_gym.evaluation.rollout import Rollout
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.render import model_labels


def write_figures(
    rollouts: dict[str, Rollout], out_dir: Path, meta: dict[str, Any], config: EnvConfig
) -> list[Path]:
    """Write :func:`figures` to ``out_dir`` as ``NAME.png``; returns the paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    return [
        _save(fig, out_dir / f"{name}.png")
        for name, fig in figures(rollouts, meta, config).items()
    ]


def figures(
    rollouts: dict[str, Rollout], meta: dict[str, Any], config: EnvConfig
) -> dict[str, Figure]:
    """``trajectory``, ``mode_probs`` and ``rmse`` of roll-outs on ``config`` (the evaluated
    configuration).

    The trajectory and model probabilities show run 0 (the first seed); the RMSE curves use all
    runs, ``RMSE(t) = sqrt(mean_r ||p_hat - p||^2)``. The mode probabilities are named by the
    bank's models; the time axis is in seconds at the scenario's sampling period, in steps where
    the sampling period is drawn per episode (``vary.T``). The estimates and mode probabilities
    drawn are the tracker's (:meth:`~imm_gym.evaluation.rollout.Rollout.tracker_records`): a run
    0 that diverged stops at the step it diverged at, which the trajectory's title and the
    policy's mode probability panel name (the RMSE counts its capped error, as the scores do).
    """
    labels = model_labels(config.bank)
    period = None if config.vary.T is not None else config.source.T
    out: dict[str, Figure] = {}
    title = f"{meta['scenario']}, {meta['runs']} runs, seeds {meta['seeds']}"
    first = next(iter(rollouts.values()))
    steps = np.arange(1, first.truth.shape[1] + 1)
    t, t_label = (steps, "step") if period is None else (steps * period, "time (s)")

    lost = {name: r.diverged_at() for name, r in rollouts.items()}
    shown = {name: r.tracker_records() for name, r in rollouts.items()}

    fig = Figure(figsize=(7, 6))
    ax = fig.subplots()
    ax.plot(first.truth[0, :, 0], first.truth[0, :, 1], "k-", lw=2, label="truth")
    for name, (estimate, _, _) in shown.items():
        ax.plot(estimate[:, 0], estimate[:, 1], lw=1, label=name)
    ax.set(
        xlabel="x (m)",
        ylabel="y (m)",
        title="\n".join(
            [f"Trajectory, run 0 ({meta['scenario']})"]
            + [f"{name} diverged at step {k}" for name, k in lost.items() if k is not None]
        ),
    )
    ax.axis("equal")
    ax.legend()
    out["trajectory"] = fig

    fig = Figure(figsize=(8, 2.4 * len(rollouts)))
    axes = fig.subplots(len(rollouts), 1, sharex=True, squeeze=False)
    for ax, (name, (_, mode_probs, _)) in zip(axes[:, 0], shown.items(), strict=True):
        for j in range(mode_probs.shape[-1]):
            ax.plot(t, mode_probs[:, j], label=labels[j])
        k = lost[name]
        ax.set(
            ylabel="probability",
            ylim=(-0.02, 1.02),
            title=name if k is None else f"{name}, diverged at step {k}",
        )
    axes[0, 0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the curves
    axes[-1, 0].set_xlabel(t_label)
    out["mode_probs"] = fig

    fig = Figure(figsize=(8, 4))
    ax = fig.subplots()
    for name, r in rollouts.items():
        ax.plot(t, np.sqrt(r.squared_position_error.mean(axis=0)), lw=1, label=name)
    ax.set(xlabel=t_label, ylabel="position RMSE (m)", title=f"RMSE over time ({title})")
    ax.legend()
    out["rmse"] = fig
    return out


def _save(fig: Figure, path: Path) -> Path:
    """Write ``fig`` (a figure outside pyplot: no backend is switched, nothing to close), making
    the missing directories of ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def tradeoff_figure(
    policies: dict[str, dict[str, Any]],
    fixed: dict[float, dict[str, Any]],
    path: Path,
    meta: dict[str, Any],
) -> Path:
    """Position ARMSE against mode accuracy: the fixed TPMs of a stay grid as one curve, every
    other policy as a point named in the legend (with its mode-probability total variation per
    step; a legend, not labels beside the points, which overlap where policies are close), all
    on the same runs. A policy or stay whose mode accuracy is None (no step's true model in the
    bank) has no point; a total variation None (no two live steps in a row) reads "TV —". Where
    none has a mode accuracy, the figure says so instead of showing empty axes.

    Args:
        policies: each policy's :func:`~imm_gym.evaluation.rollout.score`.
        fixed: the score of the classical IMM at each stay probability.
        path: the PNG written (its missing directories made); meta: the evaluation's ``meta``
            (scenario, runs, seeds).
    """
    fig = Figure(figsize=(8, 5.5))
    ax = fig.subplots()
    title = (f"ARMSE vs mode integrity ({meta['scenario']}, {meta['runs']} runs, seeds "
             f"{meta['seeds']})")
    stays = sorted(s for s in fixed if fixed[s]["mode_accuracy"] is not None)
    points = {name: row for name, row in policies.items() if row["mode_accuracy"] is not None}
    if not stays and not points:
        ax.set_axis_off()
        ax.set_title(title)
        ax.text(0.5, 0.5, "no mode accuracy to plot:\nno step's true model is in the bank",
                ha="center", va="center", transform=ax.transAxes)
        return _save(fig, path)
    acc = [100.0 * fixed[s]["mode_accuracy"] for s in stays]
    err = [fixed[s]["armse_pos"] for s in stays]
    ax.plot(acc, err, "o-", color="0.55", lw=1, ms=4, label="fixed TPM (stay on the diagonal)")
    for s, a, e in zip(stays, acc, err, strict=True):
        ax.annotate(f"{s:.3g}", (a, e), textcoords="offset points", xytext=(4, -10), fontsize=7,
                    color="0.4")
    for name, row in points.items():
        a, e = 100.0 * row["mode_accuracy"], row["armse_pos"]
        label = name if len(name) <= 28 else "…" + name[-27:]  # an agent's directory
        tv = "—" if row["mode_prob_tv"] is None else f"{row['mode_prob_tv']:.2f}"
        ax.plot(a, e, "D", ms=6, label=f"{label} (TV {tv})")
    ax.set(
        xlabel="mode accuracy (%): argmax of the mode probabilities = the true model",
        ylabel="position ARMSE (m)",
        title=title,
    )
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    return _save(fig, path)
