r"""The scenarios of seeds 002 and 003: per-step turn-rate / acceleration profiles, exact truth.

A profile gives, for every step k, the turn rate ``omega_k`` (rad/s) and the tangential
acceleration ``a_k`` (m/s²) held during that step. The truth is the exact CTRA motion
(:func:`imm_gym.conversions.ctra_transition`, closed form, no integration error), so a step can
turn and accelerate at once; states are reported as ``[x, y, vx, vy]`` (:class:`Truth`), with the
heading ``psi`` (yaw, zero sideslip) kept for the yaw metrics.

**Seed 002** (vehicle trajectory from MATLAB's Driving Scenario Designer; the data set is not
published, so this family is "like theirs"): straight segments, a gentle S-curve and two sharp 90°
turns, with the speed falling before each curve and rising after it (:class:`Seed002Family`);
``T = 0.1 s``; a position+velocity sensor with ``sigma_p = 0.5`` m, ``sigma_v = 0.5`` m/s
(Table I).

**Seed 003** §4 (43 s at ``T = 0.1 s``, position+velocity measurements). The extraction lost the
initial state, the turn rates and most noise values; the values filled in here are marked
"filled" in :func:`seed003_profile`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .config import ConfigError, check_int, check_range
from .conversions import ctra_transition
from .scenarios import Truth

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ProfileTruth:
    """Truth of N runs driven by per-step profiles.

    Attributes:
        truth: the :class:`Truth` (states ``(N, K+1, 4)``, ``turn_rate``, ``accel``).
        heading: ``(N, K+1)`` true heading / yaw (rad).
    """

    truth: Truth
    heading: Array


def profile_truth(
    omega: Array, accel: Array, position: Array, speed: Array, heading: Array, T: float
) -> ProfileTruth:
    """Exact CTRA truth from per-step profiles, batched over runs.

    Args:
        omega, accel: ``(N, K)`` turn rate (rad/s) and tangential acceleration (m/s²) of step k.
        position: ``(N, 2)``; speed: ``(N,)`` (m/s); heading: ``(N,)`` (rad) at ``t = 0``.
        T: sampling period (s).
    """
    omega, accel = np.atleast_2d(omega), np.atleast_2d(accel)
    if omega.shape != accel.shape:
        raise ConfigError(f"omega and accel profiles differ in shape: {omega.shape}, {accel.shape}")
    N, K = omega.shape
    x = np.zeros((N, 6))
    x[:, :2] = position
    x[:, 2] = speed
    x[:, 3] = heading
    states = np.empty((N, K + 1, 6))
    states[:, 0] = x
    for k in range(K):
        x = x.copy()
        x[:, 4], x[:, 5] = omega[:, k], accel[:, k]
        x, _ = ctra_transition(x, T)
        states[:, k + 1] = x
    if np.any(states[..., 2] < 0):
        raise ConfigError("the acceleration profile drives the speed below 0")
    v, psi = states[..., 2], states[..., 3]
    cart = np.stack([states[..., 0], states[..., 1], v * np.cos(psi), v * np.sin(psi)], axis=-1)
    return ProfileTruth(Truth(cart, omega.copy(), accel.copy(), T), psi)


@dataclass(frozen=True)
class Seed002Family:
    """Seed-002-like trajectories (T = 0.1 s, 67 s): straight, gentle S-curve, two sharp 90° turns.

    Segments (seconds): cruise 8; slow down 4; S-curve left 5 + right 5 at ``s_rate``; straight 3;
    speed up 4; straight 3; brake 4 to ``turn_speed``; 90° turn in 4 s (sign random); speed up 4;
    straight 5; brake 4; 90° turn in 4 s (sign random); speed up 4; straight 6. Per run: start
    ``U(-50, 50)`` m per axis, heading ``U(-pi, pi)``, cruise speed ``U(cruise)``, curve speed
    ``U(curve)`` (S-curve), turn speed ``U(turn)``, S-curve rate ``U(s_rate)`` rad/s.

    Attributes:
        cruise, curve, turn: speed ranges (m/s); s_rate: S-curve turn-rate range (rad/s).
        T: sampling period (s).
    """

    cruise: tuple[float, float] = (12.0, 16.0)
    curve: tuple[float, float] = (9.0, 11.0)
    turn: tuple[float, float] = (5.0, 7.0)
    s_rate: tuple[float, float] = (0.1, 0.2)
    T: float = 0.1

    def __post_init__(self) -> None:
        for name in ("cruise", "curve", "turn", "s_rate"):
            lo, hi = getattr(self, name)
            check_range(f"family.{name}[0]", lo, 0.0, lo_open=True)
            check_range(f"family.{name}[1]", hi, lo)
        check_range("family.T", self.T, 0.0, 0.5, lo_open=True)

    def segments(self, rng: np.random.Generator) -> tuple[list[tuple[float, float, float]], float]:
        """``[(duration s, omega, accel)]`` and the initial speed of one draw."""
        cruise, curve, turn = (rng.uniform(*getattr(self, n)) for n in ("cruise", "curve", "turn"))
        s = rng.uniform(*self.s_rate)
        signs = rng.choice([-1.0, 1.0], size=2)
        quarter = math.pi / 2 / 4.0
        return [
            (8.0, 0.0, 0.0),
            (4.0, 0.0, (curve - cruise) / 4.0),
            (5.0, s, 0.0),
            (5.0, -s, 0.0),
            (3.0, 0.0, 0.0),
            (4.0, 0.0, (cruise - curve) / 4.0),
            (3.0, 0.0, 0.0),
            (4.0, 0.0, (turn - cruise) / 4.0),
            (4.0, signs[0] * quarter, 0.0),
            (4.0, 0.0, (cruise - turn) / 4.0),
            (5.0, 0.0, 0.0),
            (4.0, 0.0, (turn - cruise) / 4.0),
            (4.0, signs[1] * quarter, 0.0),
            (4.0, 0.0, (cruise - turn) / 4.0),
            (6.0, 0.0, 0.0),
        ], cruise

    def sample(self, rngs: list[np.random.Generator]) -> ProfileTruth:
        """The truth of one run per generator."""
        if not rngs:
            raise ConfigError("Seed002Family.sample needs at least one generator")
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


def _expand(segments: list[tuple[float, float, float]], T: float) -> tuple[Array, Array]:
    steps = [round(d / T) for d, _, _ in segments]
    w = np.concatenate([np.full(n, s[1]) for n, s in zip(steps, segments, strict=True)])
    a = np.concatenate([np.full(n, s[2]) for n, s in zip(steps, segments, strict=True)])
    return w, a


def seed003_profile(T: float = 0.1) -> tuple[Array, Array, tuple[float, float], float, float]:
    """Seed 003 §4: 43 s at ``T = 0.1`` s, one deterministic trajectory.

    What the extraction kept: straight 0-10 s with ``v = (0, -5)`` m/s; 10-14 s "uniformly
    accelerated turning motion" with a constant Cartesian acceleration ``(0.25, 1)`` m/s², ending
    at ``v = (1, -1)`` m/s; 14-34 s a uniform turn (rates lost); 34-38 s uniform acceleration
    ending at ``v = (0, 8)`` m/s; straight to 43 s. Here: start at (0, 0) m (filled); 10-14 s a
    CTRA turn at +0.2 rad/s with 0.5 m/s² — **not** the source's segment: it ends at the same
    heading (-44° vs -45°) but at 7 m/s instead of the source's 1.41 m/s (``|(1, -1)|``), so the
    rest is flown ~5x faster than in seed 003; 14-34 s turn at +0.117 rad/s (2.34 rad, so that the
    heading reaches north at 34 s; the source's headings give 0.118 rad/s); 34-38 s acceleration
    0.25 m/s² along the heading (7 -> 8 m/s; the source's is ~1.65 m/s², 1.41 -> 8 m/s);
    38-43 s straight. The README's seed-003 figures are for this profile.

    Returns:
        ``omega (K,)``, ``accel (K,)``, start position, speed, heading.
    """
    check_range("T", T, 0.0, 1.0, lo_open=True)
    heading0 = -math.pi / 2  # v = (0, -5): heading south
    turn1 = 0.2
    # heading after the first turn: -pi/2 + 0.8; the uniform turn brings it to +pi/2 at 34 s
    turn2 = (math.pi / 2 - (heading0 + 4.0 * turn1)) / 20.0
    segs = [
        (10.0, 0.0, 0.0),
        (4.0, turn1, 0.5),
        (20.0, turn2, 0.0),
        (4.0, 0.0, 0.25),
        (5.0, 0.0, 0.0),
    ]
    w, a = _expand(segs, T)
    return w, a, (0.0, 0.0), 5.0, heading0


def seed003_truth(runs: int, T: float = 0.1) -> ProfileTruth:
    """``runs`` copies of the seed-003 trajectory (the noise makes the runs differ)."""
    check_int("runs", runs, 1)
    w, a, pos, v, psi = seed003_profile(T)
    return profile_truth(
        np.tile(w, (runs, 1)),
        np.tile(a, (runs, 1)),
        np.tile(pos, (runs, 1)),
        np.full(runs, v),
        np.full(runs, psi),
        T,
    )
