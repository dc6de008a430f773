"""The profile truth's edges worked by hand: a Cartesian step's recorded turn rate and
tangential acceleration, and its refusals (a speed driven below 0, a Cartesian step that also
accelerates along its heading); the families' ranges, whose lower ends must be above 0, the
driving family's longest period, the spread of its draws and its turns' directions; the
maneuver family's scaled accelerations and headings, the runs of the seed-003 truth and of a
family's truth, a single run's profile given as ``(K,)``, the first of several non-finite
entries named and a Cartesian profile of another number of runs refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym import ConfigError
from imm_gym.scenarios.profiles import (
    DrivingFamily,
    ManeuverFamily,
    maneuver_truth,
    profile_truth,
)


def test_a_cartesian_step_records_its_mean_turn_rate_and_tangential_acceleration() -> None:
    """v = (10, 0) m/s pushed by a = (0, 10) m/s² for T = 0.1 s ends at v = (10, 1): the step
    turns by atan(1/10) and speeds up by √101 − 10, so it records ``Δψ/T`` and ``Δ|v|/T``."""
    T = 0.1
    pt = profile_truth(
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        np.zeros((1, 2)),
        np.array([10.0]),
        np.array([0.0]),
        T,
        np.array([[[0.0, 10.0]]]),
    )
    np.testing.assert_allclose(pt.states[0, 1], [1.0, 0.05, 10.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(pt.turn_rate[0, 0], math.atan(0.1) / T, rtol=1e-12)
    np.testing.assert_allclose(pt.accel[0, 0], (math.sqrt(101.0) - 10.0) / T, rtol=1e-12)
    np.testing.assert_allclose(pt.heading[0], [0.0, math.atan(0.1)], atol=1e-15)


def _one_step(accel: float, cart_accel: tuple[float, float] = (0.0, 0.0)):
    """One 0.1 s step from the origin at 1 m/s heading east, no turn."""
    return profile_truth(
        np.zeros((1, 1)),
        np.full((1, 1), accel),
        np.zeros((1, 2)),
        np.array([1.0]),
        np.array([0.0]),
        0.1,
        np.array([[cart_accel]]),
    )


def test_a_speed_driven_below_zero_is_refused() -> None:
    """1 m/s braked at 15 m/s² for 0.1 s would end at −0.5 m/s; 10 m/s² stops it exactly."""
    with pytest.raises(ConfigError, match="drives the speed below 0"):
        _one_step(-15.0)
    np.testing.assert_allclose(_one_step(-10.0).states[0, 1], [0.05, 0.0, 0.0, 0.0], atol=1e-12)


def test_a_cartesian_step_that_also_accelerates_along_its_heading_is_refused() -> None:
    with pytest.raises(ConfigError, match="Cartesian acceleration must have omega = accel = 0"):
        _one_step(2.0, (0.0, 1.0))
    # either acceleration alone is a step
    np.testing.assert_allclose(_one_step(2.0).states[0, 1], [0.11, 0.0, 1.2, 0.0], atol=1e-12)
    np.testing.assert_allclose(
        _one_step(0.0, (0.0, 1.0)).states[0, 1], [0.1, 0.005, 1.0, 0.1], atol=1e-12
    )


@pytest.mark.parametrize(
    ("family", "name", "low"),
    [
        (DrivingFamily, "cruise", 11.0),  # the curve and turn speeds stay below cruise
        (DrivingFamily, "curve", 1e-6),
        (DrivingFamily, "turn", 1e-6),
        (DrivingFamily, "s_rate", 1e-6),
        (ManeuverFamily, "rate_scale", 1e-6),
        (ManeuverFamily, "accel_scale", 1e-6),
        (ManeuverFamily, "speed", 1e-6),
    ],
)
def test_a_family_range_starting_at_zero_is_refused(family, name: str, low: float) -> None:
    """A speed, rate or scale drawn from ``[0, high]`` could be 0 (a target standing still, a
    turn that does not turn): the low end must be above 0; above it is accepted."""
    high = getattr(family(), name)[1]
    with pytest.raises(ConfigError, match=rf"^family\.{name}\[0\] must be in \(0\.0, inf\)"):
        family(**{name: (0.0, high)})
    assert getattr(family(**{name: (low, high)}), name) == (low, high)


def test_the_driving_family_s_period_is_at_most_half_a_second() -> None:
    """1 s divides every driving segment (8, 4, 5, 3, 6 s) but is above the family's 0.5 s
    limit; 0.5 s gives 67 s / 0.5 s = 134 steps."""
    with pytest.raises(ConfigError, match=r"^family\.T must be in \(0\.0, 0\.5\], got 1\.0"):
        DrivingFamily(T=1.0)
    assert DrivingFamily(T=0.5).horizon == 134


def test_the_driving_family_starts_anywhere_in_its_square_at_any_heading() -> None:
    """Per run: start ``U(-50, 50)`` m per axis and heading ``U(-π, π)``; 200 draws reach near
    each end."""
    pt = DrivingFamily().truth([np.random.default_rng(s) for s in range(200)])
    start = pt.states[:, 0, :2]
    assert start.min() >= -50.0 and start.max() <= 50.0
    for axis in (0, 1):
        assert start[:, axis].min() < -45.0 and start[:, axis].max() > 45.0
    heading = pt.heading[:, 0]
    assert heading.min() >= -math.pi and heading.max() <= math.pi
    assert heading.min() < -2.9 and heading.max() > 2.9


def test_the_maneuver_family_scales_both_accelerations_by_one_draw() -> None:
    """Per run one ``U(0.5, 1.5)`` scale ``s`` multiplies the 10-14 s Cartesian acceleration
    (``|Δv| = 4 s |(0.25, 1)|`` m/s, whatever the rotation) and the 34-38 s tangential one
    (``Δ|v| = 4 s (8 − √2) / 4`` m/s); 200 draws reach near each end of the range."""
    pt = ManeuverFamily().truth([np.random.default_rng(s) for s in range(200)])
    velocity = pt.states[..., 2:]
    cartesian = np.linalg.norm(velocity[:, 140] - velocity[:, 100], axis=-1)
    cartesian /= 4.0 * math.hypot(0.25, 1.0)
    speed = np.linalg.norm(velocity, axis=-1)
    tangential = (speed[:, 380] - speed[:, 340]) / (8.0 - math.sqrt(2.0))
    np.testing.assert_allclose(tangential, cartesian, rtol=1e-9)
    assert cartesian.min() >= 0.5 and cartesian.max() <= 1.5
    assert cartesian.min() < 0.55 and cartesian.max() > 1.45


def test_the_seed_003_truth_needs_at_least_one_run() -> None:
    with pytest.raises(ConfigError, match=r"^runs must be an integer in \[1, inf\), got 0"):
        maneuver_truth(0)
    assert maneuver_truth(1).states.shape == (1, 431, 4)


def test_each_sharp_driving_turn_goes_either_way() -> None:
    """The two 90° turns (36-40 s and 53-57 s) turn at ``±(π/2) / 4 s``, each direction drawn on
    its own: 40 draws show all four pairs of directions."""
    pt = DrivingFamily().truth([np.random.default_rng(s) for s in range(40)])
    rates = pt.turn_rate[:, [365, 545]]  # mid-turn steps at T = 0.1 s
    np.testing.assert_allclose(np.abs(rates), math.pi / 8.0, rtol=1e-12)
    pairs = {(int(a), int(b)) for a, b in np.sign(rates)}
    assert pairs == {(-1, -1), (-1, 1), (1, -1), (1, 1)}


def test_the_maneuver_family_starts_at_any_heading() -> None:
    """Per run the source's trajectory is rotated to a heading ``U(-π, π)``: 200 draws reach near
    each end."""
    heading = ManeuverFamily().truth([np.random.default_rng(s) for s in range(200)]).heading[:, 0]
    assert heading.min() >= -math.pi and heading.max() <= math.pi
    assert heading.min() < -2.9 and heading.max() > 2.9


def test_a_single_run_s_profile_may_be_given_without_its_run_axis() -> None:
    """``(K,)`` turn rates and accelerations are one run's: the truth of the ``(1, K)`` ones."""
    omega, accel = np.array([0.0, 0.1, -0.05]), np.array([0.5, 0.0, -0.2])
    start = (np.zeros((1, 2)), np.array([4.0]), np.array([0.3]), 0.5)
    flat = profile_truth(omega, accel, *start)
    batched = profile_truth(omega[None], accel[None], *start)
    assert flat.states.shape == (1, 4, 4)
    np.testing.assert_array_equal(flat.states, batched.states)
    np.testing.assert_array_equal(flat.turn_rate, [omega])


