"""The randomized family's batched draws and the closed-form truth hold their references bit
for bit.

``RandomFamily`` draws each run's random numbers from its own generator and computes the rest
(signed rates, segment durations) for all runs at once. The reference below is the per-run code
it replaced, with ``Generator.choice`` called as before: the same generators must give the same
scenarios, truth and generator states, for any family and any number of runs. The truth's closed
form (``_constant_speed_truth``) is held against the whole-array code it replaced, which computed
the turn ratios at every step and stacked its temporaries, and ``true_model_index`` (computed once
per run of equal motion) against its per-step computation.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from imm_gym import MotionModel, RandomFamily, Scenario, Segment, generate_truth, paper_bank
from imm_gym.scenarios.segments import (
    Truth,
    _constant_speed_truth,
    _model_index,
    true_model_index,
)
from imm_gym.tracking.hetero import HeteroBank
from imm_gym.tracking.models import ct_ratios


def _reference_composition(
    rng: np.random.Generator, total: int, parts: int, minimum: int
) -> np.ndarray:
    extra = total - parts * minimum
    bars = np.sort(rng.choice(extra + parts - 1, size=parts - 1, replace=False))
    edges = np.concatenate([[-1], bars, [extra + parts - 1]])
    return np.diff(edges) - 1 + minimum


def _reference_sample(fam: RandomFamily, rng: np.random.Generator) -> Scenario:
    """One run's scenario, drawn run by run with ``Generator.choice`` (the former code)."""
    rng_range = rng.uniform(*fam.range_m)
    bearing = rng.uniform(-math.pi, math.pi)
    speed = rng.uniform(*fam.speed)
    heading = rng.uniform(-math.pi, math.pi)
    n = int(rng.integers(fam.n_segments[0], fam.n_segments[1] + 1))
    durations = _reference_composition(rng, fam.horizon, n, fam.min_duration)
    rates = rng.uniform(*fam.turn_rate_deg, size=n) * rng.choice([-1.0, 1.0], size=n)
    rates[0::2] = 0.0
    position = (rng_range * math.cos(bearing), rng_range * math.sin(bearing))
    velocity = (speed * math.cos(heading), speed * math.sin(heading))
    segments = tuple(Segment(int(d), float(w)) for d, w in zip(durations, rates, strict=True))
    return Scenario(segments, position, velocity, T=fam.T, truth_q=fam.truth_q)


def _reference_constant_speed_truth(
    p0: np.ndarray, v0: np.ndarray, omega: np.ndarray, T: float
) -> np.ndarray:
    """The closed-form truth as first written (ratios at every step, stacked temporaries)."""
    N, K = omega.shape
    wt = omega * T
    heading = np.concatenate([np.zeros((N, 1)), np.cumsum(wt, axis=1)], axis=1)
    c, s = np.cos(heading), np.sin(heading)
    v = np.stack([c * v0[:, :1] - s * v0[:, 1:], s * v0[:, :1] + c * v0[:, 1:]], axis=-1)
    sin_ratio, cos_ratio = ct_ratios(omega, T)
    vx, vy = v[:, :-1, 0], v[:, :-1, 1]
    dp = np.stack([sin_ratio * vx - cos_ratio * vy, cos_ratio * vx + sin_ratio * vy], axis=-1)
    states = np.empty((N, K + 1, 4))
    states[:, :, :2] = p0[:, None, :] + np.concatenate(
        [np.zeros((N, 1, 2)), np.cumsum(dp, axis=1)], axis=1
    )
    states[:, :, 2:] = v
    return states


@st.composite
def families(draw: st.DrawFn) -> RandomFamily:
    n_lo = draw(st.integers(1, 8))
    n_hi = draw(st.integers(n_lo, 12))
    minimum = draw(st.integers(1, 15))
    horizon = draw(st.integers(n_hi * minimum, n_hi * minimum + 200))
    turn_lo = draw(st.sampled_from([0.0, 0.5, 1.0]))
    truth_q = draw(st.sampled_from([None, (1.0, 1.0, 0.1, 0.1)]))
    return RandomFamily(
        horizon=horizon,
        n_segments=(n_lo, n_hi),
        min_duration=minimum,
        turn_rate_deg=(turn_lo, turn_lo + 3.0),
        truth_q=truth_q,
    )


def _states(rngs: list[np.random.Generator]) -> list[dict]:
    return [rng.bit_generator.state for rng in rngs]


