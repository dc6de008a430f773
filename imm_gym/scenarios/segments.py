"""Target scenarios: segment tables, the paper scenario, the randomized family, batched truth.

A scenario is a table of segments (duration in steps, turn rate, tangential acceleration) plus the
initial position and velocity, the sampling period and an optional truth process noise. Step ``k``
(``k = 1..K``) moves the target from ``t = (k-1) T`` to ``t = k T`` with the motion of the segment
that contains it; state 0 is the start.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.hetero import HeteroBank
from imm_gym.tracking.models import MotionModel, ct_ratios, ct_transition
from imm_gym.validation import (
    MAX_DISTANCE,
    MAX_SPEED,
    ConfigError,
    check_finite,
    check_int,
    check_range,
    check_sequence,
    from_dict,
    store,
)

Array = NDArray[np.float64]


class TruthSource(Protocol):
    """Where targets come from: every source (a fixed :class:`Scenario`, the
    :class:`RandomFamily`, the profile families of :mod:`imm_gym.scenarios.profiles`, a user's
    scenario file) draws the truth of R runs from one generator per run.

    Attributes:
        T: sampling period (s).
        horizon: steps K of a run.
    """

    T: float

    @property
    def horizon(self) -> int: ...

    def truth(self, rngs: Sequence[np.random.Generator]) -> Truth:
        """The :class:`Truth` of ``len(rngs)`` runs, run r drawn from ``rngs[r]`` alone."""
        ...


@dataclass(frozen=True)
class Segment:
    """A stretch of motion.

    Attributes:
        duration: number of steps (>= 1).
        turn_rate_deg: turn rate in °/s, > 0 counter-clockwise (the paper's "-1.2 °/s" turns
            clockwise, SPEC §6); 0 for straight motion.
        accel: tangential acceleration in m/s² (speed change along the heading); 0 by default.
            A segment either turns or accelerates.
    """

    duration: int
    turn_rate_deg: float = 0.0
    accel: float = 0.0

    def __post_init__(self) -> None:
        store(self, "duration", check_int("segment.duration", self.duration, 1))
        store(self, "turn_rate_deg", check_finite("segment.turn_rate_deg", self.turn_rate_deg))
        store(self, "accel", check_finite("segment.accel", self.accel))
        if self.turn_rate_deg != 0.0 and self.accel != 0.0:
            raise ConfigError("a segment has either turn_rate_deg or accel non-zero, not both")

    @property
    def motion(self) -> str:
        """``"straight"``, ``"turn"`` or ``"accel"``."""
        if self.turn_rate_deg != 0.0:
            return "turn"
        return "accel" if self.accel != 0.0 else "straight"


def _segment(i: int, value: Segment | Mapping[str, Any]) -> Segment:
    """Entry ``i`` of ``scenario.segments``: a :class:`Segment` or a mapping of its fields."""
    try:
        return from_dict(Segment, value, f"scenario.segments[{i}]")
    except ConfigError as err:
        if str(err).startswith(f"scenario.segments[{i}]"):
            raise
        raise ConfigError(f"scenario.segments[{i}]: {err}") from None


@dataclass(frozen=True)
class Scenario:
    """A deterministic segment table with its initial state.

    Attributes:
        segments: the motion table, in order.
        position: initial position ``(x, y)`` in m.
        velocity: initial velocity ``(vx, vy)`` in m/s.
        T: sampling period in s.
        truth_q: diagonal of a discrete-time process noise added to the true state
            ``[x, y, vx, vy]`` at every step, or ``None`` for a deterministic truth (SPEC §6).
    """

    segments: tuple[Segment, ...]
    position: tuple[float, float] = (0.0, 0.0)
    velocity: tuple[float, float] = (0.0, 0.0)
    T: float = 1.0
    truth_q: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        segs = tuple(
            _segment(i, s) for i, s in enumerate(check_sequence("scenario.segments", self.segments))
        )
        if not segs:
            raise ConfigError("scenario.segments must contain at least one segment")
        store(self, "segments", segs)
        for name, extent in (("position", MAX_DISTANCE), ("velocity", MAX_SPEED)):
            value = check_sequence(f"scenario.{name}", getattr(self, name), 2)
            store(
                self,
                name,
                tuple(check_range(f"scenario.{name}", v, -extent, extent) for v in value),
            )
        store(self, "T", check_range("scenario.T", self.T, 0.0, lo_open=True))
        self._check_speeds()
        if self.truth_q is not None:
            q = check_sequence("scenario.truth_q (x, y, vx, vy)", self.truth_q, 4)
            store(self, "truth_q", tuple(check_range("scenario.truth_q", v, 0.0) for v in q))

    def _check_speeds(self) -> None:
        """An acceleration segment acts along the heading: it needs a moving target and must not
        drive the speed below 0 nor above :data:`~imm_gym.validation.MAX_SPEED` (the speed after
        it is ``|v| + accel duration T``; turns keep it)."""
        speed = math.hypot(*self.velocity)
        if speed > MAX_SPEED:
            raise ConfigError(
                f"scenario.velocity: the speed |v| must be in [0, {MAX_SPEED}] m/s, got {speed:.6g}"
            )
        for i, seg in enumerate(self.segments):
            if seg.accel == 0.0:
                continue
            where = f"scenario.segments[{i}].accel"
            if speed <= 0.0:
                raise ConfigError(
                    f"{where}: the target is at rest when this segment starts, so it has no "
                    "heading to accelerate along; give scenario.velocity or a segment before"
                )
            end = speed + seg.accel * seg.duration * self.T
            if end < -1e-9 * max(speed, 1.0):
                raise ConfigError(
                    f"{where}: {seg.accel} m/s² for {seg.duration} steps of {self.T} s drives the "
                    f"speed from {speed:.6g} m/s below 0 ({end:.6g} m/s); it may at most stop "
                    f"the target (accel >= {-speed / (seg.duration * self.T):.6g})"
                )
            if end > MAX_SPEED:
                raise ConfigError(
                    f"{where}: {seg.accel} m/s² for {seg.duration} steps of {self.T} s drives the "
                    f"speed from {speed:.6g} m/s above {MAX_SPEED} m/s ({end:.6g} m/s; accel <= "
                    f"{(MAX_SPEED - speed) / (seg.duration * self.T):.6g})"
                )
            speed = max(end, 0.0)

    @property
    def horizon(self) -> int:
        """Number of steps K."""
        return sum(s.duration for s in self.segments)

    def truth(self, rngs: Sequence[np.random.Generator]) -> Truth:
        """The truth of one run per generator (:class:`TruthSource`): this scenario each time
        (the generators draw its truth noise, if any)."""
        return generate_truth([self] * len(rngs), rngs)

    def profile(self) -> tuple[Array, Array]:
        """Per-step turn rate (rad/s) and tangential acceleration (m/s²), each ``(K,)``."""
        durations = [s.duration for s in self.segments]
        omega = np.repeat([math.radians(s.turn_rate_deg) for s in self.segments], durations)
        accel = np.repeat([s.accel for s in self.segments], durations)
        return omega, accel


def paper_scenario() -> Scenario:
    """The TIP-IMM paper's Table 1 scenario (SPEC §3): 150 s from (3000, 4500) m at (20, 15) m/s."""
    return Scenario(
        segments=(
            Segment(40),
            Segment(30, -1.2),
            Segment(20),
            Segment(25, 1.8),
            Segment(35),
        ),
        position=(3000.0, 4500.0),
        velocity=(20.0, 15.0),
        T=1.0,
    )


