"""The distance and speed limits (MAX_DISTANCE = 1e9 m, MAX_SPEED = 1e5 m/s) where the tests of
``test_numerics`` do not reach: a position sensor's noise and a varied noise range are refused
past them naming the field and the range (at the limit they are accepted), and a deceleration
that drives the speed past zero by more than rounding is refused."""

from __future__ import annotations

import pytest

from imm_gym import Scenario, Segment
from imm_gym.sim.conditions import Variation
from imm_gym.tracking.sensors import PositionSensor
from imm_gym.validation import ConfigError


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"sigma_pos": 2e9},
         r"position_sensor\.sigma_pos must be in \(0\.0, 1000000000\.0\], got 2000000000\.0"),
        ({"sigma_vel": 2e5},
         r"position_sensor\.sigma_vel must be in \(0\.0, 100000\.0\], got 200000\.0"),
    ],
)
def test_a_position_sensor_noise_beyond_the_limits_is_refused_by_name(fields, message) -> None:
    with pytest.raises(ConfigError, match=message):
        PositionSensor(**fields)


def test_a_position_sensor_noise_at_the_limits_is_accepted() -> None:
    sensor = PositionSensor(sigma_pos=1e9, sigma_vel=1e5)
    assert (sensor.sigma_pos, sensor.sigma_vel) == (1e9, 1e5)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"sigma_r": (10.0, 2e9)},
         r"vary\.sigma_r\[1\] must be in \[10\.0, 1000000000\.0\], got 2000000000\.0"),
        ({"sigma_pos": (5.0, 2e9)},
         r"vary\.sigma_pos\[1\] must be in \[5\.0, 1000000000\.0\], got 2000000000\.0"),
    ],
)
def test_a_varied_noise_range_beyond_the_distance_limit_is_refused_as_built(
    fields, message
) -> None:
    """Refused when the variation is built, naming its end: not a sensor drawn past 1e9 m now
    and then, seconds into an evaluation."""
    with pytest.raises(ConfigError, match=message):
        Variation(**fields)
    name, (low, _) = next(iter(fields.items()))
    assert getattr(Variation(**{name: (low, 1e9)}), name) == (low, 1e9)  # the limit itself


def test_a_deceleration_past_zero_by_more_than_rounding_is_refused() -> None:
    """10 m/s slowed by 1.00001 m/s² for 10 steps of 1 s ends at 10 - 10.0001 = -1e-4 m/s:
    past zero by far more than rounding (1e-9 of the speed), refused; 1.0 m/s² stops the target
    exactly and is a target."""
    with pytest.raises(ConfigError, match=r"segments\[0\]\.accel: -1\.00001 m/s² for 10 steps of "
                       r"1\.0 s drives the speed from 10 m/s below 0 \(-0\.0001 m/s\)"):
        Scenario((Segment(10, accel=-1.00001),), velocity=(10.0, 0.0))
    Scenario((Segment(10, accel=-1.0), Segment(3)), velocity=(10.0, 0.0))
