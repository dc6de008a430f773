"""Track initiation (:func:`imm_gym.tracking.initiation.initiate`) against the polar-to-Cartesian
conversion and its covariance worked by hand, and the inputs it refuses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym import ConfigError, Sonar
from imm_gym.tracking.initiation import initiate


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
