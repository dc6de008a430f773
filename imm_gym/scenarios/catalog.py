"""Named scenarios: what ``EnvConfig(scenario=NAME)`` and ``python -m imm_gym.evaluate --scenario
NAME`` accept besides ``"random"`` (the configuration's :class:`~.segments.RandomFamily`) and a
user's scenario file. Adding one is one :func:`register` call here with a factory of its
:class:`~imm_gym.scenarios.segments.TruthSource`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path

from imm_gym.scenarios.segments import Scenario, Segment, TruthSource, paper_scenario
from imm_gym.validation import ConfigError, check_finite, check_range, check_sequence

#: Every named scenario's factory, in declaration order.
SCENARIOS: dict[str, Callable[[], TruthSource]] = {}


def register(name: str, factory: Callable[[], TruthSource]) -> None:
    """Add a named scenario (names are unique; ``"random"`` is the configured family)."""
    if name in SCENARIOS or name == "random":
        raise ValueError(f"scenario {name!r} is already defined")
    SCENARIOS[name] = factory


def timed_scenario(
    table: Sequence[tuple[float, float]],
    position: tuple[float, float],
    velocity: tuple[float, float],
    T: float,
) -> Scenario:
    """A :class:`~imm_gym.scenarios.segments.Scenario` from a table in seconds.

    Args:
        table: ``(duration_s, turn_rate_deg)`` per segment; each duration a whole number of
            sampling periods (a segment lasts ``duration_s / T`` steps).
        position: start ``(x, y)`` (m).
        velocity: start ``(vx, vy)`` (m/s).
        T: sampling period (s).

    Raises:
        ConfigError: ``T`` is not positive, a row is not a ``(duration_s, turn_rate_deg)`` pair,
            a duration is not finite, not positive or not a multiple of ``T``, or a turn rate is
            not a finite number (the error, a ``ValueError``, names the row ``table[i]``).
    """
    check_range("T", T, 0.0, lo_open=True)
    segments = []
    for i, row in enumerate(table):
        duration_s, turn_rate_deg = check_sequence(
            f"table[{i}] (duration_s, turn_rate_deg)", row, 2
        )
        steps = _steps(f"table[{i}] duration_s", duration_s, T)
        segments.append(Segment(steps, check_finite(f"table[{i}] turn_rate_deg", turn_rate_deg)))
    return Scenario(tuple(segments), position, velocity, T)


def _steps(name: str, duration_s: float, T: float) -> int:
    """The number of steps ``n = duration_s / T`` of a segment lasting ``duration_s`` seconds,
    which must be positive and a whole number of sampling periods (``n T = duration_s``)."""
    duration_s = check_range(name, check_finite(name, duration_s), 0.0, lo_open=True)
    steps = round(duration_s / T)
    if steps < 1 or not math.isclose(steps * T, duration_s):
        raise ConfigError(
            f"{name} must be a positive multiple of T = {T} s (n T, n = 1, 2, ...), got "
            f"{duration_s} s: not a multiple of T"
        )
    return steps


def atc_scenario() -> Scenario:
    """Bar-Shalom, Li and Kirubarajan (2001) §11.7.4, the air-traffic-control benchmark: T = 5 s,
    start (25, 10) km at 120 m/s west; straight 125 s, +1 °/s for 90 s, straight 125 s, −3 °/s
    for 30 s, straight 125 s (495 s, 99 steps)."""
    table = ((125, 0.0), (90, 1.0), (125, 0.0), (30, -3.0), (125, 0.0))
    return timed_scenario(table, (25_000.0, 10_000.0), (-120.0, 0.0), 5.0)


#: The VSMM guide's (Li, Bar-Shalom and Blair, §10.8.3) start velocity of S1 and S2 (m/s):
#: 300 m/s heading south-west.
VSMM_VELOCITY = (-172.0, -246.0)
#: Sampling period of the VSMM scenarios here (s).
VSMM_T = 1.0


def vsmm_s1() -> Scenario:
    """VSMM guide S1: start (30, 30) km, v = (−172, −246) m/s; straight to 61 s, +3.74 °/s to
    106 s, straight to 150 s (T = 1 s)."""
    table = ((61, 0.0), (45, 3.74), (44, 0.0))
    return timed_scenario(table, (30_000.0, 30_000.0), VSMM_VELOCITY, VSMM_T)


def vsmm_s2() -> Scenario:
    """VSMM guide S2: start (20, 50) km, v = (−172, −246) m/s; straight to 61 s, +4.68 °/s to
    96 s, straight to 150 s (T = 1 s)."""
    table = ((61, 0.0), (35, 4.68), (54, 0.0))
    return timed_scenario(table, (20_000.0, 50_000.0), VSMM_VELOCITY, VSMM_T)


def vsmm_s3() -> Scenario:
    """VSMM guide S3: start (60, 40) km, 300 m/s at 135° (counter-clockwise from +x); straight
    50 s, +1.87 °/s 96 s, straight 30 s, −2.8 °/s 64 s, straight 30 s, +5.6 °/s 32 s, straight
    30 s, −4.68 °/s 38 s, straight 30 s (400 s, T = 1 s)."""
    table = (
        (50, 0.0),
        (96, 1.87),
        (30, 0.0),
        (64, -2.8),
        (30, 0.0),
        (32, 5.6),
        (30, 0.0),
        (38, -4.68),
        (30, 0.0),
    )
    heading = math.radians(135.0)
    velocity = (300.0 * math.cos(heading), 300.0 * math.sin(heading))
    return timed_scenario(table, (60_000.0, 40_000.0), velocity, VSMM_T)


register("paper", paper_scenario)  # the TIP-IMM paper's Table 1 (SPEC §3)
register("atc", atc_scenario)
register("vsmm-s1", vsmm_s1)
register("vsmm-s2", vsmm_s2)
register("vsmm-s3", vsmm_s3)

#: The suites' configuration files (the tracker each scenario is run with), shipped in the package.
SUITE_CONFIGS = Path(__file__).resolve().parent / "suite"

#: Named suites of scenarios (``python -m imm_gym.evaluate --suite NAME``); ``"random"`` is the
#: randomized family. Each scenario runs with its configuration file ``SUITE_CONFIGS/NAME.yaml``.
SUITES: dict[str, tuple[str, ...]] = {
    "benchmark": ("paper", "random", "atc", "vsmm-s1", "vsmm-s2", "vsmm-s3"),
}
