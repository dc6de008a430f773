"""Episodes: a source's truth, the sensor's measurements and the track initiation, for R runs.

Run ``r`` draws its truth from its scenario stream and its measurement noise from its noise
stream (:func:`imm_gym.seeding.streams`): the environment's slots (a stream pair each) and the
Monte-Carlo batches (:func:`draw_batch`, run ``r`` of a batch seeded ``s`` with seed ``s + r``)
draw through the same :func:`draw_episodes`, so every policy evaluated on a batch sees the same
targets and the same noise as an environment reset with those seeds.

With a :class:`~imm_gym.sim.conditions.Variation` (``EnvConfig.vary``), each run first draws its
conditions (sampling period, sensor noise, outlier and detection probabilities) from its scenario
stream, then its target at its ``T`` and its measurements from its own sensor. A randomized
family with ``designed_share > 0`` draws its targets for the runs' trackers: it needs the bank
(:func:`~imm_gym.sim.conditions.turn_design`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imm_gym.scenarios.segments import RandomFamily, Truth, TruthSource
from imm_gym.seeding import streams
from imm_gym.sim.conditions import Conditions, Variation, draw_conditions, turn_design
from imm_gym.tracking.initiation import initiate
from imm_gym.tracking.models import MotionModel
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
        conditions: each run's sampling period and sensor where they vary, else None.
    """

    truth: Truth
    measurements: Measurements
    x0: Array
    P0: Array
    conditions: Conditions | None = None

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
    variation: Variation | None = None,
    bank: Sequence[MotionModel] | None = None,
) -> Batch:
    """One run per pair of generators: the truth of ``source``, the measurements of ``sensor``,
    and the filter start from the first measurement and the true initial velocity (SPEC §6);
    with an active ``variation``, run by run at its own conditions (:func:`_draw_varied`).
    ``bank``: the tracker's models, which a family with ``designed_share > 0`` needs.

    Raises:
        ConfigError: ``scenario_rngs`` and ``noise_rngs`` differ in length.
    """
    if len(scenario_rngs) != len(noise_rngs):
        raise ConfigError(
            "draw_episodes needs one noise generator per scenario generator (one pair per run), "
            f"got {len(scenario_rngs)} scenario_rngs and {len(noise_rngs)} noise_rngs"
        )
    if variation is not None and variation.active:
        _check_varied_source(variation, source)
        return _draw_varied(
            source, sensor, scenario_rngs, noise_rngs, velocity_std, variation, bank
        )
    if _designed(source):
        T = np.full(len(scenario_rngs), source.T)
        design = turn_design(_bank(bank), T, np.ones_like(T), np.ones_like(T))
        truth = source.varied_truth(scenario_rngs, design=design)  # type: ignore[attr-defined]
    else:
        truth = source.truth(scenario_rngs)
    return Batch(truth, *_observe(sensor, truth.states, noise_rngs, velocity_std))


def _check_varied_source(variation: Variation, source: TruthSource) -> None:
    """Raise :class:`ConfigError` where ``variation`` varies what ``source`` fixes: a varied ``T``
    or target speed needs the randomized family (the refusal of
    :func:`~imm_gym.sim.conditions.check_variation` for ``EnvConfig.vary``). A fixed scenario's
    segments are counted in steps, timed for its own ``T``: at another ``T`` every turn would
    move in time; its speed is its initial velocity, not a range to draw from."""
    if isinstance(source, RandomFamily):
        return
    got = type(source).__name__
    if variation.speed is not None:
        raise ConfigError(f"vary.speed needs scenario 'random' (a RandomFamily), got a {got}")
    if variation.T is not None:
        raise ConfigError(
            f"vary.T needs scenario 'random' (a RandomFamily; a named scenario's segments are "
            f"timed for its own T), got a {got}"
        )


def _designed(source: TruthSource) -> bool:
    """Whether ``source`` draws its targets for their trackers (``designed_share > 0``)."""
    return isinstance(source, RandomFamily) and source.designed_share > 0.0


def _bank(bank: Sequence[MotionModel] | None) -> Sequence[MotionModel]:
    """``bank``, which a designed family needs."""
    if bank is None:
        raise ConfigError(
            "family.designed_share draws turns for the tracker that follows them: pass its "
            "bank (bank=...)"
        )
    return bank


