"""Monte-Carlo batches: R runs of truth and measurements with common random numbers.

Run ``r`` of a batch seeded ``s`` draws its scenario and its noise from
:func:`imm_gym.seeding.streams` with seed ``s + r``; every policy evaluated on the batch sees the
same targets and the same noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imm_gym.scenarios.segments import RandomFamily, Scenario, Truth, generate_truth
from imm_gym.seeding import streams
from imm_gym.tracking.initiation import initiate
from imm_gym.tracking.sensors import Measurements
from imm_gym.validation import ConfigError, check_int

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Batch:
    """Truth, measurements and track initiation of R runs.

    Attributes:
        scenarios: the R scenarios.
        truth: states ``(R, K+1, 4)`` at ``t = 0..K``.
        measurements: ``z (R, K+1, m)``; ``z[:, 0]`` initiates the track, ``z[:, 1:]`` are filtered.
        x0, P0: ``(R, 4)``, ``(R, 4, 4)`` initial estimate from ``z[:, 0]``.
    """

    scenarios: tuple[Scenario, ...]
    truth: Truth
    measurements: Measurements
    x0: Array
    P0: Array

    @property
    def n_runs(self) -> int:
        return self.truth.n_runs

    @property
    def horizon(self) -> int:
        return self.truth.horizon


def draw_batch(
    source: Scenario | RandomFamily,
    sensor: object,
    runs: int,
    seed: int,
    velocity_std: float = 5.0,
) -> Batch:
    """Draw R runs of ``source`` (a fixed scenario or a family) seen by ``sensor``.

    The filter starts from the first measurement and the scenario's initial velocity (SPEC §6).
    """
    check_int("runs", runs, 1)
    check_int("seed", seed, 0)
    if not isinstance(source, (Scenario, RandomFamily)):
        raise ConfigError(
            f"source must be a Scenario or a RandomFamily, got {type(source).__name__}"
        )
    scenario_rngs, noise_rngs = zip(*(streams(seed + r) for r in range(runs)), strict=True)
    if isinstance(source, RandomFamily):
        scenarios = tuple(source.sample(rng) for rng in scenario_rngs)
    else:
        scenarios = (source,) * runs
    truth = generate_truth(scenarios, scenario_rngs)
    meas = sensor.measure(truth.states, noise_rngs)  # type: ignore[attr-defined]
    velocity = np.array([s.velocity for s in scenarios])
    x0, P0 = initiate(sensor, meas.z[:, 0], velocity, velocity_std)
    return Batch(scenarios, truth, meas, x0, P0)