@dataclass(frozen=True)
class RandomFamily:
    """The randomized scenario family of SPEC §6, used for training and held-out evaluation.

    Start at range ``U(range_m)`` and bearing ``U(-pi, pi)`` from the origin, speed ``U(speed)``,
    heading ``U(-pi, pi)``; ``n_segments`` drawn uniformly, each at least ``min_duration`` steps
    (durations uniform over all such compositions of ``horizon``); straight first, then alternating
    straight / turn; turn rates ``±U(turn_rate_deg)`` with a random sign.

    With ``designed_share > 0`` the family draws some of its targets for the tracker that will
    follow them: each run first draws, with probability ``designed_share``, whether its turns are
    the ones its tracker's CT models are designed to fly (:class:`TurnDesign`); such a run draws
    each turn's model uniformly among them and its rate uniformly within that model's
    :meth:`designed_band`, the sign the model's. A textbook IMM tunes a CT model's process noise
    to the turns it is to follow, so the tracker is evidence about its targets; a family that
    ignores it meets every tracker with every turn.

    Attributes:
        designed_share: the share of runs whose turns lie within their tracker's designed bands
            (0: none, the family as above; needs the tracker, :meth:`varied_truth`).
        designed_width: the bands' half-width in standard deviations of a CT model's
            acceleration noise (2: the noise's intensity ``q`` meets ``sqrt(q T) >= a T / 2`` for
            every lateral acceleration ``a`` of the band, the lower end of Bar-Shalom et al.'s
            2001 guideline ``a T / 2 <= sqrt(q T) <= a T``, §6.2.2).
    """

    horizon: int = 150
    range_m: tuple[float, float] = (3000.0, 8000.0)
    speed: tuple[float, float] = (5.0, 25.0)
    n_segments: tuple[int, int] = (3, 6)
    min_duration: int = 10
    turn_rate_deg: tuple[float, float] = (0.5, 3.0)
    T: float = 1.0
    truth_q: tuple[float, float, float, float] | None = None
    designed_share: float = 0.0
    designed_width: float = 2.0

    def __post_init__(self) -> None:
        store(self, "horizon", check_int("family.horizon", self.horizon, 1))
        store(self, "min_duration", check_int("family.min_duration", self.min_duration, 1))
        extents = {"range_m": MAX_DISTANCE, "speed": MAX_SPEED, "turn_rate_deg": math.inf}
        for name, extent in extents.items():
            lo, hi = check_sequence(f"family.{name} (low, high)", getattr(self, name), 2)
            lo = check_range(f"family.{name}[0]", lo, 0.0, extent)
            store(self, name, (lo, check_range(f"family.{name}[1]", hi, lo, extent)))
        n_lo, n_hi = check_sequence("family.n_segments (low, high)", self.n_segments, 2)
        n_lo = check_int("family.n_segments[0]", n_lo, 1)
        store(self, "n_segments", (n_lo, check_int("family.n_segments[1]", n_hi, n_lo)))
        if self.n_segments[1] * self.min_duration > self.horizon:
            raise ConfigError(
                f"family.n_segments[1] * family.min_duration must be <= family.horizon "
                f"({self.n_segments[1]} * {self.min_duration} > {self.horizon})"
            )
        store(self, "T", check_range("family.T", self.T, 0.0, lo_open=True))
        if self.truth_q is not None:
            q = check_sequence("family.truth_q (x, y, vx, vy)", self.truth_q, 4)
            store(self, "truth_q", tuple(check_range("family.truth_q", v, 0.0) for v in q))
        share = check_range("family.designed_share", self.designed_share, 0.0, 1.0)
        store(self, "designed_share", share)
        if share > 0.0 and self.truth_q is not None:
            raise ConfigError(
                "family.designed_share needs a noise-free family (truth_q null): its runs are "
                "drawn with their trackers' designs"
            )
        width = check_range("family.designed_width", self.designed_width, 0.0, lo_open=True)
        store(self, "designed_width", width)

    def designed_band(self, rate: Array, accel_std: Array, speed: float) -> tuple[Array, Array]:
        r"""The turn-rate magnitudes (°/s) CT models of turn rates ``rate`` (rad/s) and
        acceleration noise ``accel_std`` (m/s²) are designed to fly at ``speed`` (m/s): those
        whose lateral acceleration :math:`v\,\omega` lies within ``designed_width`` (c)
        standard deviations of the model's,

        .. math:: |\omega| \in [|\omega_j| - c\,a_j / v,\; |\omega_j| + c\,a_j / v],

        clipped to ``turn_rate_deg`` (which bounds every target of the family; a band beyond
        it becomes its nearer end). At ``speed = 0`` the band is the family's range.

        Returns:
            ``(low, high)``, each of the shape of ``rate``.
        """
        degrees = 180.0 / math.pi
        centre = np.abs(rate) * degrees
        half = self.designed_width * accel_std * degrees / speed if speed > 0 else math.inf
        lo, hi = self.turn_rate_deg
        return np.clip(centre - half, lo, hi), np.clip(centre + half, lo, hi)

    def truth(self, rngs: Sequence[np.random.Generator]) -> Truth:
        """The truth of one run per generator (:class:`TruthSource`): a scenario drawn from each
        (:meth:`sample`), then its truth noise, if any, from the same generator.

        Without truth noise the draws go straight into the batch's arrays (the same numbers as
        :func:`generate_truth` of the sampled scenarios, without building them)."""
        if not rngs:
            return generate_truth([], rngs)
        if self.truth_q is not None:
            return generate_truth(self._scenarios(self._draws(rngs)), rngs)
        return self.varied_truth(rngs)  # raises with designed_share > 0: it needs the tracker

    def varied_truth(
        self,
        rngs: Sequence[np.random.Generator],
        T: Array | None = None,
        speed: Array | None = None,
        design: TurnDesign | None = None,
    ) -> Truth:
        """The noise-free truth of one run per generator, run ``r`` as the family with
        ``T = T[r]`` and ``speed = (speed[r], speed[r])`` draws it (None, or a NaN speed: the
        family's own) for a tracker of design ``design`` (row ``r``): the runs of
        :class:`~imm_gym.sim.conditions.Variation`, all at once.

        Args:
            rngs: one generator per run (at least one).
            T: ``(R,)`` sampling periods (s), or None.
            speed: ``(R,)`` target speeds (m/s; NaN keeps the family's range), or None.
            design: the runs' trackers (required with ``designed_share > 0``, else unused).

        Returns:
            The :class:`Truth`; its ``T`` is ``T`` where given.

        Raises:
            ConfigError: the family has truth noise (its runs need one family per ``T``), or
                ``designed_share > 0`` and no ``design``.
        """
        if self.truth_q is not None:
            raise ConfigError("varied_truth draws noise-free runs; this family has truth_q")
        draws = self._draws(rngs, speed, design)
        rates = draws.rates * (math.pi / 180.0)  # as math.radians
        omega = np.repeat(rates, draws.durations).reshape(len(rngs), self.horizon)
        period = self.T if T is None else np.asarray(T, dtype=np.float64)
        states = _constant_speed_truth(draws.position, draws.velocity, omega, period)
        return Truth(states=states, turn_rate=omega, accel=np.zeros_like(omega), T=period)  # type: ignore[arg-type]

    def sample(self, rng: np.random.Generator) -> Scenario:
        """Draw one scenario; the sequence of draws is fixed, so a seeded ``rng`` reproduces it."""
        return self._scenarios(self._draws([rng]))[0]

    def _draws(
        self,
        rngs: Sequence[np.random.Generator],
        speed: Array | None = None,
        design: TurnDesign | None = None,
    ) -> FamilyDraws:
        """The scenarios' draws, one run per generator (at least one); run ``r`` draws its speed
        from ``(speed[r], speed[r])`` where given and not NaN (:meth:`varied_truth`).

        Run ``r`` draws from ``rngs[r]``, in this order: range, bearing, speed and heading
        (uniform), the number of segments ``n``, the composition's ``n - 1`` bars (a choice
        without replacement), ``n`` turn-rate magnitudes (uniform) and ``n`` signs (the index
        draw of ``choice([-1, 1], size=n)``, :data:`_SIGNS`). With ``designed_share > 0`` then one
        uniform; below the share, ``n`` CT models of ``design`` (an index each) and ``n``
        uniforms that place the magnitudes in their :meth:`designed_band`, which replace the
        magnitudes and signs drawn before. Only these calls are made per run; what follows from
        them (the signed rates, the durations) is computed for all runs at once.
        """
        if self.designed_share > 0.0 and design is None:
            raise ConfigError(
                "family.designed_share draws turns for the tracker that follows them: draw the "
                "family with its bank (draw_episodes(..., bank=...), or an environment)"
            )
        lo, hi = self.n_segments
        K, minimum = self.horizon, self.min_duration
        speeds = [self.speed] * len(rngs)
        if speed is not None:
            speeds = [s if math.isnan(v) else (v, v) for s, v in zip(speeds, speed.tolist(),
                                                                     strict=True)]
        starts, counts, bars, magnitudes, signs = [], [], [], [], []
        for r, (rng, speed_range) in enumerate(zip(rngs, speeds, strict=True)):
            rng_range = rng.uniform(*self.range_m)
            bearing = rng.uniform(-math.pi, math.pi)
            v = rng.uniform(*speed_range)
            heading = rng.uniform(-math.pi, math.pi)
            n = int(rng.integers(lo, hi + 1))
            bars.append(rng.choice(K - n * minimum + n - 1, size=n - 1, replace=False))
            magnitudes.append(rng.uniform(*self.turn_rate_deg, size=n))
            signs.append(rng.integers(0, 2, size=n))
            if design is not None and self.designed_share > 0.0:
                if rng.uniform() < self.designed_share:
                    model = rng.integers(0, design.rates.shape[1], size=n)
                    rate = design.rates[r, model]
                    low, high = self.designed_band(rate, design.accel_std[r, model], v)
                    magnitudes[-1] = low + rng.uniform(size=n) * (high - low)
                    signs[-1] = (rate > 0).astype(np.int64)
            counts.append(n)
            starts.append((rng_range * math.cos(bearing), rng_range * math.sin(bearing),
                           v * math.cos(heading), v * math.sin(heading)))
        n_segments = np.array(counts, dtype=np.int64)
        rates = np.concatenate(magnitudes) * _SIGNS[np.concatenate(signs)]
        # straight first, then alternating straight / turn: the run's segments 0, 2, 4, ...
        first = np.repeat(np.cumsum(n_segments) - n_segments, n_segments)
        rates[(np.arange(rates.size) - first) % 2 == 0] = 0.0
        start = np.array(starts)
        return FamilyDraws(
            start[:, :2], start[:, 2:], n_segments, _compositions(bars, n_segments, K, minimum),
            rates,
        )

    def _scenarios(self, draws: FamilyDraws) -> list[Scenario]:
        """The :class:`Scenario` of each run of :meth:`_draws`."""
        ends = np.cumsum(draws.n_segments).tolist()
        durations, rates = draws.durations.tolist(), draws.rates.tolist()
        scenarios = []
        for r, (n, end) in enumerate(zip(draws.n_segments.tolist(), ends, strict=True)):
            segments = tuple(
                Segment(d, w) for d, w in zip(durations[end - n:end], rates[end - n:end],
                                              strict=True)
            )
            scenarios.append(Scenario(segments, tuple(draws.position[r].tolist()),
                                      tuple(draws.velocity[r].tolist()), T=self.T,
                                      truth_q=self.truth_q))
        return scenarios


