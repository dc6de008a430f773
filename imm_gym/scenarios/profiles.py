r"""The scenarios of seeds 002 and 003: per-step turn-rate / acceleration profiles, exact truth.

A profile gives, for every step k, the turn rate ``omega_k`` (rad/s) and the tangential
acceleration ``a_k`` (m/s²) held during that step. The truth is the exact CTRA motion
(:func:`imm_gym.tracking.conversions.ctra_transition`, closed form, no integration error), so a step
can turn and accelerate at once; states are reported as ``[x, y, vx, vy]`` (:class:`Truth`), with
the heading ``psi`` (yaw, zero sideslip) kept for the yaw metrics (``Truth.heading``).

**Seed 002** (vehicle trajectory from MATLAB's Driving Scenario Designer; the data set is not
published, so this family is "like theirs"): straight segments, a gentle S-curve and two sharp 90°
turns, with the speed falling before each curve and rising after it (:class:`DrivingFamily`);
``T = 0.1 s``; a position+velocity sensor with ``sigma_p = 0.5`` m, ``sigma_v = 0.5`` m/s
(Table I).

**Seed 003** §4 (43 s at ``T = 0.1 s``, position+velocity measurements): a straight leg, a
constant Cartesian acceleration, a uniform turn, a straight acceleration, a straight leg. The
extraction lost the initial state, the turn rate, the last acceleration and most noise values;
the values filled in here are marked "filled" in :func:`maneuver_profile`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from imm_gym.scenarios.segments import Truth
from imm_gym.tracking.conversions import ctra_transition
from imm_gym.validation import ConfigError, check_int, check_range, check_sequence, store

Array = NDArray[np.float64]


def profile_truth(
    omega: Array,
    accel: Array,
    position: Array,
    speed: Array,
    heading: Array,
    T: float,
    cart_accel: Array | None = None,
) -> Truth:
    """Exact truth from per-step profiles, batched over runs, with the heading ``psi``.

    A step is either CTRA (turn rate ``omega`` and tangential acceleration ``accel`` held, the
    closed form of :func:`~imm_gym.tracking.conversions.ctra_transition`) or, where ``cart_accel``
    is non-zero, a constant **Cartesian** acceleration (``p += v T + a T²/2``, ``v += a T``, exact
    too). A Cartesian step's ``omega`` and ``accel`` must be 0; the :class:`Truth` records for it
    the step's mean turn rate ``Δψ/T`` and mean tangential acceleration ``Δ|v|/T``.

    Args:
        omega, accel: ``(N, K)`` turn rate (rad/s) and tangential acceleration (m/s²) of step k.
        position: ``(N, 2)``; speed: ``(N,)`` (m/s); heading: ``(N,)`` (rad) at ``t = 0``.
        T: sampling period (s).
        cart_accel: optional ``(N, K, 2)`` world-frame acceleration (m/s²) of step k.

    Raises:
        ConfigError: ``T <= 0``, a NaN or infinite entry (naming the array), mismatched shapes,
            a Cartesian step that also turns or accelerates, or a speed driven below 0.
    """
    T = check_range("T", T, 0.0, lo_open=True)
    omega, accel = _finite("omega", omega, 2), _finite("accel", accel, 2)
    position, speed = _finite("position", position), _finite("speed", speed)
    heading = _finite("heading", heading)
    if omega.shape != accel.shape:
        raise ConfigError(f"omega and accel profiles differ in shape: {omega.shape}, {accel.shape}")
    N, K = omega.shape
    if cart_accel is None:
        cart_accel = np.zeros((N, K, 2))
    cart_accel = _finite("cart_accel", cart_accel).reshape(-1, K, 2)
    if cart_accel.shape != (N, K, 2):
        raise ConfigError(f"cart_accel has shape {cart_accel.shape}, expected {(N, K, 2)}")
    cartesian = np.any(cart_accel != 0.0, axis=-1)
    if np.any(cartesian & ((omega != 0.0) | (accel != 0.0))):
        raise ConfigError("a step with a Cartesian acceleration must have omega = accel = 0")
    x = np.zeros((N, 6))
    x[:, :2] = position
    x[:, 2] = speed
    x[:, 3] = heading
    states = np.empty((N, K + 1, 6))
    states[:, 0] = x
    for k in range(K):
        x = x.copy()
        x[:, 4], x[:, 5] = omega[:, k], accel[:, k]
        cart = cartesian[:, k]
        x_ctra, _ = ctra_transition(x, T)
        if np.any(cart):
            a = cart_accel[cart, k]
            v0 = x[cart, 2:3] * np.stack([np.cos(x[cart, 3]), np.sin(x[cart, 3])], axis=-1)
            v1 = v0 + a * T
            x_ctra[cart, :2] = x[cart, :2] + v0 * T + 0.5 * a * T * T
            x_ctra[cart, 2] = np.hypot(v1[:, 0], v1[:, 1])
            turn = np.arctan2(v1[:, 1], v1[:, 0]) - x[cart, 3]
            x_ctra[cart, 3] = x[cart, 3] + (turn + math.pi) % (2 * math.pi) - math.pi
        x = x_ctra
        states[:, k + 1] = x
    if np.any(states[..., 2] < 0):
        raise ConfigError("the acceleration profile drives the speed below 0")
    v, psi = states[..., 2], states[..., 3]
    omega, accel = omega.copy(), accel.copy()
    omega[cartesian] = (np.diff(psi, axis=1) / T)[cartesian]
    accel[cartesian] = (np.diff(v, axis=1) / T)[cartesian]
    cart = np.stack([states[..., 0], states[..., 1], v * np.cos(psi), v * np.sin(psi)], axis=-1)
    return Truth(cart, omega, accel, T, heading=psi)


def _finite(name: str, value: Array, ndim: int = 0) -> Array:
    """``value`` as a float array of at least ``ndim`` dimensions, every entry finite, else
    :class:`ConfigError` naming ``name`` and the first bad entry."""
    array = np.asarray(value, dtype=np.float64)
    array = np.atleast_2d(array) if ndim == 2 else array
    bad = np.argwhere(~np.isfinite(array))
    if bad.size:
        where = tuple(int(i) for i in bad[0])
        raise ConfigError(
            f"{name} must be finite everywhere, got {array[where]} at index {list(where)}"
        )
    return array


def _check_ranges(family: object, names: tuple[str, ...]) -> None:
    """Check and store the ``(low, high)`` fields ``names`` of ``family``: ``0 < low <= high``."""
    for name in names:
        lo, hi = check_sequence(f"family.{name} (low, high)", getattr(family, name), 2)
        lo = check_range(f"family.{name}[0]", lo, 0.0, lo_open=True)
        store(family, name, (lo, check_range(f"family.{name}[1]", hi, lo)))


#: The driving profile's segment durations (s), :meth:`DrivingFamily.segments`.
DRIVING_DURATIONS = (8.0, 4.0, 5.0, 5.0, 3.0, 4.0, 3.0, 4.0, 4.0, 4.0, 5.0, 4.0, 4.0, 4.0, 6.0)

#: Seed 003's segment durations (s): 0-10, 10-14, 14-34, 34-38 and 38-43 s.
MANEUVER_DURATIONS = (10.0, 4.0, 20.0, 4.0, 5.0)


@dataclass(frozen=True)
class DrivingFamily:
    """Seed-002-like trajectories (T = 0.1 s, 67 s): straight, gentle S-curve, two sharp 90° turns.

    Segments (seconds): cruise 8; slow down 4; S-curve left 5 + right 5 at ``s_rate``; straight 3;
    speed up 4; straight 3; brake 4 to ``turn_speed``; 90° turn in 4 s (sign random); speed up 4;
    straight 5; brake 4; 90° turn in 4 s (sign random); speed up 4; straight 6. Per run: start
    ``U(-50, 50)`` m per axis, heading ``U(-pi, pi)``, cruise speed ``U(cruise)``, curve speed
    ``U(curve)`` (S-curve), turn speed ``U(turn)``, S-curve rate ``U(s_rate)`` rad/s.

    Attributes:
        cruise, curve, turn: speed ranges (m/s), each ``0 < low <= high``; the curve and turn
            speeds are slower than any cruise speed (``curve[1] <= cruise[0]``,
            ``turn[1] <= cruise[0]``), so the target slows down before the curves.
        s_rate: S-curve turn-rate range (rad/s).
        T: sampling period (s).
    """

    cruise: tuple[float, float] = (12.0, 16.0)
    curve: tuple[float, float] = (9.0, 11.0)
    turn: tuple[float, float] = (5.0, 7.0)
    s_rate: tuple[float, float] = (0.1, 0.2)
    T: float = 0.1

    def __post_init__(self) -> None:
        _check_ranges(self, ("cruise", "curve", "turn", "s_rate"))
        self._check_slower_than_cruise()
        store(self, "T", check_range("family.T", self.T, 0.0, 0.5, lo_open=True))
        check_divides("family.T", self.T, DRIVING_DURATIONS)

    def _check_slower_than_cruise(self) -> None:
        """``curve[1] <= cruise[0]`` and ``turn[1] <= cruise[0]``: the target brakes before the
        curves and speeds up after them (accelerations ``(curve - cruise) / 4 s <= 0``)."""
        for name in ("curve", "turn"):
            lo, hi = getattr(self, name)
            if hi > self.cruise[0]:
                raise ConfigError(
                    f"family.{name}[1] must be <= family.cruise[0] = {self.cruise[0]} m/s (the "
                    f"target slows down from cruise to the {name} speed), got {name} = {(lo, hi)}"
                )

    def segments(self, rng: np.random.Generator) -> tuple[list[tuple[float, float, float]], float]:
        """``[(duration s, omega, accel)]`` and the initial speed of one draw."""
        cruise, curve, turn = (rng.uniform(*getattr(self, n)) for n in ("cruise", "curve", "turn"))
        s = rng.uniform(*self.s_rate)
        signs = rng.choice([-1.0, 1.0], size=2)
        quarter = math.pi / 2 / 4.0
        rates = [
            (0.0, 0.0),
            (0.0, (curve - cruise) / 4.0),
            (s, 0.0),
            (-s, 0.0),
            (0.0, 0.0),
            (0.0, (cruise - curve) / 4.0),
            (0.0, 0.0),
            (0.0, (turn - cruise) / 4.0),
            (signs[0] * quarter, 0.0),
            (0.0, (cruise - turn) / 4.0),
            (0.0, 0.0),
            (0.0, (turn - cruise) / 4.0),
            (signs[1] * quarter, 0.0),
            (0.0, (cruise - turn) / 4.0),
            (0.0, 0.0),
        ]
        return [(d, w, a) for d, (w, a) in zip(DRIVING_DURATIONS, rates, strict=True)], cruise

    @property
    def horizon(self) -> int:
        """Steps K of a run: the profile's duration over ``T``."""
        return round(sum(DRIVING_DURATIONS) / self.T)

    def truth(self, rngs: Sequence[np.random.Generator]) -> Truth:
        """The truth of one run per generator (:class:`~imm_gym.scenarios.segments.TruthSource`)."""
        if not rngs:
            raise ConfigError("DrivingFamily.truth needs at least one generator")
        omegas, accels, pos, speed, heading = [], [], [], [], []
        for rng in rngs:
            pos.append(rng.uniform(-50.0, 50.0, size=2))
            heading.append(rng.uniform(-math.pi, math.pi))
            segs, v0 = self.segments(rng)
            speed.append(v0)
            w, a = _expand(segs, self.T)
            omegas.append(w)
            accels.append(a)
        return profile_truth(
            np.stack(omegas),
            np.stack(accels),
            np.array(pos),
            np.array(speed),
            np.array(heading),
            self.T,
        )


