"""Episodes: a source's truth, the sensor's measurements and the track initiation, for R runs.

Run ``r`` draws its truth from its scenario stream and its measurement noise from its noise
stream (:func:`imm_gym.seeding.streams`): the environment's slots (a stream pair each) and the
Monte-Carlo batches (:func:`draw_batch`, run ``r`` of a batch seeded ``s`` with seed ``s + r``)
draw through the same :func:`draw_episodes`, so every policy evaluated on a batch sees the same
targets and the same noise as an environment reset with those seeds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imm_gym.scenarios.segments import Truth, TruthSource
from imm_gym.seeding import streams
from imm_gym.tracking.initiation import initiate
from imm_gym.tracking.sensors import Measurements
from imm_gym.validation import ConfigError, check_int

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Batch:
    """Truth, measurements and track initiation of R runs.

    Attributes:
        truth: states ``(R, K+1, 4)`` at ``t = 0..K``.
        measurements: ``z (R, K+1, m)``; ``z[:, 0]`` initiates the track, ``z[:, 1:]`` are filtered.
        x0, P0: ``(R, 4)``, ``(R, 4, 4)`` initial estimate from ``z[:, 0]``.
    """

    truth: Truth
    measurements: Measurements
    x0: Array
    P0: Array

    @property
    def n_runs(self) -> int:
        return self.x0.shape[0]

    @property
    def horizon(self) -> int:
        return self.truth.horizon


def draw_episodes(
    source: TruthSource,
    sensor: object,
    scenario_rngs: Sequence[np.random.Generator],
    noise_rngs: Sequence[np.random.Generator],
    velocity_std: float = 5.0,
) -> Batch:
    """One run per pair of generators: the truth of ``source``, the measurements of ``sensor``,
    and the filter start from the first measurement and the true initial velocity (SPEC §6)."""
    truth = source.truth(scenario_rngs)
    meas = sensor.measure(truth.states, noise_rngs)  # type: ignore[attr-defined]
    x0, P0 = initiate(sensor, meas.z[:, 0], truth.states[:, 0, 2:4], velocity_std)
    return Batch(truth, meas, x0, P0)


def draw_batch(
    source: TruthSource,
    sensor: object,
    runs: int,
    seed: int,
    velocity_std: float = 5.0,
) -> Batch:
    """R runs of ``source`` (a fixed scenario or a family) seen by ``sensor``, run ``r`` from the
    streams of seed ``seed + r``."""
    runs = check_int("runs", runs, 1)
    seed = check_int("seed", seed, 0)
    if not callable(getattr(source, "truth", None)):
        raise ConfigError(
            f"source must be a Scenario, a RandomFamily or another truth source, got "
            f"{type(source).__name__}"
        )
    scenario_rngs, noise_rngs = zip(*(streams(seed + r) for r in range(runs)), strict=True)
    return draw_episodes(source, sensor, scenario_rngs, noise_rngs, velocity_std)