#: The population of the turn signs: ``rng.choice(_SIGNS, size=n)`` is
#: ``_SIGNS[rng.integers(0, 2, size=n)]`` (``Generator.choice`` without ``p``, with replacement,
#: draws its indices with ``integers(0, len(a), size, dtype=int64)`` and takes them from ``a``).
_SIGNS = np.array([-1.0, 1.0])


class TurnDesign(NamedTuple):
    """The turns each run's tracker is designed to fly (:attr:`RandomFamily.designed_share`):
    its CT models' turn rates and the lateral acceleration their process noise absorbs.

    Attributes:
        rates: ``(R, C)`` the turn rates (rad/s, > 0 counter-clockwise) of the C CT models.
        accel_std: ``(R, C)`` their RMS velocity process noise per step over the sampling
            period (m/s²): ``sqrt(q / T)`` for white-noise acceleration of intensity ``q``.
    """

    rates: Array
    accel_std: Array


class FamilyDraws(NamedTuple):
    """The draws of R runs of a :class:`RandomFamily`, their segments concatenated run after run.

    Attributes:
        position, velocity: ``(R, 2)`` start position (m) and velocity (m/s).
        n_segments: ``(R,)`` segments of each run.
        durations: ``(S,)`` segment durations (steps), ``S = n_segments.sum()``.
        rates: ``(S,)`` turn rates (°/s; 0 on the straight segments).
    """

    position: Array
    velocity: Array
    n_segments: NDArray[np.int64]
    durations: NDArray[np.int64]
    rates: Array


