"""The clairvoyant filter: one filter told the true motion of every step (SPEC §6), and whether
its errors bound the policies' on a given run set.

The filter knows the exact transition ``F_CT(omega_k)`` of the truth (CV when ``omega_k = 0``)
and uses the process noise of the bank's model of that type (the CV model's ``Q`` on straight
steps, the ``Q`` of the CT model turning the same way on turns). It runs through the same
predict/update code as the IMM bank.

It lower-bounds what a TPM policy on the same bank can reach only in expectation, and only where
its models and noise match the bank's: a finite run set, a target close to the nonlinear sensor
(the UKF's approximation is then poor for both) or a noise-free truth that a smaller ``Q`` would
follow better can let a policy beat it. :func:`clairvoyant_role` therefore calls it a ``bound``
only when no policy beat it on the runs at hand, a ``reference`` otherwise; motion it cannot
follow (tangential acceleration, a bank without CV or CT models) is named by
:func:`unsupported`. Its runs are scored under the policies' divergence rule
(:func:`hold_diverged`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.scenarios.segments import Truth
from imm_gym.sim.core import INFINITY_STAND_IN
from imm_gym.tracking.filters import Filter, MeasurementModel, make_filter, predict
from imm_gym.tracking.hetero import HeteroBank
from imm_gym.tracking.models import MotionModel, ct_transition
from imm_gym.validation import ConfigError

Array = NDArray[np.float64]

#: The errors a policy is compared on (:func:`~imm_gym.evaluation.metrics.tracking_errors`).
BOUNDED_KEYS = (
    "armse_pos",
    "armse_pos_x",
    "armse_pos_y",
    "armse_vel",
    "armse_vel_x",
    "armse_vel_y",
)

#: The bank models the filter borrows ``Q`` from: (description, test).
_NEEDED = (
    ("CV", lambda m: m.kind == "cv"),
    ("left-turn CT", lambda m: m.kind == "ct" and m.omega > 0),
    ("right-turn CT", lambda m: m.kind == "ct" and m.omega < 0),
)


def unsupported(truth: Truth, models: Sequence[MotionModel] | HeteroBank) -> str | None:
    """Why the clairvoyant filter cannot run on ``truth`` with the bank ``models``, or None.

    It follows straight and turn motion only (no tangential acceleration) and needs a CV, a
    left-turn CT and a right-turn CT model among linear bank models.
    """
    if isinstance(models, HeteroBank):
        return "the clairvoyant filter runs linear CV/CT models; this bank is NCV/CT/CTRA"
    accelerating = np.any(truth.accel != 0.0, axis=-1)
    if np.any(accelerating):
        return (
            "the clairvoyant filter is defined for straight and turn segments only; "
            f"{int(accelerating.sum())} of {accelerating.size} runs have acceleration segments"
        )
    for what, needed in _NEEDED:
        if not any(needed(m) for m in models):
            return f"the clairvoyant filter needs a {what} model in the bank"
    return None


def _noise_by_motion(models: Sequence[MotionModel], T: float) -> tuple[Array, Array, Array]:
    """``Q`` for straight, left-turn and right-turn steps from the bank's CV / CT models, at the
    sampling period ``T``."""
    q_cv, q_left, q_right = (
        next(m for m in models if needed(m)).noise_covariance(4, T) for _, needed in _NEEDED
    )
    return q_cv, q_left, q_right


def clairvoyant_role(
    errors: Mapping[str, float], policies: Mapping[str, Mapping[str, Any]]
) -> dict[str, Any]:
    """Whether the clairvoyant filter's ``errors`` bound the ``policies``' on these runs.

    A policy beats it when any of its :data:`BOUNDED_KEYS` is below the filter's.

    Args:
        errors: the filter's :func:`~imm_gym.evaluation.metrics.tracking_errors`.
        policies: each policy's scores, holding at least :data:`BOUNDED_KEYS`.

    Returns:
        ``role`` (``"bound"`` or ``"reference"``), ``note`` (one sentence) and ``beaten_by``
        (``{policy: [keys it is lower on]}``, empty for a bound).
    """
    beaten_by = {
        name: [k for k in BOUNDED_KEYS if row[k] < errors[k]] for name, row in policies.items()
    }
    beaten_by = {name: keys for name, keys in beaten_by.items() if keys}
    if beaten_by:
        note = f"reference: beaten by {', '.join(beaten_by)}"
        return {"role": "reference", "note": note, "beaten_by": beaten_by}
    note = (
        "bound: a lower bound in expectation for TPM policies on this bank (the true motion at "
        "every step, the bank's noise); no policy beat it on these runs"
    )
    return {"role": "bound", "note": note, "beaten_by": {}}


def _check_shapes(arrays: Mapping[str, tuple[Any, tuple[int, ...]]]) -> None:
    """Refuse an input whose shape is not the one the truth's ``R`` runs of ``K`` steps call
    for (measurements of steps 0..K would otherwise update every step one measurement late)."""
    for name, (value, shape) in arrays.items():
        if np.shape(value) != shape:
            raise ConfigError(
                f"clairvoyant_filter: {name} must have shape {shape} (R runs, K steps of the "
                f"truth), got {np.shape(value)}"
            )


def clairvoyant_filter(
    truth: Truth,
    z: Array,
    sensor: MeasurementModel,
    models: Sequence[MotionModel],
    x0: Array,
    P0: Array,
    filter: str | Filter = "ukf",
    detected: NDArray[np.bool_] | None = None,
) -> tuple[Array, Array]:
    """Run the clairvoyant filter over R runs.

    Args:
        truth: the runs' truth (turn rates per step); tangential accelerations are not supported
            (:func:`unsupported`).
        z: ``(R, K, m)`` measurements at steps 1..K.
        sensor, models: the sensor and the bank whose noise levels the filter borrows.
        x0, P0: ``(R, 4)``, ``(R, 4, 4)`` initial estimate.
        filter: ``"ukf"``, ``"ukf-cholesky"``, ``"ekf"`` or ``"kf"``.
        detected: ``(R, K)`` detection flags (filter predicts only where False).

    Returns:
        Estimates ``(R, K, 4)`` and covariances ``(R, K, 4, 4)``.

    Raises:
        ConfigError: the truth or the bank unsupported, or an input whose shape is not the truth's
            ``R`` and ``K``'s.
    """
    reason = unsupported(truth, models)
    if reason is not None:
        raise ConfigError(reason)
    flt = make_filter(filter) if isinstance(filter, str) else filter
    q_cv, q_left, q_right = _noise_by_motion(models, truth.T)
    R, K = truth.turn_rate.shape
    _check_shapes(
        {"z": (z, (R, K, sensor.dim_z)), "x0": (x0, (R, 4)), "P0": (P0, (R, 4, 4))}
        | ({} if detected is None else {"detected": (detected, (R, K))})
    )
    omega = truth.turn_rate
    Q = np.where(
        (omega == 0)[..., None, None],
        q_cv,
        np.where((omega > 0)[..., None, None], q_left, q_right),
    )
    F = ct_transition(omega, truth.T)
    x, P = np.array(x0, dtype=np.float64), np.array(P0, dtype=np.float64)
    xs, Ps = np.empty((R, K, 4)), np.empty((R, K, 4, 4))
    for k in range(K):
        x_pred, P_pred = predict(x, P, F[:, k], Q[:, k])
        upd = flt.update(x_pred, P_pred, z[:, k], sensor)
        if detected is None:
            x, P = upd.x, upd.P
        else:
            det = detected[:, k]
            x = np.where(det[:, None], upd.x, x_pred)
            P = np.where(det[:, None, None], upd.P, P_pred)
        xs[:, k], Ps[:, k] = x, P
    return xs, Ps


def hold_diverged(
    xs: Array, Ps: Array, truth: Array, divergence_error: float, divergence_cov: float
) -> tuple[Array, NDArray[np.bool_]]:
    """The filter's estimates as the policies' are scored
    (:func:`~imm_gym.evaluation.rollout.rollout`): a run diverges at the first step ``k`` whose
    estimate is not finite, whose position error exceeds ``divergence_error`` or whose
    :math:`P_{xx} + P_{yy}` exceeds ``divergence_cov``; from ``k`` on its position is held
    ``divergence_error / sqrt(2)`` off the truth on x and on y and its velocity error at step
    ``k``'s (an entry NaN or beyond :data:`~imm_gym.sim.core.INFINITY_STAND_IN` as 0).

    Args:
        xs, Ps: ``(R, K, 4)``, ``(R, K, 4, 4)`` of :func:`clairvoyant_filter`.
        truth: ``(R, K, 4)`` the true states at steps 1..K.

    Returns:
        The held estimates ``(R, K, 4)`` and the runs that diverged ``(R,)``.
    """
    R, K = xs.shape[:2]
    error = np.sqrt(np.sum((xs[..., :2] - truth[..., :2]) ** 2, axis=-1))
    bad = (
        ~np.all(np.isfinite(xs), axis=-1)
        | ~(error <= divergence_error)
        | ~(Ps[..., 0, 0] + Ps[..., 1, 1] <= divergence_cov)
    )
    diverged = bad.any(axis=1)
    first = np.where(diverged, bad.argmax(axis=1), K)
    runs = np.flatnonzero(diverged)
    velocity = xs[runs, first[runs], 2:4]
    velocity_error = np.zeros((R, 2))
    velocity = np.where(np.abs(velocity) < INFINITY_STAND_IN, velocity, 0.0)
    velocity_error[runs] = velocity - truth[runs, first[runs], 2:4]
    position = truth[..., :2] + divergence_error / np.sqrt(2.0)
    held = np.concatenate([position, truth[..., 2:4] + velocity_error[:, None]], axis=-1)
    after = np.arange(K)[None, :] >= first[:, None]
    return np.where(after[..., None], held, xs), diverged