def check_divides(name: str, T: float, durations: Sequence[float]) -> None:
    """Raise :class:`ConfigError` naming ``name`` unless every duration (s) is a whole number of
    sampling periods ``T``: a profile's turns and accelerations are timed in seconds."""
    for d in durations:
        if not math.isclose(round(d / T) * T, d):
            raise ConfigError(
                f"{name} must divide every segment's duration ({sorted(set(durations))} s); "
                f"{d} s is not a multiple of {T} s"
            )


def _expand(segments: list[tuple[float, float, float]], T: float) -> tuple[Array, Array]:
    """Per-step turn rates and accelerations of ``[(duration s, omega, accel)]`` at ``T``
    (durations multiples of ``T``, :func:`check_divides`)."""
    steps = [round(d / T) for d, _, _ in segments]
    w = np.concatenate([np.full(n, s[1]) for n, s in zip(steps, segments, strict=True)])
    a = np.concatenate([np.full(n, s[2]) for n, s in zip(steps, segments, strict=True)])
    return w, a


#: Seed 003's 14-34 s turn rate (filled): the heading turns from -45° (``v = (1, -1)`` m/s) to
#: north (``v = (0, 8)`` m/s at 38 s after a straight acceleration), 135° in 20 s.
MANEUVER_TURN_RATE = 3.0 * math.pi / 4.0 / 20.0


