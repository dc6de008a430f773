"""Figures like the TIP-IMM paper's: trajectory with estimates, model probabilities, RMSE(t)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from imm_gym.evaluation.rollout import Rollout


def write_figures(rollouts: dict[str, Rollout], out_dir: Path, meta: dict[str, Any]) -> list[Path]:
    """Write ``trajectory.png``, ``mode_probs.png`` and ``rmse.png`` to ``out_dir``.

    The trajectory and model probabilities show run 0 (the first seed); the RMSE curves use all
    runs, ``RMSE(t) = sqrt(mean_r ||p_hat - p||^2)``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    title = f"{meta['scenario']}, {meta['runs']} runs, seeds {meta['seeds']}"
    first = next(iter(rollouts.values()))
    t = np.arange(1, first.truth.shape[1] + 1)

    fig, ax = plt.subplots(figsize=(7, 6))
    ax.plot(first.truth[0, :, 0], first.truth[0, :, 1], "k-", lw=2, label="truth")
    for name, r in rollouts.items():
        ax.plot(r.estimate[0, :, 0], r.estimate[0, :, 1], lw=1, label=name)
    ax.set(xlabel="x (m)", ylabel="y (m)", title=f"Trajectory, run 0 ({meta['scenario']})")
    ax.axis("equal")
    ax.legend()
    paths.append(_save(fig, out_dir / "trajectory.png"))

    labels = ["CV", "CT+", "CT-"] + [f"model {j}" for j in range(3, first.mode_probs.shape[-1])]
    fig, axes = plt.subplots(
        len(rollouts), 1, figsize=(8, 2.4 * len(rollouts)), sharex=True, squeeze=False
    )
    for ax, (name, r) in zip(axes[:, 0], rollouts.items(), strict=True):
        for j in range(r.mode_probs.shape[-1]):
            ax.plot(t, r.mode_probs[0, :, j], label=labels[j])
        ax.set(ylabel="probability", ylim=(-0.02, 1.02), title=name)
    axes[0, 0].legend(loc="upper right", ncol=3)
    axes[-1, 0].set_xlabel("time (s)")
    paths.append(_save(fig, out_dir / "mode_probs.png"))

    fig, ax = plt.subplots(figsize=(8, 4))
    for name, r in rollouts.items():
        ax.plot(t, np.sqrt(r.squared_position_error.mean(axis=0)), lw=1, label=name)
    ax.set(xlabel="time (s)", ylabel="position RMSE (m)", title=f"RMSE over time ({title})")
    ax.legend()
    paths.append(_save(fig, out_dir / "rmse.png"))
    return paths


def _save(fig: Any, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path
