"""The clairvoyant filter: a bound no TPM policy can beat (SPEC §6).

One filter that knows the true motion of every step — the exact transition ``F_CT(omega_k)`` of
the truth (CV when ``omega_k = 0``) — and uses the process noise of the bank's model of that type
(the CV model's ``Q`` on straight steps, the ``Q`` of the CT model turning the same way on turns).
It runs through the same predict/update code as the IMM bank.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from imm_gym.scenarios.segments import Truth
from imm_gym.tracking.filters import Filter, MeasurementModel, make_filter, predict
from imm_gym.tracking.models import MotionModel, ct_transition
from imm_gym.validation import ConfigError

Array = NDArray[np.float64]


def _noise_by_motion(models: Sequence[MotionModel]) -> tuple[Array, Array, Array]:
    """``Q`` for straight, left-turn and right-turn steps from the bank's CV / CT models."""

    def first(pred: object, what: str) -> Array:
        for m in models:
            if pred(m):  # type: ignore[operator]
                return m.noise_covariance(4)
        raise ConfigError(f"the clairvoyant filter needs a {what} model in the bank")

    q_cv = first(lambda m: m.kind == "cv", "CV")
    q_left = first(lambda m: m.kind == "ct" and m.omega > 0, "left-turn CT")
    q_right = first(lambda m: m.kind == "ct" and m.omega < 0, "right-turn CT")
    return q_cv, q_left, q_right


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
        truth: the runs' truth (turn rates per step); tangential accelerations are not supported.
        z: ``(R, K, m)`` measurements at steps 1..K.
        sensor, models: the sensor and the bank whose noise levels the filter borrows.
        x0, P0: ``(R, 4)``, ``(R, 4, 4)`` initial estimate.
        filter: ``"ukf"``, ``"ekf"`` or ``"kf"``.
        detected: ``(R, K)`` detection flags (filter predicts only where False).

    Returns:
        Estimates ``(R, K, 4)`` and covariances ``(R, K, 4, 4)``.
    """
    if np.any(truth.accel != 0.0):
        raise ConfigError("the clairvoyant filter is defined for straight and turn segments only")
    flt = make_filter(filter) if isinstance(filter, str) else filter
    q_cv, q_left, q_right = _noise_by_motion(models)
    R, K = truth.turn_rate.shape
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