def _compositions(
    bars: Sequence[NDArray[np.int64]], parts: NDArray[np.int64], total: int, minimum: int
) -> NDArray[np.int64]:
    """Uniformly drawn compositions of ``total`` into ``parts[r]`` integers, each >= ``minimum``,
    concatenated run after run, from each run's ``parts[r] - 1`` distinct bars drawn from
    ``range(extra + parts[r] - 1)``, ``extra = total - parts[r] * minimum`` (stars and bars).

    Run by run: ``diff([-1, *sort(bars), extra + parts - 1]) - 1 + minimum``; here the runs'
    edges are the rows of one array, padded with ``total`` (above every edge), sorted at once.
    """
    R, width = parts.size, int(parts.max())
    n_bars = parts - 1
    edges = np.full((R, width + 1), total, dtype=np.int64)
    edges[:, 0] = -1
    flat = np.concatenate(bars)
    rows = np.repeat(np.arange(R), n_bars)
    edges[rows, 1 + np.arange(flat.size) - np.repeat(np.cumsum(n_bars) - n_bars, n_bars)] = flat
    edges[np.arange(R), parts] = total - parts * minimum + parts - 1
    edges.sort(axis=1)
    durations = np.diff(edges, axis=1) - 1 + minimum
    return durations[np.arange(width) < parts[:, None]]


