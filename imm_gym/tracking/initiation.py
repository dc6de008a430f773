"""Track initiation from the first measurement (SPEC §6, "filter start")."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imm_gym.validation import ConfigError, check_range

Array = NDArray[np.float64]


def initiate(
    sensor: object, z0: Array, velocity: Array, velocity_std: float = 5.0
) -> tuple[Array, Array]:
    """Initial state and covariance from one measurement and a velocity guess.

    Position from the measurement (polar to Cartesian for the sonar), velocity given;
    ``P0 = blockdiag(J R J^T, velocity_std^2 I)`` with ``J`` the Jacobian of the conversion.

    Args:
        sensor: a sensor with ``initial_position`` (:mod:`imm_gym.tracking.sensors`).
        z0: ``(N, m)`` first measurements.
        velocity: ``(2,)`` or ``(N, 2)`` velocity (m/s).
        velocity_std: standard deviation of the velocity guess (m/s).

    Returns:
        ``x0 (N, 4)`` and ``P0 (N, 4, 4)``.
    """
    check_range("velocity_std", velocity_std, 0.0, lo_open=True)
    z0 = np.atleast_2d(np.asarray(z0, dtype=np.float64))
    N = z0.shape[0]
    v = np.broadcast_to(np.asarray(velocity, dtype=np.float64), (N, 2))
    if not np.all(np.isfinite(z0)) or not np.all(np.isfinite(v)):
        raise ConfigError("z0 and velocity must be finite")
    pos, pos_cov = sensor.initial_position(z0)  # type: ignore[attr-defined]
    x0 = np.concatenate([pos, v], axis=-1)
    P0 = np.zeros((N, 4, 4))
    P0[:, :2, :2] = pos_cov
    P0[:, 2, 2] = P0[:, 3, 3] = velocity_std**2
    return x0, P0
