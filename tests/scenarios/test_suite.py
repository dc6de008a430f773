"""The benchmark suite's named scenarios: each truth matches its segment table (in seconds) at
every segment end, by the closed form of straight and constant-turn motion."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym import ConfigError
from imm_gym.scenarios.catalog import SCENARIOS, SUITES, register, timed_scenario
from imm_gym.scenarios.segments import paper_scenario

#: name: (T, start position, start speed, start heading (deg), [(seconds, turn rate (deg/s))])
TABLES = {
    "atc": (
        5.0,
        (25_000.0, 10_000.0),
        120.0,
        180.0,
        [(125, 0.0), (90, 1.0), (125, 0.0), (30, -3.0), (125, 0.0)],
    ),
    "vsmm-s1": (
        1.0,
        (30_000.0, 30_000.0),
        math.hypot(172.0, 246.0),
        math.degrees(math.atan2(-246.0, -172.0)),
        [(61, 0.0), (106 - 61, 3.74), (150 - 106, 0.0)],
    ),
    "vsmm-s2": (
        1.0,
        (20_000.0, 50_000.0),
        math.hypot(172.0, 246.0),
        math.degrees(math.atan2(-246.0, -172.0)),
        [(61, 0.0), (96 - 61, 4.68), (150 - 96, 0.0)],
    ),
    "vsmm-s3": (
        1.0,
        (60_000.0, 40_000.0),
        300.0,
        135.0,
        [
            (50, 0.0),
            (96, 1.87),
            (30, 0.0),
            (64, -2.8),
            (30, 0.0),
            (32, 5.6),
            (30, 0.0),
            (38, -4.68),
            (30, 0.0),
        ],
    ),
}


def segment_ends(position, speed, heading_deg, table):
    """Position, heading (rad) and time at the end of every segment, by closed form: straight
    ``p + v t (cos h, sin h)``; turn at ``w``: ``p + (v / w) (sin(h + w t) - sin h,
    cos h - cos(h + w t))``, heading ``h + w t``."""
    x, y = position
    h = math.radians(heading_deg)
    t = 0.0
    ends = []
    for seconds, rate_deg in table:
        w = math.radians(rate_deg)
        if w == 0.0:
            x, y = x + speed * seconds * math.cos(h), y + speed * seconds * math.sin(h)
        else:
            x += speed / w * (math.sin(h + w * seconds) - math.sin(h))
            y += speed / w * (math.cos(h) - math.cos(h + w * seconds))
            h += w * seconds
        t += seconds
        ends.append((x, y, h, t))
    return ends


@pytest.mark.parametrize("name", list(TABLES))
def test_truth_matches_the_table_at_segment_ends(name) -> None:
    T, position, speed, heading, table = TABLES[name]
    scenario = SCENARIOS[name]()
    assert scenario.T == T
    assert scenario.horizon * T == sum(seconds for seconds, _ in table)
    states = scenario.truth([np.random.default_rng(0)]).states[0]
    for x, y, h, t in segment_ends(position, speed, heading, table):
        k = round(t / T)
        px, py, vx, vy = states[k]
        assert math.hypot(px - x, py - y) < 1e-6 * max(1.0, math.hypot(x, y)), (name, t)
        assert math.hypot(vx, vy) == pytest.approx(speed, rel=1e-9)
        assert math.remainder(math.atan2(vy, vx) - h, 2 * math.pi) == pytest.approx(0, abs=1e-9)


def test_the_benchmark_suite_names_known_scenarios() -> None:
    suite = SUITES["benchmark"]
    assert suite[:2] == ("paper", "random")
    assert set(suite[2:]) == set(TABLES) <= set(SCENARIOS)


def test_a_duration_that_is_not_a_multiple_of_T_is_refused() -> None:
    with pytest.raises(ValueError, match="not a multiple"):
        timed_scenario([(12, 0.0)], (0.0, 0.0), (1.0, 0.0), 5.0)
    assert timed_scenario([(10, 1.0)], (0.0, 0.0), (1.0, 0.0), 5.0).segments[0].duration == 2


@pytest.mark.parametrize(
    ("table", "T", "message"),
    [
        ([(10, 0.0)], 0.0, r"^T must be in \(0.0, inf\), got 0.0"),
        ([(10, 0.0)], -1.0, r"^T must be in"),
        ([(math.nan, 0.0)], 1.0, r"^table\[0\] duration_s must be finite"),
        ([(math.inf, 0.0)], 1.0, r"^table\[0\] duration_s must be finite"),
        ([(10, 0.0), (0, 1.0)], 1.0, r"^table\[1\] duration_s must be in \(0.0, inf\), got 0"),
        ([(10, 0.0), (-5, 1.0)], 1.0, r"^table\[1\] duration_s must be in \(0.0, inf\), got -5"),
        ([(10, 0.0), (0.4, 1.0)], 1.0,
         r"^table\[1\] duration_s must be a positive multiple of T = 1.0 s .* not a multiple"),
        ([(12, 0.0)], 5.0, r"^table\[0\] duration_s must be a positive multiple of T = 5.0 s"),
        ([(10, 0.0), (10,)], 1.0, r"^table\[1\] \(duration_s, turn_rate_deg\) must have 2"),
        ([(10, 0.0), 10], 1.0, r"^table\[1\] \(duration_s, turn_rate_deg\) must be a list"),
        ([(10, 0.0), (10, "1.0")], 1.0,
         r"^table\[1\] turn_rate_deg must be a finite real number, got '1\.0' \(str\)"),
        ([(10, 0.0), (10, math.nan)], 1.0, r"^table\[1\] turn_rate_deg must be finite"),
    ],
)
def test_a_period_or_duration_out_of_range_is_refused_by_name(table, T, message) -> None:
    """Division by zero, NaN or infinite durations and malformed rows were Python's errors naming
    nothing; a duration of 0 s or below was "not a multiple of T" (a plain ValueError); a bad
    turn rate named ``segment.turn_rate_deg``, not its row."""
    with pytest.raises(ConfigError, match=message):
        timed_scenario(table, (0.0, 0.0), (1.0, 0.0), T)


@pytest.mark.parametrize(
    ("T", "table", "steps"),
    [
        (0.1, [(0.3, 0.0), (0.7, 2.0), (0.2, 0.0)], [3, 7, 2]),
        (0.2, [(0.6, 0.0), (1.4, -1.0)], [3, 7]),
    ],
)
def test_a_duration_that_is_a_multiple_of_T_only_in_decimal_is_its_whole_steps(
    T, table, steps
) -> None:
    """Durations that are whole multiples of T on paper but not in binary floating point
    (0.3 / 0.1 = 2.9999999999999996, 0.7 / 0.1 = 6.999999999999999, 0.1 * 7 =
    0.7000000000000001) last their whole number of periods worked by hand, 0.3 s / 0.1 s = 3
    steps, and are not refused as "not a multiple of T"."""
    scenario = timed_scenario(table, (0.0, 0.0), (1.0, 0.0), T)
    assert [s.duration for s in scenario.segments] == steps
    assert [s.turn_rate_deg for s in scenario.segments] == [w for _, w in table]
    assert scenario.horizon == sum(steps)


def test_the_randomized_family_name_cannot_be_registered() -> None:
    """``"random"`` names the configuration's family: registering a scenario under it is refused
    like a name already taken, and leaves the registry without it."""
    with pytest.raises(ValueError, match="already defined"):
        register("random", paper_scenario)
    assert "random" not in SCENARIOS


@pytest.mark.parametrize(
    ("table", "T"),
    [([(26, 0.0)], 5.0), ([(10, 0.0), (10.00001, 1.0)], 1.0), ([(10.5, 0.0)], 1.0)],
)
def test_a_duration_a_little_off_a_multiple_of_T_is_refused(table, T) -> None:
    """26 s at T = 5 s is 5.2 periods, 10.00001 s at T = 1 s a hundred-thousandth of a period
    over 10, 10.5 s half a period: none is a whole number of periods, so none is silently
    rounded to the nearest (25 s, 10 s, 10 s) but refused, naming the row."""
    with pytest.raises(ConfigError, match=r"^table\[\d\] duration_s must be a positive multiple"):
        timed_scenario(table, (0.0, 0.0), (1.0, 0.0), T)