class ManeuverProfile(NamedTuple):
    """Per-step profile of one seed-003 trajectory (see :func:`profile_truth`)."""

    omega: Array
    accel: Array
    cart_accel: Array
    position: tuple[float, float]
    speed: float
    heading: float


def maneuver_profile(T: float = 0.1) -> ManeuverProfile:
    """Seed 003 §4: 43 s at ``T = 0.1`` s, one deterministic trajectory.

    From the source (every value it kept):

    * 0-10 s straight, ``v = (0, -5)`` m/s;
    * 10-14 s "uniformly accelerated turning motion": constant Cartesian acceleration
      ``(0.25, 1)`` m/s², ending at ``v = (1, -1)`` m/s (|v| 5 -> 1.41 m/s, heading -90° -> -45°);
    * 14-34 s a uniform turn (constant speed 1.41 m/s, constant rate);
    * 34-38 s uniform acceleration ending at ``v = (0, 8)`` m/s;
    * 38-43 s straight (so at ``v = (0, 8)`` m/s).

    **Filled** (lost in extraction): the start position (0, 0) m; the 14-34 s turn rate,
    :data:`MANEUVER_TURN_RATE` = 3π/80 ≈ 0.1178 rad/s (left), so that the heading is north at 34 s
    and the 34-38 s acceleration is straight, (0, (8 - √2)/4) ≈ (0, 1.646) m/s² (its value was
    lost too: this is the one that reaches ``v = (0, 8)`` from the turn's end along the heading).

    Returns:
        :class:`ManeuverProfile`: ``omega (K,)``, ``accel (K,)``, ``cart_accel (K, 2)``, start
        position, speed, heading.
    """
    check_range("T", T, 0.0, 1.0, lo_open=True)
    check_divides("T", T, MANEUVER_DURATIONS)
    heading0 = -math.pi / 2  # v = (0, -5): heading south
    speed0 = 5.0
    v14 = math.hypot(1.0, -1.0)  # |(1, -1)|, the speed of the uniform turn
    rates = [
        (0.0, 0.0),
        (0.0, 0.0),  # constant Cartesian acceleration, below
        (MANEUVER_TURN_RATE, 0.0),
        (0.0, (8.0 - v14) / 4.0),
        (0.0, 0.0),
    ]
    segs = [(d, w, a) for d, (w, a) in zip(MANEUVER_DURATIONS, rates, strict=True)]
    w, a = _expand(segs, T)
    cart = np.zeros((w.size, 2))
    k10, k14 = round(10.0 / T), round(14.0 / T)
    cart[k10:k14] = (0.25, 1.0)
    return ManeuverProfile(w, a, cart, (0.0, 0.0), speed0, heading0)


