"""Tracking metrics: RMSE(t) and ARMSE (SPEC §3, eqs. 20-21), NIS/NEES consistency (seed 002),
mode-identification accuracy.

Shapes: R runs, K scored steps; estimates ``(R, K, n >= 4)`` and truth ``(R, K, 4)`` on
``[x, y, vx, vy]``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from imm_gym.tracking.linalg import inv_logdet, mahalanobis

Array = NDArray[np.float64]


def rmse_over_time(error: Array) -> Array:
    """``RMSE(t) = sqrt(mean over runs of ||e_t||^2)``: ``(R, K, d) -> (K,)``."""
    return np.sqrt(np.mean(np.sum(error**2, axis=-1), axis=0))


def tracking_errors(estimate: Array, truth: Array) -> dict[str, float]:
    """ARMSE (mean over t of RMSE(t)) of position, per axis, and of velocity, per axis.

    Returns:
        ``armse_pos``, ``armse_pos_x``, ``armse_pos_y``, ``armse_vel``, ``armse_vel_x``,
        ``armse_vel_y`` (m and m/s).
    """
    e = estimate[..., :4] - truth[..., :4]
    return {
        "armse_pos": float(rmse_over_time(e[..., 0:2]).mean()),
        "armse_pos_x": float(rmse_over_time(e[..., 0:1]).mean()),
        "armse_pos_y": float(rmse_over_time(e[..., 1:2]).mean()),
        "armse_vel": float(rmse_over_time(e[..., 2:4]).mean()),
        "armse_vel_x": float(rmse_over_time(e[..., 2:3]).mean()),
        "armse_vel_y": float(rmse_over_time(e[..., 3:4]).mean()),
    }


def nees(estimate: Array, covariance: Array, truth: Array) -> Array:
    """``(x - x_hat)^T P^-1 (x - x_hat)`` on ``[x, y, vx, vy]``: ``(R, K)``."""
    e = truth[..., :4] - estimate[..., :4]
    P_inv, _ = inv_logdet(covariance[..., :4, :4])
    return mahalanobis(e, P_inv)


def consistency(
    values: Array, dof: int, mask: NDArray[np.bool_] | None = None, level: float = 0.95
) -> dict[str, float]:
    """Share of NIS/NEES values below the ``level`` quantile of ``chi2(dof)``, and their mean.

    Seed 002's test: a consistent filter has about 95 % of the values below the one-sided 95 %
    bound and a mean near ``dof``.

    Args:
        values: NIS or NEES values, any shape; mask: which to count (e.g. detections only).
    """
    v = values if mask is None else values[mask]
    bound = float(stats.chi2.ppf(level, dof))
    if v.size == 0:
        return {"mean": 0.0, "inside": 0.0, "bound": bound, "dof": dof}
    return {
        "mean": float(v.mean()),
        "inside": float(np.mean(v <= bound)),
        "bound": bound,
        "dof": dof,
    }


def mode_accuracy(mode_probs: Array, true_index: NDArray[np.int64]) -> float:
    """Share of steps whose most probable model is the true one (steps with a match only)."""
    valid = true_index >= 0
    if not np.any(valid):
        return 0.0
    return float(np.mean(np.argmax(mode_probs, axis=-1)[valid] == true_index[valid]))


def trajectory_metrics(estimate: Array, truth: Array, heading: Array) -> dict[str, float]:
    r"""Seed 002's accuracy metrics (eqs. 30-32), pooled over runs and steps.

    With ``e_k`` the position error of step k (R runs, K steps):
    ``pos_rmse = sqrt(mean ||e||^2)``, ``pos_mae = mean ||e||``, ``pos_max`` = mean over runs of
    ``max_k ||e_k||``, ``fde`` = mean over runs of ``||e_K||``, ``vel_rmse = sqrt(mean ||e_v||^2)``,
    ``yaw_rmse_deg``: RMSE of ``atan2(vy_hat, vx_hat) - psi`` wrapped to [-180°, 180°).

    Args:
        estimate: ``(R, K, >= 4)``; truth: ``(R, K, 4)``; heading: ``(R, K)`` true yaw (rad).
    """
    e = np.linalg.norm(estimate[..., :2] - truth[..., :2], axis=-1)
    ev = estimate[..., 2:4] - truth[..., 2:4]
    yaw = np.arctan2(estimate[..., 3], estimate[..., 2]) - heading
    yaw = np.mod(yaw + np.pi, 2 * np.pi) - np.pi
    return {
        "pos_rmse": float(np.sqrt(np.mean(e**2))),
        "pos_mae": float(np.mean(e)),
        "pos_max": float(np.mean(e.max(axis=-1))),
        "fde": float(np.mean(e[:, -1])),
        "vel_rmse": float(np.sqrt(np.mean(np.sum(ev**2, axis=-1)))),
        "yaw_rmse_deg": float(np.degrees(np.sqrt(np.mean(yaw**2)))),
    }
