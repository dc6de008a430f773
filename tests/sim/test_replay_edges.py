"""imm_gym.run_policy at its edges, each against a value worked by hand or another input that
means the same."""

from __future__ import annotations

import math

import numpy as np

from baselines import make_baseline
from imm_gym.sim.replay import run_policy

#: A target straight ahead on the x axis, 1000 m out (bearing 0), closing at 10 m/s.
Z = np.array([[1000.0 - 10.0 * k, 0.0] for k in range(6)])


def test_the_start_without_a_velocity_by_hand() -> None:
    """From z0 = (1000 m, 0 rad): x0 = (1000, 0, 0, 0); P0's position block diag(σ_r²,
    (r σ_θ)²) = diag(50², (1000 · 0.05° in rad)²), its velocity block 30² I (a velocity
    unknown: 30 m/s, as the command line's help says); given a velocity, its block is
    velocity_std² = 5² I."""
    out = run_policy(Z, make_baseline("fixed"))
    np.testing.assert_array_equal(out.x0, [[1000.0, 0.0, 0.0, 0.0]])
    across = 1000.0 * math.radians(0.05)
    expected = np.diag([50.0**2, across**2, 30.0**2, 30.0**2])
    np.testing.assert_allclose(out.P0[0], expected, rtol=1e-12, atol=1e-12)
    given = run_policy(Z, make_baseline("fixed"), velocity=[-10.0, 0.0])
    np.testing.assert_array_equal(given.x0, [[1000.0, 0.0, -10.0, 0.0]])
    np.testing.assert_allclose(given.P0[0], np.diag([50.0**2, across**2, 25.0, 25.0]),
                               rtol=1e-12, atol=1e-12)