def _observe(
    sensor: object, states: Array, noise_rngs: Sequence[np.random.Generator], velocity_std: float
) -> tuple[Measurements, Array, Array]:
    """The measurements of ``sensor`` of the true ``states`` and the filter start from the first
    one and the true initial velocity (SPEC §6)."""
    meas = sensor.measure(states, noise_rngs)  # type: ignore[attr-defined]
    x0, P0 = initiate(sensor, meas.z[:, 0], states[:, 0, 2:4], velocity_std)
    return meas, x0, P0


def _draw_varied(
    source: TruthSource,
    sensor: object,
    scenario_rngs: Sequence[np.random.Generator],
    noise_rngs: Sequence[np.random.Generator],
    velocity_std: float,
    variation: Variation,
    bank: Sequence[MotionModel] | None,
) -> Batch:
    """Run ``r``: its conditions from ``scenario_rngs[r]``
    (:func:`~imm_gym.sim.conditions.draw_conditions`), then the truth of ``source`` at its ``T``
    from the same generator, its measurements and start from its sensor; the runs stacked
    (``truth.T`` holds the R sampling periods). The randomized family without truth noise draws
    every run's target at once (:meth:`~imm_gym.scenarios.segments.RandomFamily.varied_truth`,
    the same numbers as a family per run); another source, run by run."""
    conditions = draw_conditions(variation, source.T, sensor, scenario_rngs, velocity_std)
    if isinstance(source, RandomFamily) and source.truth_q is None:
        design = None
        if _designed(source):
            design = turn_design(
                _bank(bank), conditions.T, conditions.q_scale, conditions.q_maneuver
            )
        truth = source.varied_truth(scenario_rngs, conditions.T, conditions.speed, design)
        states, turn_rate, accel = truth.states, truth.turn_rate, truth.accel
    else:
        truths = [
            _run_source(source, conditions, r).truth([rng]) for r, rng in enumerate(scenario_rngs)
        ]
        states, turn_rate, accel = (
            np.concatenate([getattr(t, name) for t in truths])
            for name in ("states", "turn_rate", "accel")
        )
    runs = []
    for r, noise_rng in enumerate(noise_rngs):
        runs.append(_observe(
            conditions.sensors[r], states[r:r + 1], [noise_rng], float(conditions.velocity_std[r])
        ))
    meas = Measurements(
        z=np.concatenate([m.z for m, _, _ in runs]),
        detected=np.concatenate([m.detected for m, _, _ in runs]),
        outlier=np.concatenate([m.outlier for m, _, _ in runs]),
    )
    x0 = np.concatenate([x0 for _, x0, _ in runs])
    P0 = np.concatenate([P0 for _, _, P0 in runs])
    return Batch(Truth(states, turn_rate, accel, conditions.T), meas, x0, P0, conditions)


def _run_source(source: TruthSource, conditions: Conditions, r: int) -> TruthSource:
    """``source`` at run ``r``'s sampling period and target speed, where they vary."""
    changes: dict[str, object] = {}
    if conditions.T[r] != source.T:
        changes["T"] = float(conditions.T[r])
    if conditions.speed is not None and not np.isnan(conditions.speed[r]):
        changes["speed"] = (float(conditions.speed[r]),) * 2
    return dataclasses.replace(source, **changes) if changes else source  # type: ignore[type-var]


def draw_batch(
    source: TruthSource,
    sensor: object,
    runs: int,
    seed: int,
    velocity_std: float = 5.0,
    variation: Variation | None = None,
    bank: Sequence[MotionModel] | None = None,
) -> Batch:
    """R runs of ``source`` (a fixed scenario or a family) seen by ``sensor``, run ``r`` from the
    streams of seed ``seed + r`` (at conditions drawn from ``variation``, if given; for the
    tracker of models ``bank``, which a family with ``designed_share > 0`` needs)."""
    runs = check_int("runs", runs, 1)
    seed = check_int("seed", seed, 0)
    if not callable(getattr(source, "truth", None)):
        raise ConfigError(
            f"source must be a Scenario, a RandomFamily or another truth source, got "
            f"{type(source).__name__}"
        )
    scenario_rngs, noise_rngs = zip(*(streams(seed + r) for r in range(runs)), strict=True)
    return draw_episodes(
        source, sensor, scenario_rngs, noise_rngs, velocity_std, variation, bank
    )
