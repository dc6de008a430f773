"""Tracking conditions drawn per episode: sampling period, sensor noise, outliers, detections,
target speed and the bank's process-noise tuning (overall, and of the maneuver models against
the first).

A policy that has to work on someone else's tracker must see more than one sensor and one
sampling period. :class:`Variation` gives each condition a range in the configuration
(``EnvConfig.vary``); every episode draws its own value from its scenario stream, before its
target (so a run's conditions and target are fixed by its seed alone). Together with the
randomized family's own ranges (turn rate, range: :class:`~imm_gym.scenarios.segments.
RandomFamily`) this is the broadened family of the "Bring your own tracker" issue.

Scale parameters (the sampling period and the noise standard deviations) are drawn
log-uniformly, ``exp(U(log lo, log hi))``, so that 0.5-5 s is as likely below 1.6 s as above;
probabilities uniformly. The tracker of each episode is built for that episode's conditions:
its transition and process noise for its ``T`` (right at every ``T`` only for a bank with
continuous-time noise, which ``vary.T`` therefore requires), its measurement noise ``R`` for its
sensor (:func:`bank_constants`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.scenarios.segments import TurnDesign
from imm_gym.sim.model_order import canonical_order
from imm_gym.tracking.initiation import MAX_VELOCITY_STD, MIN_VELOCITY_STD
from imm_gym.tracking.models import MotionModel, bank_dim, velocity_noise
from imm_gym.validation import (
    MAX_DISTANCE,
    MAX_SPEED,
    ConfigError,
    check_range,
    check_sequence,
    store,
)

Array = NDArray[np.float64]

#: The varied conditions in the order each episode draws them, with how: ``log`` (log-uniform,
#: a scale) or ``uniform``; the sensor fields among them are replaced in the episode's sensor.
DRAWS: dict[str, str] = {
    "T": "log",
    "sigma_r": "log",
    "sigma_theta_deg": "log",
    "sigma_pos": "log",
    "outlier_prob": "uniform",
    "detection_prob": "uniform",
    "speed": "log",
    "q_scale": "log",
    "q_maneuver": "log",
    "velocity_std": "log",
}
#: Each condition's allowed range (the sensor's own checks apply to a drawn sensor too).
LIMITS: dict[str, tuple[float, float]] = {
    "T": (0.0, math.inf),
    "sigma_r": (0.0, MAX_DISTANCE),
    "sigma_theta_deg": (0.0, 180.0),
    "sigma_pos": (0.0, MAX_DISTANCE),
    "outlier_prob": (0.0, 1.0),
    "detection_prob": (0.0, 1.0),
    "speed": (0.0, MAX_SPEED),
    "q_scale": (0.0, math.inf),
    "q_maneuver": (0.0, math.inf),
    "velocity_std": (MIN_VELOCITY_STD, MAX_VELOCITY_STD),
}
#: The conditions that are not the sensor's fields.
NOT_SENSOR = ("T", "speed", "q_scale", "q_maneuver", "velocity_std")


@dataclass(frozen=True)
class Variation:
    """Per-episode ranges ``(low, high)`` of the tracking conditions; ``None`` keeps the
    configured value (the default: nothing varies).

    Attributes:
        T: sampling period (s), log-uniform; replaces the randomized family's ``T`` (needs
            ``scenario="random"``, whose segments are counted in steps, and a bank with
            continuous-time noise).
        sigma_r, sigma_theta_deg: the sonar's range (m) and bearing (°) noise, log-uniform.
        sigma_pos: the position sensor's noise (m), log-uniform.
        outlier_prob, detection_prob: the sensor's outlier and detection (> 0) probabilities,
            uniform.
        speed: the target's speed (m/s), log-uniform; replaces the randomized family's
            ``speed`` range (needs ``scenario="random"``).
        q_scale: factor on every model's process noise (its ``q`` or ``intensity``,
            :meth:`~imm_gym.tracking.models.MotionModel.scaled`), log-uniform: trackers tuned
            tighter or looser than the configured bank.
        q_maneuver: a further factor on the process noise of the maneuver models (every model
            but the CV one: CT and CA; needs a CV model), log-uniform: banks whose
            maneuver models are tuned looser or tighter against straight flight than the
            configured one (the CT models of ``atc`` and ``vsmm-s1..s3`` carry 10-20 times the
            CV model's noise intensity, the paper's half of it).
        share: the share of episodes that draw their conditions (each decides by one uniform
            draw first); the others keep the configured tracker and target ranges, so that a
            training mixture keeps the configured tracker beside the varied ones (1: every
            episode varies).
        velocity_std: the prior standard deviation (m/s) of the track's first velocity
            estimate (``EnvConfig.velocity_std``; the estimate is the true velocity, SPEC §6),
            log-uniform: tracks started more or less sure of their velocity. Drawn after the other
            conditions, which it leaves as they were (the target, drawn next from the same
            stream, changes).
    """

    T: tuple[float, float] | None = None
    sigma_r: tuple[float, float] | None = None
    sigma_theta_deg: tuple[float, float] | None = None
    sigma_pos: tuple[float, float] | None = None
    outlier_prob: tuple[float, float] | None = None
    detection_prob: tuple[float, float] | None = None
    speed: tuple[float, float] | None = None
    q_scale: tuple[float, float] | None = None
    q_maneuver: tuple[float, float] | None = None
    velocity_std: tuple[float, float] | None = None
    share: float = 1.0

    def __post_init__(self) -> None:
        store(self, "share", check_range("vary.share", self.share, 0.0, 1.0, lo_open=True))
        for name, (lo_limit, hi_limit) in LIMITS.items():
            value = getattr(self, name)
            if value is None:
                continue
            lo, hi = check_sequence(f"vary.{name} (low, high)", value, 2)
            positive = DRAWS[name] == "log" or name == "detection_prob"
            lo = check_range(f"vary.{name}[0]", lo, lo_limit, hi_limit, lo_open=positive)
            hi = check_range(f"vary.{name}[1]", hi, lo, hi_limit)
            store(self, name, (lo, hi))
        if self.share != 1.0 and not self.active:
            raise ConfigError(
                f"vary.share ({self.share}) is the share of episodes that draw their conditions, "
                f"but no range is given: give at least one of {list(DRAWS)}"
            )

    @property
    def active(self) -> bool:
        """Whether any condition varies."""
        return any(getattr(self, name) is not None for name in DRAWS)

    @property
    def varied(self) -> tuple[str, ...]:
        """The varied conditions, in drawing order."""
        return tuple(name for name in DRAWS if getattr(self, name) is not None)

    def check(self, sensor: object) -> None:
        """Raise :class:`ConfigError` if a varied sensor field is not one of ``sensor``'s."""
        fields = {f.name for f in dataclasses.fields(sensor)}  # type: ignore[arg-type]
        for name in self.varied:
            if name not in NOT_SENSOR and name not in fields:
                raise ConfigError(
                    f"vary.{name}: the sensor {type(sensor).__name__} has no field {name!r} "
                    f"(its fields: {sorted(fields)})"
                )

    def draw(self, rng: np.random.Generator) -> dict[str, float]:
        """One episode's conditions from its generator: with ``share < 1`` first a uniform draw
        that keeps the configured conditions (nothing returned) above ``share``, then one draw
        per varied condition, in the order of :data:`DRAWS`, clipped to its ``[low, high]``
        (a log-uniform draw's ``exp`` may round one step past an end: a pinned range draws its
        value)."""
        values: dict[str, float] = {}
        if self.share < 1.0 and rng.uniform() >= self.share:
            return values
        for name in self.varied:
            lo, hi = getattr(self, name)
            if DRAWS[name] == "log":
                value = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
            else:
                value = float(rng.uniform(lo, hi))
            values[name] = min(max(value, lo), hi)
        return values


