"""Tracking metrics: RMSE(t) and ARMSE (SPEC §3, eqs. 20-21), NIS/NEES consistency (seed 002),
mode-identification accuracy, and what IMM users look at besides: the mode probabilities'
step-to-step variation, the peak error and the error just after each change of the true model
(a maneuver's start or end).

Shapes: R runs, K scored steps; estimates ``(R, K, n >= 4)`` and truth ``(R, K, 4)`` on
``[x, y, vx, vy]``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from imm_gym.tracking.linalg import inv_logdet, mahalanobis

Array = NDArray[np.float64]

#: :func:`stratified_bootstrap_iqm`'s defaults, the evaluation's (recorded in its
#: ``meta.bootstrap``): resamples, the resampling generator's seed, the confidence level.
IQM_RESAMPLES, IQM_SEED, IQM_LEVEL = 10_000, 0, 0.95


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
) -> dict[str, float | None]:
    """Share of NIS/NEES values below the ``level`` quantile of ``chi2(dof)``, and their mean.

    Seed 002's test: a consistent filter has about 95 % of the values below the one-sided 95 %
    bound and a mean near ``dof``.

    Args:
        values: NIS or NEES values, any shape; mask: which to count (e.g. detections only).

    Returns:
        ``mean``, ``inside`` (None, not 0, when no value counts: every run diverged at its first
        step, say), ``bound``, ``dof``.
    """
    v = values if mask is None else values[mask]
    bound = float(stats.chi2.ppf(level, dof))
    if v.size == 0:
        return {"mean": None, "inside": None, "bound": bound, "dof": dof}
    return {
        "mean": float(v.mean()),
        "inside": float(np.mean(v <= bound)),
        "bound": bound,
        "dof": dof,
    }


def mode_accuracy(mode_probs: Array, true_index: NDArray[np.int64]) -> float | None:
    """Share of steps whose most probable model is the true one (steps with a match only; None
    when no step has one).

    The true model must be more probable than every other: a tie at the top — the uniform
    probabilities of a diverged run, or of the uniform TPM after a missed detection — identifies
    no model, and counts as a miss (not as the first model, which ``argmax`` would return)."""
    valid = true_index >= 0
    if not np.any(valid):
        return None
    probs, true = mode_probs[valid], true_index[valid]
    is_true = np.arange(probs.shape[-1]) == true[:, None]
    p_true = probs[is_true]
    p_other = np.where(is_true, -np.inf, probs).max(axis=-1)
    return float(np.mean(p_true > p_other))


def mode_prob_tv(mode_probs: Array, live: NDArray[np.bool_] | None = None) -> float | None:
    r"""Mean per-step total variation of the mode probabilities.

    ``TV_k = 1/2 * sum_j |mu_j(k) - mu_j(k-1)|`` for ``k = 2..K`` — the first scored step has no
    predecessor here (the initial probabilities ``mu(0)`` are not part of the record), so the
    mean is over the ``K - 1`` differences of each run and over the R runs, or, with ``live``,
    over the differences whose steps ``k - 1`` and ``k`` are both live (a diverged run's held
    probabilities do not move: counted, they would read as a smooth IMM). 0 for probabilities
    that never move, 1 for one-hot probabilities that switch model every step; a jittery IMM
    scores high even where its estimates are good.

    Args:
        mode_probs: ``(R, K, M)``.
        live: ``(R, K)`` the steps recorded from the tracker (:attr:`Rollout.live
            <imm_gym.evaluation.rollout.Rollout.live>`); None: every step.

    Returns:
        The mean of ``TV_k``, None when no difference counts (K < 2, or no two consecutive live
        steps).
    """
    if mode_probs.shape[-2] < 2:
        return None
    tv = 0.5 * np.abs(np.diff(mode_probs, axis=-2)).sum(axis=-1)
    if live is not None:
        tv = tv[live[..., 1:] & live[..., :-1]]
    if tv.size == 0:
        return None
    return float(tv.mean())


def peak_error(estimate: Array, truth: Array) -> float:
    r"""Mean over runs of each run's largest position error: ``mean_r max_k ||e_{r,k}||``.

    The peak a user meets on one track (seed 002's ``pos_max``), rather than ``max_k RMSE(k)``,
    the peak of the curve averaged over runs, which hides when each run's worst moment comes.

    Args:
        estimate: ``(R, K, >= 2)``; truth: ``(R, K, >= 2)`` (position first).
    """
    e = np.linalg.norm(estimate[..., :2] - truth[..., :2], axis=-1)
    return float(np.mean(e.max(axis=-1)))


def maneuver_starts(true_model: NDArray[np.int64]) -> NDArray[np.bool_]:
    """``(R, K)``: True at the steps ``k >= 2`` whose true model differs from step ``k - 1``'s
    (a turn's start and its end; -1, no matching bank model, counts as a model of its own)."""
    starts = np.zeros(true_model.shape, dtype=bool)
    starts[..., 1:] = true_model[..., 1:] != true_model[..., :-1]
    return starts


def maneuver_response(
    estimate: Array, truth: Array, true_model: NDArray[np.int64], window: int = 10
) -> float | None:
    r"""Position RMSE over the ``window`` steps from each change of the true model (a maneuver's
    start or its end).

    With ``S`` the maneuver starts (:func:`maneuver_starts`: ``(r, s)`` such that the true model
    of step ``s`` differs from step ``s - 1``'s) and ``c_{r,k} = #{s in S_r : s <= k < s + window}``
    the number of windows step ``k`` of run ``r`` lies in,
    ``sqrt(sum_{r,k} c_{r,k} ||e_{r,k}||^2 / sum_{r,k} c_{r,k})``: every maneuver's window weighs
    the same (overlapping windows count a step once per window, a window cut by the episode end
    counts its steps inside it), pooled over runs.

    Args:
        estimate: ``(R, K, >= 2)``; truth: ``(R, K, >= 2)``; true_model: ``(R, K)`` the bank index
            of each step's true motion (``Rollout.true_model``).
        window: steps per maneuver, the start included.

    Returns:
        The RMSE (m), or None when no run has a maneuver.
    """
    if window < 1:
        raise ValueError(f"window must be >= 1 step, got {window}")
    starts = np.cumsum(maneuver_starts(true_model), axis=-1)
    count = starts.copy()
    count[..., window:] -= starts[..., :-window]
    if not count.any():
        return None
    e2 = np.sum((estimate[..., :2] - truth[..., :2]) ** 2, axis=-1)
    return float(np.sqrt(np.sum(count * e2) / count.sum()))


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


def interquartile_mean(scores: Array) -> float:
    r"""The interquartile mean of ``scores`` (all axes pooled), as Agarwal et al. (2021) compute it
    (rliable's ``aggregate_iqm``: ``scipy.stats.trim_mean(x, 0.25)``).

    With the n scores sorted, ``x_(1) <= ... <= x_(n)``, and ``c = floor(n / 4)`` whole scores cut
    at each end: ``IQM = 1 / (n - 2c) * sum_{i=c+1}^{n-c} x_(i)``. Whole scores only, no
    fractional weights: for n = 5 the mean of the middle 3, for n = 8 of the middle 4, for
    n <= 3 the plain mean (nothing cut).
    """
    return float(stats.trim_mean(np.ravel(scores), 0.25))


def stratified_bootstrap_iqm(
    scores: Array, n_boot: int = IQM_RESAMPLES, seed: int = IQM_SEED, level: float = IQM_LEVEL
) -> dict[str, float]:
    """Interquartile mean of ``scores (tasks, seeds)`` with a stratified bootstrap CI.

    Each resample draws, for every task (scenario) separately, its seeds with replacement, and
    takes the IQM (:func:`interquartile_mean`) of all resampled scores; the interval is the
    percentile interval of the resampled IQMs (Agarwal et al., "Deep RL at the edge of the
    statistical precipice", 2021).

    Args:
        scores: ``(tasks, seeds)`` one score per training seed and task (a 1-d array: one task).
        n_boot: number of resamples; seed: the resampling generator's seed; level: the CI's.

    Returns:
        ``iqm``, ``low``, ``high``.
    """
    x = np.atleast_2d(np.asarray(scores, dtype=np.float64))
    tasks, seeds = x.shape
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, seeds, size=(n_boot, tasks, seeds))
    resampled = np.take_along_axis(np.broadcast_to(x, (n_boot, tasks, seeds)), picks, axis=2)
    boot = stats.trim_mean(resampled.reshape(n_boot, -1), 0.25, axis=1)
    alpha = (1.0 - level) / 2.0
    return {
        "iqm": interquartile_mean(x),
        "low": float(np.quantile(boot, alpha)),
        "high": float(np.quantile(boot, 1.0 - alpha)),
    }
