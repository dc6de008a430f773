"""Track initiation (:func:`imm_gym.tracking.initiation.initiate`) against the polar-to-Cartesian
conversion and its covariance worked by hand, and the inputs it refuses."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from imm_gym import ConfigError, PositionSensor, Sonar
from imm_gym.tracking.initiation import initiate


def test_a_sonar_track_starts_at_the_converted_position_with_j_r_j_t_by_hand() -> None:
    """Two first measurements of a sonar away from the origin, each with its own velocity: ``x0``
    is ``(p_x + r cos t, p_y + r sin t, v_x, v_y)`` and ``P0`` is ``blockdiag(J R J^T, s^2 I)``
    with ``J R J^T`` multiplied out by hand for ``R = diag(sr^2, st^2)``:
    ``[[c^2 sr^2 + r^2 s^2 st^2, c s (sr^2 - r^2 st^2)], [., s^2 sr^2 + r^2 c^2 st^2]]``."""
    sonar = Sonar(sigma_r=7.0, sigma_theta_deg=2.0, position=(100.0, -50.0))
    sr2, st2 = 49.0, math.radians(2.0) ** 2
    z0 = np.array([[3000.0, 0.4], [1500.0, -2.0]])
    velocity = np.array([[4.0, -3.0], [-1.0, 6.0]])
    x0, P0 = initiate(sonar, z0, velocity, velocity_std=2.5)
    assert x0.shape == (2, 4) and P0.shape == (2, 4, 4)
    for row in range(2):
        r, t = z0[row]
        c, s = math.cos(t), math.sin(t)
        np.testing.assert_allclose(
            x0[row], [100.0 + r * c, -50.0 + r * s, *velocity[row]], rtol=1e-14, atol=1e-9
        )
        expected = np.zeros((4, 4))
        expected[0, 0] = c * c * sr2 + r * r * s * s * st2
        expected[1, 1] = s * s * sr2 + r * r * c * c * st2
        expected[0, 1] = expected[1, 0] = c * s * (sr2 - r * r * st2)
        expected[2, 2] = expected[3, 3] = 6.25
        np.testing.assert_allclose(P0[row], expected, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("where", ["z0", "velocity"])
def test_a_non_finite_measurement_or_velocity_is_refused(where: str, bad: float) -> None:
    """A NaN or infinite first measurement or velocity would start a track of NaN: refused."""
    z0 = np.array([[3000.0, 0.4], [1500.0, -2.0]])
    velocity = np.array([[4.0, -3.0], [-1.0, 6.0]])
    (z0 if where == "z0" else velocity)[1, 0] = bad
    with pytest.raises(ConfigError, match="z0 and velocity must be finite"):
        initiate(Sonar(), z0, velocity)


def test_a_velocity_of_transposed_shape_is_refused() -> None:
    """Three first measurements take a velocity of shape (2,) or (3, 2); (2, 3) is refused by
    name, not broadcast."""
    z0 = np.array([[3000.0, 0.4], [1500.0, -2.0], [800.0, 1.0]])
    with pytest.raises(ConfigError, match=r"velocity must have shape \(2,\) or \(3, 2\)"):
        initiate(Sonar(), z0, np.zeros((2, 3)))


@pytest.mark.parametrize("std", [0.0, -2.5, 1e-160, 1.001e6, math.nan, math.inf])
def test_a_velocity_std_outside_its_range_is_refused(std: float) -> None:
    """``velocity_std`` in ``[sqrt(smallest normal float64), 1e6]`` m/s: 0 (a singular ``P0``),
    negatives, a std whose square is not a normal float, and beyond 1e6 are refused by name."""
    with pytest.raises(ConfigError, match=r"^velocity_std must be in \["):
        initiate(Sonar(), np.array([3000.0, 0.4]), np.zeros(2), velocity_std=std)


def test_velocity_std_at_the_ends_of_its_range_and_by_default() -> None:
    """The ends are allowed (``P0``'s velocity block is their square); the default is 5 m/s
    (``P0`` velocity block ``25 I``)."""
    z0, v = np.array([3000.0, 0.4]), np.zeros(2)
    for std in (math.sqrt(sys.float_info.min), 1e6):
        _, P0 = initiate(Sonar(), z0, v, velocity_std=std)
        np.testing.assert_array_equal(np.diag(P0[0])[2:], [std**2, std**2])
    _, P0 = initiate(Sonar(), z0, v)
    np.testing.assert_array_equal(P0[0, 2:, 2:], 25.0 * np.eye(2))


@pytest.mark.parametrize(
    ("sensor", "z0"),
    [
        (Sonar(), np.array([[3000.0, 0.4, 1.0]])),
        (Sonar(), np.array([3000.0])),
        (PositionSensor(sigma_pos=5.0, sigma_vel=1.0), np.array([[3000.0, 4000.0]])),
    ],
)
def test_a_first_measurement_of_another_width_is_refused(sensor, z0: np.ndarray) -> None:
    """A first measurement must have the sensor's ``dim_z`` components (2 for the sonar, 4 for a
    position+velocity sensor): a third component is not dropped silently."""
    m = sensor.dim_z
    with pytest.raises(ConfigError, match=rf"z0 must have shape \({m},\) or \(N, {m}\)"):
        initiate(sensor, z0, np.zeros(2))


def test_a_first_position_covariance_float64_cannot_factor_is_refused_naming_the_noise() -> None:
    """A range accuracy of 1e-12 m beside a cross-range one of 3000 m x 0.05°: ``J R J^T`` is
    positive definite in exact arithmetic, its standard deviations 2.6e12 apart, beyond float64's
    Cholesky. Refused with the sonar's noise settings named; 1e-6 m (2.6e6 apart) still starts."""
    with pytest.raises(
        ConfigError,
        match=r"^sensor\.sigma_r = 1e-12, sensor\.sigma_theta_deg = 0\.05: the "
        r"covariance of the first measurement's position is not positive definite in float64",
    ):
        initiate(Sonar(sigma_r=1e-12), np.array([3000.0, 0.4]), np.zeros(2))
    _, P0 = initiate(Sonar(sigma_r=1e-6), np.array([3000.0, 0.4]), np.zeros(2))
    np.linalg.cholesky(P0[0])