@dataclass(frozen=True)
class Conditions:
    """Each run's sampling period, sensor, target speed, process-noise factors and track start.

    Attributes:
        T: ``(R,)`` sampling periods (s).
        sensors: the R runs' sensors (the configured one with the varied fields replaced).
        speed: ``(R,)`` target speeds (m/s; NaN for a run that keeps the source's range), or
            None where no run varies it.
        q_scale: ``(R,)`` factors on the bank's process noise (1 where not varied).
        q_maneuver: ``(R,)`` further factors on the process noise of the maneuver models, every
            model but the CV one (1 where not varied).
        velocity_std: ``(R,)`` prior standard deviations of the first velocity estimate
            (m/s; the configured one where not varied).
    """

    T: Array
    sensors: tuple[Any, ...]
    speed: Array | None
    q_scale: Array
    q_maneuver: Array
    velocity_std: Array

    @property
    def R(self) -> Array:
        """``(R, m, m)`` the runs' measurement noise covariances."""
        return np.stack([np.asarray(s.R, dtype=np.float64) for s in self.sensors])

    def take(self, rows: NDArray[np.intp]) -> Conditions:
        """The conditions of the runs ``rows`` (in that order, repeats allowed)."""
        return Conditions(
            self.T[rows],
            tuple(self.sensors[r] for r in rows.tolist()),
            None if self.speed is None else self.speed[rows],
            self.q_scale[rows],
            self.q_maneuver[rows],
            self.velocity_std[rows],
        )


def draw_conditions(
    variation: Variation,
    T: float,
    sensor: object,
    rngs: Sequence[np.random.Generator],
    velocity_std: float = 5.0,
) -> Conditions:
    """The conditions of one run per generator: ``T``, ``sensor``, ``velocity_std`` and the rest
    with the varied values drawn from each (:meth:`Variation.draw`)."""
    R = len(rngs)
    periods, speeds, q_scale = np.full(R, float(T)), np.full(R, np.nan), np.ones(R)
    q_maneuver = np.ones(R)
    spreads = np.full(R, float(velocity_std))
    sensors = []
    for r, rng in enumerate(rngs):
        values = variation.draw(rng)
        periods[r] = values.pop("T", T)
        speeds[r] = values.pop("speed", np.nan)
        q_scale[r] = values.pop("q_scale", 1.0)
        q_maneuver[r] = values.pop("q_maneuver", 1.0)
        spreads[r] = values.pop("velocity_std", velocity_std)
        sensors.append(dataclasses.replace(sensor, **values) if values else sensor)  # type: ignore[type-var]
    speed = None if variation.speed is None else speeds
    return Conditions(periods, tuple(sensors), speed, q_scale, q_maneuver, spreads)