@dataclass(frozen=True)
class Truth:
    """Ground truth of N runs.

    Attributes:
        states: ``(N, K+1, 4)`` true ``[x, y, vx, vy]`` at ``t = 0, T, ..., K T``.
        turn_rate: ``(N, K)`` turn rate (rad/s) of step k (moving from k-1 to k).
        accel: ``(N, K)`` tangential acceleration (m/s²) of step k.
        T: sampling period.
        heading: ``(N, K+1)`` true heading / yaw (rad) where the source keeps it (the profile
            sources of :mod:`imm_gym.scenarios.profiles`), else None.
    """

    states: Array
    turn_rate: Array
    accel: Array
    T: float = field(default=1.0)
    heading: Array | None = None

    @property
    def n_runs(self) -> int:
        return self.states.shape[0]

    @property
    def horizon(self) -> int:
        return self.turn_rate.shape[1]


def true_model_index(truth: Truth, models: Sequence[MotionModel] | HeteroBank) -> NDArray[np.int64]:
    """The bank model that matches the true motion of each step, ``(R, K)``; -1 if none.

    Straight -> the first CV model; turn -> the CT model turning the same way whose rate is
    closest; acceleration -> the first CA model, turning or not (a constant Cartesian
    acceleration records a turn rate too), else the turn's CT model. For a heterogeneous bank
    (:class:`~imm_gym.tracking.hetero.HeteroBank`): straight -> NCV, turn -> CT (turn rate
    estimated), acceleration -> CTRA.

    Twins (two models of one kind that differ in their noise only, such as a quiet and a loud
    CV model, or two CT models of one turn rate) make the true model ambiguous: the first
    listed is taken, so the index, and the critic's one-hot of it, depends on how the bank lists
    the twins, also with ``model_order="canonical"``.
    """
    omega, accel = truth.turn_rate, truth.accel
    starts, lengths = _runs(omega, accel)  # a segment's motion holds for many steps
    idx = _model_index(omega.reshape(-1)[starts], accel.reshape(-1)[starts], models)
    return np.repeat(idx, lengths).reshape(omega.shape)


