"""One evaluation path for every policy: batched roll-outs, Table-2 scores, paired bootstrap CIs.

:func:`rollout` runs a policy (anything with SB3's ``predict``) on R episodes at once — one
:class:`~imm_gym.sim.core.TrackingCore` with R slots, slot ``r`` reset with seed ``seed + r`` — so
all policies see the same targets and the same sensor noise (common random numbers) whatever
environment settings they need (a designed family's targets are drawn for the evaluated bank
whatever bank a policy brings, :func:`evaluation_config`; :func:`check_paired` holds roll-outs to
the same targets and the same measurements before their errors are paired). A run whose tracker
diverges keeps a position error of ``divergence_error`` (the cap: ``divergence_error / sqrt(2)``
on x and on y), the velocity error of its estimate at the step it diverges at (the error it was
lost with; an entry that is not finite there, the error of a zero velocity) and uniform mode
probabilities from that step to the end of its episode; its NIS and NEES count up to the step before
(:attr:`Rollout.live`), the divergence itself is counted apart (``diverged``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.evaluation.metrics import (
    consistency,
    maneuver_response,
    mode_accuracy,
    mode_prob_tv,
    nees,
    peak_error,
    tracking_errors,
)
from imm_gym.sim.core import INFINITY_STAND_IN, PairedConfig, TrackingCore, design_bank
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.features import FEATURES
from imm_gym.sim.model_order import for_bank

Array = NDArray[np.float64]

#: :func:`paired_bootstrap`'s defaults, the evaluation's (recorded in its ``meta.bootstrap``):
#: resamples of the runs, the resampling generator's seed, the confidence level.
PAIRED_RESAMPLES, PAIRED_SEED, PAIRED_LEVEL = 2000, 0, 0.95


@dataclass(frozen=True)
class Rollout:
    """Per-run, per-step records of one policy (R runs, K steps).

    Attributes:
        estimate: ``(R, K, 4)``; covariance: ``(R, K, 4, 4)``; truth: ``(R, K, 4)``.
        mode_probs: ``(R, K, M)``; tpm: ``(R, K, M, M)`` the TPM each step used.
        nis: ``(R, K)``; detected: ``(R, K)`` the steps whose NIS counts: a detection by a run
            not diverged at that step (False from the step a run diverges at, its NIS 0 there);
            true_model: ``(R, K)``.
        diverged: ``(R,)`` runs whose tracker diverged.
        live: ``(R, K)`` the steps recorded from the tracker itself: False from the step a run
            diverges at (its estimate held at the cap there, its covariance a placeholder ``I``).
        measurements: ``(R, K + 1, m)`` the measurements ``z`` the tracker was given, step 0's
            (the track's start) first, NaN at a missed detection (what the policy's tracker
            saw: the common random numbers :func:`check_paired` holds).
    """

    estimate: Array
    covariance: Array
    truth: Array
    mode_probs: Array
    tpm: Array
    nis: Array
    detected: NDArray[np.bool_]
    true_model: NDArray[np.int64]
    diverged: NDArray[np.bool_]
    live: NDArray[np.bool_]
    measurements: Array

    def groups(self, G: int) -> list[Rollout]:
        """The records of a roll-out from ``G`` starting TPMs (:func:`rollout`'s
        ``initial_tpms``), one :class:`Rollout` of its runs per TPM."""
        R = len(self.diverged) // G
        parts = [getattr(self, f.name) for f in fields(self)]
        return [Rollout(*(a[g * R : (g + 1) * R] for a in parts)) for g in range(G)]

    def diverged_at(self, run: int = 0) -> int | None:
        """The step (1..K, as :func:`rollout` counts them) at which run ``run``'s tracker
        diverged, None if it did not: the first step not :attr:`live`."""
        lost = np.flatnonzero(~self.live[run])
        return int(lost[0]) + 1 if lost.size else None

    def tracker_records(self, run: int = 0) -> tuple[Array, Array, Array]:
        """Run ``run``'s estimates ``(K, 4)``, mode probabilities ``(K, M)`` and covariances
        ``(K, 4, 4)`` as its tracker gave them: NaN (nothing drawn) from the step it diverged at,
        where the roll-out holds the scoring's stand-ins (the estimate at the capped error,
        uniform mode probabilities, the covariance ``I``)."""
        live = self.live[run]
        return (
            np.where(live[:, None], self.estimate[run], np.nan),
            np.where(live[:, None], self.mode_probs[run], np.nan),
            np.where(live[:, None, None], self.covariance[run], np.nan),
        )

    @property
    def squared_position_error(self) -> Array:
        """``(R, K)`` squared position errors, the unit of the paired bootstrap."""
        d = self.estimate[..., :2] - self.truth[..., :2]
        return np.sum(d * d, axis=-1)


#: The reward fields a roll-out sets whatever the policy was trained with: it reads no reward,
#: so every term is off (none then needs the shadow IMM or the stay bank).
NO_REWARD: dict[str, Any] = {
    "reward": "error", "tpm_cost": 0.0, "tpm_change_cost": 0.0, "mode_reward": 0.0,
}


def needs_shadow(config: EnvConfig) -> bool:
    """Whether what a policy of ``config`` observes or acts with is computed from the shadow
    IMM: an observed feature that needs it (:attr:`imm_gym.sim.features.Feature.needs_shadow`),
    or the ``shadow`` detector's belief, placing ``detector_share`` of the jumps or observed
    (``detector_belief``)."""
    features = config.obs_features
    return any(FEATURES[f].needs_shadow for f in features) or (
        config.detector == "shadow"
        and (config.detector_share > 0.0 or "detector_belief" in features)
    )


def evaluation_config(base: EnvConfig, overrides: dict[str, Any]) -> EnvConfig:
    """``base`` with a policy's overrides and the reward off (:data:`NO_REWARD`: a roll-out
    reads no reward, so an agent trained with a reward or cost that needs the shadow IMM is
    taken); the shadow IMM runs only where :func:`needs_shadow` (it is ``"none"`` otherwise,
    which changes no observation: nothing else observed is computed from it). A policy's own
    bank (``bbsca``'s tuned ``Q``) tracks the episodes drawn for ``base``'s: a
    :class:`~imm_gym.sim.core.PairedConfig` whose ``design_bank`` is ``base``'s, so that a
    designed family (``family.designed_share > 0``, whose turns follow the CT models' noise)
    gives it the targets every other policy meets."""
    config = base.replace(**{**overrides, **NO_REWARD, "shadow": "fixed"})
    if not needs_shadow(config):
        config = config.replace(shadow="none")
    drawn_for = design_bank(base)
    if drawn_for is not None and config.bank != drawn_for:
        kept = {f.name: getattr(config, f.name) for f in fields(EnvConfig)}
        config = PairedConfig(**kept, design_bank=drawn_for)
    return config


def _runs_differing(a: Array, b: Array) -> str:
    """The runs (first axis) where ``a`` and ``b`` are not the same, NaN equal to NaN, the first
    five of them (all runs for arrays of other shapes)."""
    if a.shape != b.shape:
        return "all"
    same = (a == b) | (np.isnan(a) & np.isnan(b))
    runs = np.flatnonzero(~same.reshape(len(a), -1).all(axis=1))
    return f"{runs[:5].tolist()}{' ...' if runs.size > 5 else ''}"


def check_paired(rollouts: Mapping[str, Rollout]) -> None:
    """Raise :class:`ValueError` naming the first of ``rollouts`` whose runs are not the first
    one's — another number of runs or steps, other targets (``truth`` not bit for bit the same)
    or other measurements (:attr:`Rollout.measurements`: other sensor noise, detections or
    outliers, as a policy's overrides of the sensor give) —: a paired difference
    (:func:`paired_bootstrap`) holds only between roll-outs of the same runs (common random
    numbers). Cheap beside the roll-outs: one comparison of the ``(R, K, 4)`` truths and the
    ``(R, K + 1, m)`` measurements per policy."""
    items = iter(rollouts.items())
    first = next(items, None)
    if first is None:
        return
    ref_name, ref = first
    for name, other in items:
        if other.truth.shape != ref.truth.shape:
            raise ValueError(
                f"{name!r} ran {other.truth.shape[0]} runs of {other.truth.shape[1]} steps and "
                f"{ref_name!r} {ref.truth.shape[0]} of {ref.truth.shape[1]}: they cannot be paired"
            )
        if not np.array_equal(other.truth, ref.truth):
            raise ValueError(
                f"{name!r} was rolled out on other targets than {ref_name!r} (runs "
                f"{_runs_differing(other.truth, ref.truth)} differ): their errors cannot be "
                "paired (common random numbers)"
            )
        if not np.array_equal(other.measurements, ref.measurements, equal_nan=True):
            raise ValueError(
                f"{name!r} was given other measurements than {ref_name!r} (runs "
                f"{_runs_differing(other.measurements, ref.measurements)} differ: other sensor "
                "noise, detections or outliers): their errors cannot be paired (common random "
                "numbers)"
            )


def rollout(
    policy: Any,
    config: EnvConfig,
    runs: int,
    seed: int,
    progress: Callable[[int], None] | None = None,
    make_core: Callable[[EnvConfig, int], Any] = TrackingCore,
    initial_tpms: Array | None = None,
) -> Rollout:
    """Run ``policy`` on ``runs`` episodes seeded ``seed + r``; see the module docstring.

    Args:
        policy: an object with ``predict(obs, state, episode_start, deterministic)``; a policy
            shared by the models is rebuilt for the bank's size
            (:func:`~imm_gym.sim.model_order.for_bank`).
        config: the environment configuration (with the policy's overrides applied).
        runs: R, the number of Monte-Carlo runs.
        seed: run ``r`` uses seed ``seed + r``.
        progress: called with the number of steps done after each step.
        make_core: builds the core of ``runs`` slots: a :class:`TrackingCore`, or a
            :class:`~imm_gym.evaluation.distributed.ShardedCore` spread over a Ray cluster (the
            same numbers).
        initial_tpms: ``(G, M, M)``: every run from each of these starting TPMs instead of the
            configuration's, in one batch of ``G * runs`` slots (slot ``g * runs + r`` is run
            ``r`` from ``initial_tpms[g]``; the records in that order). The floor ``p_min`` is
            lowered to their smallest entry where it is above it, so each starts as given.
    """
    policy = for_bank(policy, len(config.bank))
    G = 1
    if initial_tpms is not None:
        G = len(initial_tpms)
        config = config.replace(p_min=min(config.p_min, float(np.min(initial_tpms))))
    core = make_core(config, G * runs)
    core.reset(
        np.arange(G * runs),
        [seed + r for _ in range(G) for r in range(runs)],
        None if initial_tpms is None else np.repeat(initial_tpms, runs, axis=0),
    )
    R, K, M = G * runs, core.horizon, core.M
    est = np.empty((R, K, 4))
    cov = np.empty((R, K, 4, 4))
    probs = np.empty((R, K, M))
    tpms = np.empty((R, K, M, M))
    nis = np.zeros((R, K))
    detected = np.zeros((R, K), dtype=bool)
    live = np.zeros((R, K), dtype=bool)
    truth = core.truth[:, 1:].copy()
    true_model = core.true_model.copy()
    measurements = np.where(core.detected[..., None], core.z, np.nan)
    obs = core.observe()
    state = None
    start = np.ones(R, dtype=bool)
    alive = np.ones(R, dtype=bool)
    cap = config.divergence_error / np.sqrt(2.0)
    held_velocity_error = np.zeros((R, 2))
    for k in range(K):
        actions, state = policy.predict(obs, state=state, episode_start=start, deterministic=True)
        start = np.zeros(R, dtype=bool)
        result = core.step(actions, active=alive)
        info = result.info
        # a run diverged at this step records the capped position error and this step's velocity
        # error from this step on, and its NIS counts up to the step before (the diverging step's
        # is excluded, as every later one)
        diverging = alive & result.terminated
        alive &= ~result.terminated
        live[:, k] = alive
        detected[:, k] = alive & info["detected"]
        velocity = info["estimate"][diverging, 2:4]  # NaN is 0 here, an infinity its stand-in
        velocity = np.where(np.abs(velocity) < INFINITY_STAND_IN, velocity, 0.0)
        held_velocity_error[diverging] = velocity - truth[diverging, k, 2:4]
        held = np.concatenate([truth[:, k, :2] + cap, truth[:, k, 2:4] + held_velocity_error], -1)
        est[:, k] = np.where(alive[:, None], info["estimate"][:, :4], held)
        cov[:, k] = np.where(alive[:, None, None], info["covariance"][:, :4, :4], np.eye(4))
        probs[:, k] = np.where(alive[:, None], info["mode_probs"], 1.0 / M)
        tpms[:, k] = info["tpm"]
        nis[:, k] = np.where(alive, info["nis"], 0.0)
        obs = result.obs
        if progress is not None:
            progress(k + 1)
    return Rollout(
        est, cov, truth, probs, tpms, nis, detected, true_model, ~alive, live, measurements
    )


def score(rollout: Rollout, dim_z: int = 2) -> dict[str, Any]:
    """Table-2 ARMSEs, NIS/NEES consistency, mode-identification accuracy, divergences, and the
    IMM behaviour: ``mode_prob_tv`` (:func:`~imm_gym.evaluation.metrics.mode_prob_tv`),
    ``peak_error`` (:func:`~imm_gym.evaluation.metrics.peak_error`) and ``maneuver_response``
    (:func:`~imm_gym.evaluation.metrics.maneuver_response`, 10 steps; None without maneuvers).
    A diverged run counts in the errors with its held error and in the mode accuracy with uniform
    mode probabilities (:func:`rollout`); the total variation is over the step pairs both live
    (held probabilities do not move: a divergence would read as smooth); NIS and NEES are over
    the live steps only
    (:attr:`Rollout.live`: a held estimate has no covariance to test; scored against ``I`` its
    NEES would be of the order of ``divergence_error²``); the divergences count in ``diverged``."""
    out: dict[str, Any] = tracking_errors(rollout.estimate, rollout.truth)
    out["nis"] = consistency(rollout.nis, dim_z, mask=rollout.detected)
    out["nees"] = consistency(
        nees(rollout.estimate, rollout.covariance, rollout.truth), 4, mask=rollout.live
    )
    out["mode_accuracy"] = mode_accuracy(rollout.mode_probs, rollout.true_model)
    out["diverged"] = int(rollout.diverged.sum())
    out["mode_prob_tv"] = mode_prob_tv(rollout.mode_probs, rollout.live)
    out["peak_error"] = peak_error(rollout.estimate, rollout.truth)
    out["maneuver_response"] = maneuver_response(
        rollout.estimate, rollout.truth, rollout.true_model
    )
    return out


def armse_from_squared(err2: Array) -> float:
    """Position ARMSE from squared errors ``(R, K)``: ``mean_t sqrt(mean_r e^2)``."""
    return float(np.sqrt(err2.mean(axis=0)).mean())


def paired_bootstrap(
    err2_a: Array,
    err2_b: Array,
    n_boot: int = PAIRED_RESAMPLES,
    seed: int = PAIRED_SEED,
    level: float = PAIRED_LEVEL,
) -> dict[str, float]:
    """Difference of position ARMSE, policy A minus policy B, with a paired bootstrap CI.

    Runs are resampled with replacement — the same runs for both policies, so the shared targets
    and noise cancel — and the ARMSE difference recomputed; the interval is the percentile
    interval of the resampled differences. A resample is a weight vector ``w`` (counts / R), so
    ``mean_r e^2`` is one matrix product for all resamples.

    Args:
        err2_a, err2_b: ``(R, K)`` squared position errors of the same runs.
        n_boot: number of resamples; seed: the resampling generator's seed.

    Returns:
        ``diff`` (m), ``low``, ``high`` (the CI), ``relative`` (diff / ARMSE of B).
    """
    if err2_a.shape != err2_b.shape:
        raise ValueError(f"paired errors must have the same shape: {err2_a.shape}, {err2_b.shape}")
    R = err2_a.shape[0]
    rng = np.random.default_rng(seed)
    w = rng.multinomial(R, np.full(R, 1.0 / R), size=n_boot) / R  # (B, R)
    boot = np.sqrt(w @ err2_a).mean(axis=1) - np.sqrt(w @ err2_b).mean(axis=1)
    alpha = (1.0 - level) / 2.0
    diff = armse_from_squared(err2_a) - armse_from_squared(err2_b)
    return {
        "diff": diff,
        "low": float(np.quantile(boot, alpha)),
        "high": float(np.quantile(boot, 1.0 - alpha)),
        "relative": diff / armse_from_squared(err2_b),
    }