@pytest.mark.parametrize("family", [DrivingFamily, ManeuverFamily])
def test_a_family_s_truth_needs_at_least_one_generator(family) -> None:
    with pytest.raises(ConfigError, match=rf"^{family.__name__}\.truth needs at least one"):
        family().truth([])
    assert family().truth([np.random.default_rng(0)]).states.shape[0] == 1


def test_the_first_of_several_non_finite_entries_is_named() -> None:
    omega = np.zeros((2, 4))
    omega[0, 3], omega[1, 1] = np.inf, np.nan
    with pytest.raises(
        ConfigError, match=r"^omega must be finite everywhere, got inf at index \[0, 3\]"
    ):
        profile_truth(omega, np.zeros((2, 4)), np.zeros((2, 2)), np.ones(2), np.zeros(2), 1.0)


def test_a_cartesian_profile_of_another_number_of_runs_is_refused() -> None:
    args = (np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 2)), np.ones(1), np.zeros(1), 1.0)
    with pytest.raises(
        ConfigError, match=r"cart_accel has shape \(2, 3, 2\), expected \(1, 3, 2\)"
    ):
        profile_truth(*args, np.zeros((2, 3, 2)))
    assert profile_truth(*args, np.zeros((3, 2))).states.shape == (1, 4, 4)  # one run's (K, 2)