def _model_index(
    omega: Array, accel: Array, models: Sequence[MotionModel] | HeteroBank
) -> NDArray[np.int64]:
    """:func:`true_model_index` of each entry of ``omega``, ``accel`` (one shape)."""
    idx = np.full(omega.shape, -1, dtype=np.int64)
    if isinstance(models, HeteroBank):  # kinds ncv / ct / ctra
        kinds = list(models.models)
        for kind, where in (
            ("ncv", (omega == 0) & (accel == 0)),
            ("ct", (omega != 0) & (accel == 0)),
            ("ctra", accel != 0),
        ):
            if kind in kinds:
                idx[where] = kinds.index(kind)
        return idx
    kinds = [m.kind for m in models]
    if "cv" in kinds:
        idx[(omega == 0) & (accel == 0)] = kinds.index("cv")
    accelerating = np.zeros(omega.shape, dtype=bool)
    if "ca" in kinds:
        accelerating = accel != 0  # the CA model's, turning or not
        idx[accelerating] = kinds.index("ca")
    for sign in (1.0, -1.0):
        cts = [(i, m.omega) for i, m in enumerate(models) if m.kind == "ct" and m.omega * sign > 0]
        if not cts:
            continue
        turning = (omega * sign > 0) & ~accelerating
        rates = np.array([w for _, w in cts])
        nearest = np.argmin(np.abs(omega[..., None] - rates), axis=-1)
        idx[turning] = np.array([i for i, _ in cts])[nearest[turning]]
    return idx


