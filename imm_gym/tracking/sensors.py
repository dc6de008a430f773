r"""Sensors: the range-bearing sonar and a linear position(+velocity) sensor.

A sensor is a measurement model (``h``, its Jacobian, ``R``, the residual) plus a simulator that
draws measurements from the truth. Simulation draws, per run and in this order, the standard
normal noise ``(K+1, m)``, the outlier uniforms ``(K+1,)`` and the detection uniforms ``(K+1,)``,
whatever the outlier and detection settings: changing those settings keeps every other draw
identical (common random numbers).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.linalg import wrap_angle
from imm_gym.validation import (
    MAX_DISTANCE,
    MAX_SPEED,
    ConfigError,
    check_range,
    check_sequence,
    store,
)

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Measurements:
    """Measurements of N runs at ``t = 0, T, ..., K T``.

    Attributes:
        z: ``(N, K+1, m)`` measurements; where ``detected`` is False the value is the would-be
            measurement and the filters ignore it.
        detected: ``(N, K+1)`` False for a missed detection (filters predict only). Always True at
            ``t = 0``, the detection that initiates the track.
        outlier: ``(N, K+1)`` True where the noise was inflated.
    """

    z: Array
    detected: NDArray[np.bool_]
    outlier: NDArray[np.bool_]


@dataclass(frozen=True)
class _Clutter:
    """Outlier and missed-detection settings shared by the sensors; ``noise_fields`` maps a
    sensor's noise attributes to the names its errors give them."""

    outlier_prob: float = 0.0
    outlier_scale: float = 10.0
    detection_prob: float = 1.0

    noise_fields: ClassVar[dict[str, str]] = {}

    def _check_clutter(self, prefix: str) -> None:
        for name, lo, hi, lo_open in (
            ("outlier_prob", 0.0, 1.0, False),
            ("outlier_scale", 1.0, math.inf, False),
            ("detection_prob", 0.0, 1.0, True),
        ):
            value = check_range(f"{prefix}.{name}", getattr(self, name), lo, hi, lo_open=lo_open)
            store(self, name, value)

    def measure(self, states: Array, rngs: Sequence[np.random.Generator]) -> Measurements:
        """Draw measurements of true states ``(N, K+1, 4)``, one generator per run.

        ``z = h(x) + v``, ``v ~ N(0, R)``; with probability ``outlier_prob`` the noise standard
        deviation is multiplied by ``outlier_scale``; with probability ``1 - detection_prob`` the
        measurement is missed (never at ``t = 0``).
        """
        states = np.asarray(states, dtype=np.float64)
        if states.ndim != 3 or states.shape[-1] < 4:
            raise ConfigError(f"states must have shape (N, K+1, 4), got {states.shape}")
        N, K1, _ = states.shape
        if len(rngs) != N:
            raise ConfigError(f"measure needs one generator per run: {N} runs, {len(rngs)} rngs")
        m = self.dim_z  # type: ignore[attr-defined]
        noise = np.empty((N, K1, m))
        uniforms = np.empty((N, 2, K1))  # the outlier uniforms, then the detection uniforms
        for n, rng in enumerate(rngs):
            rng.standard_normal(out=noise[n])
            rng.random(out=uniforms[n])  # the same doubles as random(K1) twice
        outlier = uniforms[:, 0] < self.outlier_prob
        detected = uniforms[:, 1] < self.detection_prob
        detected[:, 0] = True
        scale = np.where(outlier, self.outlier_scale, 1.0)[..., None]
        noise *= scale  # z = h(x) + scale * noise * sigma, without temporaries
        noise *= self.sigma  # type: ignore[attr-defined]
        noise += self.h(states)  # type: ignore[attr-defined]
        return Measurements(z=self.wrap(noise), detected=detected, outlier=outlier)