def maneuver_truth(runs: int, T: float = 0.1) -> Truth:
    """``runs`` copies of the seed-003 trajectory (the noise makes the runs differ)."""
    check_int("runs", runs, 1)
    p = maneuver_profile(T)
    return profile_truth(
        np.tile(p.omega, (runs, 1)),
        np.tile(p.accel, (runs, 1)),
        np.tile(p.position, (runs, 1)),
        np.full(runs, p.speed),
        np.full(runs, p.heading),
        T,
        np.tile(p.cart_accel, (runs, 1, 1)),
    )


@dataclass(frozen=True)
class ManeuverFamily:
    """Trajectories around seed 003's (``maneuver_profile``), rotated to a random heading.

    Per run: the turn rate scaled by ``U(rate_scale)`` **keeping the source's (left) turn
    direction** — the bank has a single left-turning CT model —, the accelerations (the 10-14 s
    Cartesian one, rotated with the heading, and the 34-38 s tangential one) scaled by
    ``U(accel_scale)``, initial speed ``U(speed)``, heading ``U(-pi, pi)``, start ``U(-20, 20)`` m
    per axis.
    """

    rate_scale: tuple[float, float] = (0.6, 1.4)
    accel_scale: tuple[float, float] = (0.5, 1.5)
    speed: tuple[float, float] = (4.0, 6.0)
    T: float = 0.1

    def __post_init__(self) -> None:
        _check_ranges(self, ("rate_scale", "accel_scale", "speed"))
        store(self, "T", check_range("family.T", self.T, 0.0, 1.0, lo_open=True))
        check_divides("family.T", self.T, MANEUVER_DURATIONS)

    @property
    def horizon(self) -> int:
        """Steps K of a run: the profile's duration over ``T``."""
        return round(sum(MANEUVER_DURATIONS) / self.T)

    def truth(self, rngs: Sequence[np.random.Generator]) -> Truth:
        """The truth of one run per generator (:class:`~imm_gym.scenarios.segments.TruthSource`)."""
        if not rngs:
            raise ConfigError("ManeuverFamily.truth needs at least one generator")
        p = maneuver_profile(self.T)
        w, a, ca, pos, v, psi = [], [], [], [], [], []
        for rng in rngs:
            w.append(p.omega * rng.uniform(*self.rate_scale))
            s = rng.uniform(*self.accel_scale)
            a.append(p.accel * s)
            pos.append(rng.uniform(-20.0, 20.0, size=2))
            v.append(rng.uniform(*self.speed))
            psi.append(rng.uniform(-math.pi, math.pi))
            c, sn = math.cos(psi[-1] - p.heading), math.sin(psi[-1] - p.heading)
            ca.append(s * p.cart_accel @ np.array([[c, sn], [-sn, c]]))
        return profile_truth(
            np.stack(w),
            np.stack(a),
            np.array(pos),
            np.array(v),
            np.array(psi),
            self.T,
            np.stack(ca),
        )