def _constant_speed_truth(p0: Array, v0: Array, omega: Array, T: float | Array) -> Array:
    """Noise-free straight/turn motion in closed form, vectorized over runs and steps.

    The heading advances by ``omega_k T`` per step and the speed is constant, so the velocity
    before step k is ``R(sum_{l<k} omega_l T) v0``; step k moves the position by
    ``sin(omega T)/omega v + (1 - cos(omega T))/omega J v`` (``J`` the 90° rotation; ``T v`` when
    ``omega = 0``), the first row of ``F_CT``. The position is ``p0`` plus the cumulative sum of
    the moves (``p0 + 0`` at ``t = 0``). ``T``: one sampling period, or one per run ``(N,)``.
    """
    N, K = omega.shape
    if np.ndim(T):
        T = np.asarray(T, dtype=np.float64)[:, None]
    states = np.empty((N, K + 1, 4))
    heading = np.empty((N, K + 1))
    heading[:, 0] = 0.0
    np.cumsum(omega * T, axis=1, out=heading[:, 1:])
    c, s = np.cos(heading), np.sin(heading)
    vx0, vy0 = v0[:, :1], v0[:, 1:]
    np.subtract(c * vx0, s * vy0, out=states[:, :, 2])
    np.add(s * vx0, c * vy0, out=states[:, :, 3])
    sin_ratio, cos_ratio = _ct_ratios_by_runs(omega, T)  # F_CT[:2, 2:] = [[sr, -cr], [cr, sr]]
    vx, vy = states[:, :-1, 2], states[:, :-1, 3]  # velocity before step k
    states[:, 0, :2] = p0 + 0.0
    for axis, dp in enumerate((sin_ratio * vx - cos_ratio * vy, cos_ratio * vx + sin_ratio * vy)):
        np.add(p0[:, axis, None], np.cumsum(dp, axis=1, out=dp), out=states[:, 1:, axis])
    return states