@dataclass(frozen=True)
class Sonar(_Clutter):
    r"""Range-bearing sonar at ``position``: ``z = [\sqrt{dx^2+dy^2}, atan2(dy, dx)] + v``.

    ``R = diag(sigma_r^2, sigma_theta^2)``; bearing in rad, measured counter-clockwise from +x.
    Defaults from SPEC §6: ``sigma_r = 50 m``, ``sigma_theta = 0.05°``.

    Attributes:
        sigma_r: range noise standard deviation (m).
        sigma_theta_deg: bearing noise standard deviation (°).
        position: sensor position ``(x, y)`` (m).
        outlier_prob: probability that a measurement's noise is inflated.
        outlier_scale: standard-deviation multiplier of an outlier (>= 1).
        detection_prob: probability of a detection at each step (> 0).
    """

    sigma_r: float = 50.0
    sigma_theta_deg: float = 0.05
    position: tuple[float, float] = (0.0, 0.0)

    dim_z = 2
    noise_fields: ClassVar[dict[str, str]] = {
        "sigma_r": "sensor.sigma_r",
        "sigma_theta_deg": "sensor.sigma_theta_deg",
    }

    def __post_init__(self) -> None:
        sigma_r = check_range("sensor.sigma_r", self.sigma_r, 0.0, MAX_DISTANCE, lo_open=True)
        store(self, "sigma_r", sigma_r)
        store(
            self,
            "sigma_theta_deg",
            check_range("sensor.sigma_theta_deg", self.sigma_theta_deg, 0.0, 180.0, lo_open=True),
        )
        position = check_sequence("sensor.position", self.position, 2)
        store(
            self,
            "position",
            tuple(check_range("sensor.position", v, -MAX_DISTANCE, MAX_DISTANCE) for v in position),
        )
        self._check_clutter("sensor")

    @property
    def sigma(self) -> Array:
        """Noise standard deviations ``[sigma_r, sigma_theta]`` (m, rad)."""
        return np.array([self.sigma_r, math.radians(self.sigma_theta_deg)])

    @property
    def R(self) -> Array:
        """``diag(sigma_r^2, sigma_theta^2)``."""
        return np.diag(self.sigma**2)

    def h(self, x: Array) -> Array:
        """Range and bearing of states ``(..., n)`` -> ``(..., 2)``."""
        dx = x[..., 0] - self.position[0]
        dy = x[..., 1] - self.position[1]
        z = np.empty((*x.shape[:-1], 2))
        np.sqrt(dx * dx + dy * dy, out=z[..., 0])
        np.arctan2(dy, dx, out=z[..., 1])
        return z

    def jacobian(self, x: Array) -> Array:
        r"""``H = dh/dx = [[dx/r, dy/r, 0..], [-dy/r^2, dx/r^2, 0..]]``, shape ``(..., 2, n)``."""
        dx = x[..., 0] - self.position[0]
        dy = x[..., 1] - self.position[1]
        r2 = np.maximum(dx * dx + dy * dy, 1e-12)
        r = np.sqrt(r2)
        H = np.zeros((*x.shape[:-1], 2, x.shape[-1]))
        H[..., 0, 0] = dx / r
        H[..., 0, 1] = dy / r
        H[..., 1, 0] = -dy / r2
        H[..., 1, 1] = dx / r2
        return H

    def residual(self, a: Array, b: Array) -> Array:
        """``a - b`` with the bearing difference wrapped to (-pi, pi]."""
        d = np.asarray(a, dtype=np.float64) - b
        d[..., 1] = wrap_angle(d[..., 1])
        return d

    def wrap(self, z: Array) -> Array:
        """Measurements with the bearing wrapped to (-pi, pi]."""
        z = np.array(z, dtype=np.float64)
        z[..., 1] = wrap_angle(z[..., 1])
        return z

    def linear_matrix(self, n: int) -> None:
        """The sonar is nonlinear: no constant ``H``."""
        return None

    #: What a recorded sonar measurement is expected to be (:meth:`implausible`).
    measurement_units: ClassVar[str] = "a range >= 0 m and a bearing in rad, |bearing| <= 2 pi"

    def implausible(self, z: Array) -> NDArray[np.bool_]:
        """The rows of ``z (..., 2)`` unlikely to be sonar measurements in its units: a negative
        range, or a bearing beyond ``2 pi`` in magnitude (degrees, likely); NaN rows are not.
        The simulation draws such rows too (its noise is not clipped): a negative range for a
        target within a few ``sigma_r`` of the sonar, a bearing beyond ``2 pi`` under heavy
        outliers; so they are told of, not refused."""
        return (z[..., 0] < 0.0) | (np.abs(z[..., 1]) > 2.0 * math.pi)

    def initial_position(self, z: Array) -> tuple[Array, Array]:
        r"""Position from a measurement (polar to Cartesian) and its covariance ``J R J^T``.

        ``J = [[cos(theta), -r sin(theta)], [sin(theta), r cos(theta)]]``.

        Args:
            z: ``(..., 2)`` range-bearing measurements.

        Returns:
            ``(..., 2)`` positions and ``(..., 2, 2)`` covariances.
        """
        r, th = z[..., 0], z[..., 1]
        c, s = np.cos(th), np.sin(th)
        pos = np.stack([self.position[0] + r * c, self.position[1] + r * s], axis=-1)
        J = np.empty((*z.shape[:-1], 2, 2))
        J[..., 0, 0], J[..., 0, 1] = c, -r * s
        J[..., 1, 0], J[..., 1, 1] = s, r * c
        return pos, J @ self.R @ np.swapaxes(J, -1, -2)