def bank_constants(
    models: Sequence[MotionModel], T: Array, q_scale: Array, q_maneuver: Array
) -> tuple[Array, Array]:
    """Per-run transition matrices and process noise of a linear bank, ``F (R, M, n, n)`` and
    ``Q (R, M, n, n)``: ``F_j(T_r)`` and the noise ``Q_j(T_r)`` of model ``j`` scaled by
    ``q_scale[r]``, and every model's but the CV model's by ``q_maneuver[r]`` too
    (:meth:`MotionModel.transition_matrix`, :meth:`MotionModel.noise_covariance`,
    :meth:`MotionModel.scaled`)."""
    n = bank_dim(models)
    F = np.stack([np.stack([m.transition_matrix(t, n) for m in models]) for t in T])
    return F, bank_noise(models, T, q_scale, q_maneuver)


def bank_noise(
    models: Sequence[MotionModel], T: Array, q_scale: Array, q_maneuver: Array
) -> Array:
    """The process noise ``Q (R, M, n, n)`` of :func:`bank_constants`."""
    n = bank_dim(models)
    return np.stack([
        np.stack([
            (m if f == 1.0 else m.scaled(f)).noise_covariance(n, t)
            for m, f in zip(models, maneuver_factors(models, s, a), strict=True)
        ])
        for t, s, a in zip(T, q_scale, q_maneuver, strict=True)
    ])


def maneuver_factors(
    models: Sequence[MotionModel], q_scale: float, q_maneuver: float
) -> list[float]:
    """Each model's process-noise factor: ``q_scale`` for a CV model, ``q_scale * q_maneuver``
    for the maneuver models (CT, CA), wherever the bank lists them."""
    return [q_scale if m.kind == "cv" else q_scale * q_maneuver for m in models]


def turn_design(
    models: Sequence[MotionModel], T: Array, q_scale: Array, q_maneuver: Array
) -> TurnDesign:
    """The turns each run's tracker is designed to fly: the turn rates of the bank's CT models
    and their :func:`~imm_gym.tracking.models.velocity_noise` per step at the run's ``T`` and
    process-noise factors (:func:`bank_noise`) over ``T``, the lateral acceleration
    ``sqrt(q / T)`` (m/s²) their noise absorbs. The CT models are taken in canonical order
    (:func:`~imm_gym.sim.model_order.canonical_order`, the first run's velocity noise breaking
    ties of turn rate), so that every listing of one bank draws the same targets.

    Raises:
        ConfigError: the bank has no CT model.
    """
    cts = [j for j, m in enumerate(models) if m.kind == "ct"]
    if not cts:
        raise ConfigError(
            "family.designed_share needs a bank with a CT model (the turns it is designed to "
            f"fly), got {[m.label for m in models]}"
        )
    Q = bank_noise(models, T, q_scale, q_maneuver)
    order = canonical_order(tuple(models[j] for j in cts), velocity_noise(Q[0, cts]))
    cts = [cts[c] for c in order]
    rates = np.array([models[j].omega for j in cts])
    accel_std = velocity_noise(Q[:, cts]) / np.asarray(T, dtype=np.float64)[:, None]
    return TurnDesign(np.broadcast_to(rates, accel_std.shape).copy(), accel_std)


def check_variation(variation: Variation, scenario: object, bank: object, sensor: object) -> None:
    """Raise :class:`ConfigError` where ``variation`` cannot apply: ``T`` varied outside the
    randomized family or with a bank whose process noise is per step, a varied field the sensor
    lacks, a heterogeneous bank (no per-run bank in its engine)."""
    if not variation.active:
        return
    variation.check(sensor)
    if not isinstance(bank, tuple):
        raise ConfigError(
            f"vary ({', '.join(variation.varied)}) needs a linear bank: the heterogeneous bank's "
            "engine runs every run at one T, one sensor and one track-start prior"
        )
    if variation.q_maneuver is not None and not any(m.kind == "cv" for m in bank):
        raise ConfigError(
            "vary.q_maneuver needs a bank with a CV model (the one whose noise it leaves, the "
            f"maneuver models' it scales), got {[m.label for m in bank]}"
        )
    if variation.speed is not None and scenario != "random":
        raise ConfigError(f"vary.speed needs scenario 'random', got {scenario!r}")
    if variation.T is not None:
        if scenario != "random":
            raise ConfigError(
                f"vary.T needs scenario 'random' (a named scenario's segments are timed for its "
                f"own T), got {scenario!r}"
            )
        per_step = [i for i, m in enumerate(bank) if m.noise != "continuous"]
        if per_step:
            raise ConfigError(
                f"vary.T needs a bank with continuous-time process noise (noise: continuous); "
                f"bank[{per_step[0]}] has per-step noise, right at one T only"
            )
