"""Track initiation from the first measurement (SPEC §6, "filter start")."""

from __future__ import annotations

import math
import sys

import numpy as np
from numpy.typing import NDArray

from imm_gym.validation import ConfigError, check_range

Array = NDArray[np.float64]

MIN_VELOCITY_STD = math.sqrt(sys.float_info.min)
"""The smallest prior standard deviation (m/s) of a first velocity estimate: the smallest whose
variance is a normal float64."""

MAX_VELOCITY_STD = 1e6
"""The largest prior standard deviation (m/s) of a first velocity estimate: far beyond any
target (a track started knowing nothing of its velocity takes tens of m/s,
:data:`~imm_gym.sim.replay.UNKNOWN_VELOCITY_STD`), its variance far from overflow."""


def initiate(
    sensor: object, z0: Array, velocity: Array, velocity_std: float = 5.0
) -> tuple[Array, Array]:
    """Initial state and covariance from one measurement and a velocity guess.

    Position from the measurement (polar to Cartesian for the sonar), velocity given;
    ``P0 = blockdiag(J R J^T, velocity_std^2 I)`` with ``J`` the Jacobian of the conversion.

    Args:
        sensor: a sensor with ``initial_position`` (:mod:`imm_gym.tracking.sensors`).
        z0: ``(m,)`` or ``(N, m)`` first measurements (``m`` the sensor's ``dim_z``).
        velocity: ``(2,)`` or ``(N, 2)`` velocity (m/s).
        velocity_std: standard deviation of the velocity guess (m/s), in
            ``[MIN_VELOCITY_STD, MAX_VELOCITY_STD]``.

    Returns:
        ``x0 (N, 4)`` and ``P0 (N, 4, 4)``.
    """
    check_range("velocity_std", velocity_std, MIN_VELOCITY_STD, MAX_VELOCITY_STD)
    z0 = np.atleast_2d(np.asarray(z0, dtype=np.float64))
    dim_z = getattr(sensor, "dim_z", z0.shape[-1])
    if z0.ndim != 2 or z0.shape[1] != dim_z:
        raise ConfigError(f"z0 must have shape ({dim_z},) or (N, {dim_z}), got {z0.shape}")
    N = z0.shape[0]
    v = np.asarray(velocity, dtype=np.float64)
    if v.shape not in ((2,), (N, 2)):
        raise ConfigError(f"velocity must have shape (2,) or ({N}, 2), got {v.shape}")
    v = np.broadcast_to(v, (N, 2))
    if not np.all(np.isfinite(z0)) or not np.all(np.isfinite(v)):
        raise ConfigError("z0 and velocity must be finite")
    pos, pos_cov = sensor.initial_position(z0)  # type: ignore[attr-defined]
    check_factorable(sensor, pos_cov)
    x0 = np.concatenate([pos, v], axis=-1)
    P0 = np.zeros((N, 4, 4))
    P0[:, :2, :2] = pos_cov
    P0[:, 2, 2] = P0[:, 3, 3] = velocity_std**2
    return x0, P0


def check_factorable(sensor: object, pos_cov: Array) -> None:
    """Refuse first-measurement position covariances ``(N, 2, 2)`` that float64 cannot factor.

    ``J R J^T`` is positive definite in exact arithmetic, but its Cholesky factorization fails
    in float64 once its standard deviations differ by about 1e8: a range accuracy of 1e-12 m
    beside a bearing's 4 m across range. The error names the sensor's noise fields
    (``noise_fields``).
    """
    try:
        np.linalg.cholesky(pos_cov)
    except np.linalg.LinAlgError:
        fields = getattr(sensor, "noise_fields", {})
        named = ", ".join(f"{name} = {getattr(sensor, attr)!r}" for attr, name in fields.items())
        raise ConfigError(
            f"{named or type(sensor).__name__}: the covariance of the first measurement's "
            "position is not positive definite in float64; its standard deviations (the sonar's "
            "sigma_r along range and range x sigma_theta across it) may differ by a factor of "
            "about 1e7 at most"
        ) from None