@dataclass(frozen=True)
class PositionSensor(_Clutter):
    """Linear sensor of position, or position and velocity: ``z = H x + v``.

    ``H = [I_2 0]`` or ``[I_4 0]`` (with velocity); ``R = diag(sigma_pos^2 I, sigma_vel^2 I)``.

    Attributes:
        sigma_pos: position noise standard deviation (m).
        sigma_vel: velocity noise standard deviation (m/s), or ``None`` to measure position only.
        outlier_prob, outlier_scale, detection_prob: as for :class:`Sonar`.
    """

    sigma_pos: float = 10.0
    sigma_vel: float | None = None

    noise_fields: ClassVar[dict[str, str]] = {"sigma_pos": "position_sensor.sigma_pos"}

    def __post_init__(self) -> None:
        sigma_pos = check_range(
            "position_sensor.sigma_pos", self.sigma_pos, 0.0, MAX_DISTANCE, lo_open=True
        )
        store(self, "sigma_pos", sigma_pos)
        if self.sigma_vel is not None:
            sigma_vel = check_range(
                "position_sensor.sigma_vel", self.sigma_vel, 0.0, MAX_SPEED, lo_open=True
            )
            store(self, "sigma_vel", sigma_vel)
        self._check_clutter("position_sensor")

    @property
    def dim_z(self) -> int:  # type: ignore[override]
        return 2 if self.sigma_vel is None else 4

    @property
    def sigma(self) -> Array:
        s = [self.sigma_pos] * 2
        if self.sigma_vel is not None:
            s += [self.sigma_vel] * 2
        return np.array(s)

    @property
    def R(self) -> Array:
        return np.diag(self.sigma**2)

    def linear_matrix(self, n: int) -> Array:
        """The constant ``H`` of shape ``(m, n)``."""
        H = np.zeros((self.dim_z, n))
        H[:, : self.dim_z] = np.eye(self.dim_z)
        return H

    def h(self, x: Array) -> Array:
        return x[..., : self.dim_z].copy()

    def jacobian(self, x: Array) -> Array:
        return np.broadcast_to(
            self.linear_matrix(x.shape[-1]), (*x.shape[:-1], self.dim_z, x.shape[-1])
        )

    def residual(self, a: Array, b: Array) -> Array:
        return a - b

    def wrap(self, z: Array) -> Array:
        return np.array(z, dtype=np.float64)

    def initial_position(self, z: Array) -> tuple[Array, Array]:
        """Measured position and ``R``'s position block."""
        cov = np.broadcast_to(np.eye(2) * self.sigma_pos**2, (*z.shape[:-1], 2, 2)).copy()
        return z[..., :2].copy(), cov


Sensor = Sonar | PositionSensor