@settings(max_examples=60, deadline=None)
@given(fam=families(), runs=st.integers(1, 40), seed=st.integers(0, 2**32))
def test_batched_draws_equal_per_run_reference(fam: RandomFamily, runs: int, seed: int) -> None:
    new = [np.random.default_rng([seed, r]) for r in range(runs)]
    ref = [np.random.default_rng([seed, r]) for r in range(runs)]
    truth = fam.truth(new)
    scenarios = [_reference_sample(fam, rng) for rng in ref]
    expected = generate_truth(scenarios, ref)
    if fam.truth_q is None:
        profiles = [sc.profile()[0] for sc in scenarios]
        p0 = np.array([sc.position for sc in scenarios])
        v0 = np.array([sc.velocity for sc in scenarios])
        reference = _reference_constant_speed_truth(p0, v0, np.stack(profiles), fam.T)
        assert truth.states.tobytes() == reference.tobytes()
    assert _states(new) == _states(ref)  # the same draws consumed, and no more
    for name in ("states", "turn_rate", "accel"):
        a, b = getattr(truth, name), getattr(expected, name)
        assert a.dtype == b.dtype and a.shape == b.shape
        assert a.tobytes() == b.tobytes(), name
    again = [np.random.default_rng([seed, r]) for r in range(runs)]
    assert [fam.sample(rng) for rng in again] == scenarios  # sample: the same scenarios


def test_default_family_many_seeds() -> None:
    """The default family over 2,000 runs (every segment count), the environment's case."""
    fam = RandomFamily()
    new = [np.random.default_rng(s) for s in range(2000)]
    ref = [np.random.default_rng(s) for s in range(2000)]
    truth = fam.truth(new)
    scenarios = [_reference_sample(fam, rng) for rng in ref]
    p0 = np.array([sc.position for sc in scenarios])
    v0 = np.array([sc.velocity for sc in scenarios])
    omega = np.stack([sc.profile()[0] for sc in scenarios])
    expected = generate_truth(scenarios)
    assert truth.states.tobytes() == expected.states.tobytes()
    reference = _reference_constant_speed_truth(p0, v0, omega, fam.T)
    assert truth.states.tobytes() == reference.tobytes()
    assert truth.turn_rate.tobytes() == expected.turn_rate.tobytes()
    assert _states(new) == _states(ref)


@settings(max_examples=60, deadline=None)
@given(
    runs=st.integers(1, 12),
    steps=st.integers(1, 60),
    seed=st.integers(0, 2**32),
    T=st.sampled_from([0.1, 1.0, 2.5]),
)
def test_constant_speed_truth_equals_reference(runs: int, steps: int, seed: int, T: float) -> None:
    """Runs of equal rates, rates that differ only in the sign of zero, rates under the series
    threshold, negative zero starts: the same bits as the reference."""
    rng = np.random.default_rng(seed)
    pool = np.array([0.0, -0.0, 1e-9, -1e-9, 1e-7, 0.02, -0.03, 0.05])
    omega = np.repeat(rng.choice(pool, size=(runs, steps)), rng.integers(1, 4, size=steps), axis=1)
    p0 = rng.choice([0.0, -0.0, 3000.0, -4500.5], size=(runs, 2))
    v0 = rng.normal(0.0, 10.0, size=(runs, 2))
    got = _constant_speed_truth(p0, v0, omega, T)
    assert got.tobytes() == _reference_constant_speed_truth(p0, v0, omega, T).tobytes()


BANKS = (
    paper_bank(),
    (MotionModel("ct", 1.0), MotionModel("cv"), MotionModel("ct", 5.0), MotionModel("ct", -2.0),
     MotionModel("ca", q=(0.1,) * 6)),
    (MotionModel("ct", 3.0),),
    HeteroBank(),
)


@settings(max_examples=40, deadline=None)
@given(runs=st.integers(1, 8), steps=st.integers(1, 40), seed=st.integers(0, 2**32))
def test_true_model_index_equals_per_step(runs: int, steps: int, seed: int) -> None:
    """Computed once per run of equal (turn rate, acceleration): the per-step answer everywhere,
    runs that change only the acceleration or the sign of a zero rate included."""
    rng = np.random.default_rng(seed)
    rates = np.radians([0.0, -0.0, 0.5, 1.5, 4.0, -1.0, -3.0])
    omega = np.repeat(rng.choice(rates, size=(runs, steps)), rng.integers(1, 4, size=steps), axis=1)
    accel = np.where(rng.random(omega.shape) < 0.2, rng.choice([0.5, -1.0], omega.shape), 0.0)
    truth = Truth(np.zeros((*omega.shape[:1], omega.shape[1] + 1, 4)), omega, accel)
    for bank in BANKS:
        assert np.array_equal(true_model_index(truth, bank), _model_index(omega, accel, bank))