def _ct_ratios_by_runs(omega: Array, T: float | Array) -> tuple[Array, Array]:
    """:func:`~imm_gym.tracking.models.ct_ratios` of ``omega (N, K)`` at ``T`` (a float or an
    array broadcast to ``omega``), computed once per run of equal entries (:func:`_runs`) and
    repeated: a segment's turn rate holds for many steps."""
    if np.ndim(T):
        period = np.broadcast_to(T, omega.shape)
        starts, lengths = _runs(omega, period)
        T = period.reshape(-1)[starts]
    else:
        starts, lengths = _runs(omega)
    return tuple(  # type: ignore[return-value]
        np.repeat(ratio, lengths).reshape(omega.shape)
        for ratio in ct_ratios(omega.reshape(-1)[starts], T)  # type: ignore[arg-type]
    )


def _runs(*arrays: Array) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Starts and lengths of the runs of the flattened ``arrays`` (float64, one shape) along
    which every array holds one value: the same bit pattern, so ``-0.0`` and ``0.0`` differ and
    an elementwise function computed once per run is the function of every entry."""
    size = arrays[0].size
    first = np.zeros(size, dtype=bool)
    first[:1] = True
    for a in arrays:
        bits = np.ascontiguousarray(a, dtype=np.float64).reshape(-1).view(np.int64)
        first[1:] |= bits[1:] != bits[:-1]
    starts = np.flatnonzero(first)
    return starts, np.diff(starts, append=size)


def generate_truth(
    scenarios: Sequence[Scenario], rngs: Sequence[np.random.Generator] | None = None
) -> Truth:
    """Simulate the true trajectories of several scenarios at once (batched over runs).

    A step with turn rate ``omega`` is exact circular motion ``x_k = F_CT(omega) x_{k-1}`` (computed
    in closed form over all steps when there is no acceleration and no truth noise); a step
    with tangential acceleration ``a`` moves ``p += v T + a u T^2 / 2``, ``v += a u T`` with
    ``u = v / |v|``. Truth noise, if the scenario has ``truth_q``, is ``N(0, diag(truth_q))`` drawn
    from that run's generator after each step.

    Args:
        scenarios: N scenarios with the same horizon and sampling period.
        rngs: one generator per scenario; needed only when a scenario has truth noise.

    Returns:
        The batched :class:`Truth`.
    """
    if len(scenarios) == 0:
        raise ConfigError("generate_truth needs at least one scenario")
    K, T = scenarios[0].horizon, scenarios[0].T
    for s in scenarios:
        if s.horizon != K or s.T != T:
            raise ConfigError("all scenarios of one batch must share horizon and T")
    noisy = [s.truth_q is not None for s in scenarios]
    if any(noisy) and (rngs is None or len(rngs) != len(scenarios)):
        raise ConfigError("scenarios with truth_q need one generator per scenario (rngs)")
    N = len(scenarios)
    profiles = [s.profile() for s in scenarios]
    omega = np.stack([p[0] for p in profiles])
    accel = np.stack([p[1] for p in profiles])
    p0 = np.array([s.position for s in scenarios])
    v0 = np.array([s.velocity for s in scenarios])
    if not any(noisy) and not np.any(accel != 0.0):
        states = _constant_speed_truth(p0, v0, omega, T)
        return Truth(states=states, turn_rate=omega, accel=accel, T=T)
    states = np.empty((N, K + 1, 4))
    states[:, 0, :2] = p0
    states[:, 0, 2:] = v0
    F = ct_transition(omega, T)  # (N, K, 4, 4)
    for k in range(K):
        x = np.einsum("nij,nj->ni", F[:, k], states[:, k])
        a = accel[:, k]
        if np.any(a != 0.0):
            v = states[:, k, 2:]
            speed = np.linalg.norm(v, axis=-1, keepdims=True)
            u = np.divide(v, speed, out=np.zeros_like(v), where=speed > 0)
            av = a[:, None] * u
            x[:, :2] += 0.5 * T * T * av
            x[:, 2:] += T * av
        states[:, k + 1] = x
        for n in np.flatnonzero(noisy):
            q = np.asarray(scenarios[n].truth_q)
            states[n, k + 1] += np.sqrt(q) * rngs[n].standard_normal(4)  # type: ignore[index]
    return Truth(states=states, turn_rate=omega, accel=accel, T=T)
