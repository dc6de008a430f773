"""Tests of imm_gym.scenarios.segments: the paper scenario, the random family, batched truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym import (
    ConfigError,
    RandomFamily,
    Scenario,
    Segment,
    ct_transition,
    generate_truth,
    paper_scenario,
)

TURN_A = np.array([4130.0, 5220.0])
TURN_B = np.array([5345.0, 5310.0])


# --------------------------------------------------------------------------- paper scenario


def test_paper_scenario_table() -> None:
    sc = paper_scenario()
    assert sc.horizon == 150
    assert sc.position == (3000.0, 4500.0)
    assert sc.velocity == (20.0, 15.0)
    assert sc.T == 1.0
    assert sc.truth_q is None
    table = [(s.duration, s.turn_rate_deg, s.motion) for s in sc.segments]
    assert table == [
        (40, 0.0, "straight"),
        (30, -1.2, "turn"),
        (20, 0.0, "straight"),
        (25, 1.8, "turn"),
        (35, 0.0, "straight"),
    ]
    omega, accel = sc.profile()
    assert omega.shape == accel.shape == (150,)
    np.testing.assert_array_equal(accel, 0.0)
    # steps are 1-based in the table (1-40 straight, 41-70 turn, ...), 0-based here
    np.testing.assert_array_equal(omega[:40], 0.0)
    np.testing.assert_allclose(omega[40:70], math.radians(-1.2))
    np.testing.assert_array_equal(omega[70:90], 0.0)
    np.testing.assert_allclose(omega[90:115], math.radians(1.8))
    np.testing.assert_array_equal(omega[115:], 0.0)


def test_paper_truth_passes_turn_points() -> None:
    truth = generate_truth([paper_scenario()])
    assert truth.states.shape == (1, 151, 4)
    assert truth.turn_rate.shape == (1, 150)
    assert truth.horizon == 150
    assert truth.n_runs == 1
    p = truth.states[0, :, :2]
    np.testing.assert_array_equal(p[0], [3000.0, 4500.0])
    assert np.linalg.norm(p - TURN_A, axis=1).min() < 60.0
    assert np.linalg.norm(p - TURN_B, axis=1).min() < 120.0


def test_paper_truth_straight_then_turns() -> None:
    truth = generate_truth([paper_scenario()])
    s = truth.states[0]
    # first leg straight: x_k = x_0 + k v_0
    k = np.arange(41)
    np.testing.assert_allclose(s[:41, :2], [3000.0, 4500.0] + k[:, None] * [20.0, 15.0])
    heading = np.unwrap(np.arctan2(s[:, 3], s[:, 2]))
    # -1.2 deg/s for 30 s turns clockwise by 36 deg, +1.8 deg/s for 25 s back by 45 deg
    assert heading[70] - heading[40] == pytest.approx(math.radians(-36.0), abs=1e-9)
    assert heading[115] - heading[90] == pytest.approx(math.radians(45.0), abs=1e-9)
    assert heading[150] - heading[115] == pytest.approx(0.0, abs=1e-12)


def test_paper_truth_constant_speed() -> None:
    speed = np.linalg.norm(generate_truth([paper_scenario()]).states[0, :, 2:], axis=1)
    np.testing.assert_allclose(speed, 25.0, rtol=1e-12)


@pytest.mark.parametrize("T", [0.5, 1.0, 2.5])
def test_truth_with_tangential_acceleration(T: float) -> None:
    """Along the heading u from speed v0 = 5 m/s at a = 2 m/s² for 10 steps of T, the closed
    form: p(t) = (v0 t + a t²/2) u and |v(t)| = v0 + a t at t = k T; then straight at
    v0 + 10 a T."""
    sc = Scenario(
        (Segment(10, accel=2.0), Segment(5)), position=(0.0, 0.0), velocity=(3.0, 4.0), T=T
    )
    s = generate_truth([sc]).states[0]
    u = np.array([0.6, 0.8])
    t = np.arange(11) * T
    np.testing.assert_allclose(s[:11, :2], (5.0 * t + t**2)[:, None] * u, atol=1e-10)
    np.testing.assert_allclose(np.linalg.norm(s[:, 2:], axis=1)[:11], 5.0 + 2.0 * t)
    np.testing.assert_allclose(np.linalg.norm(s[11:, 2:], axis=1), 5.0 + 20.0 * T)
    end = 5.0 + 20.0 * T
    t_after = np.arange(1, 6) * T
    np.testing.assert_allclose(
        s[11:, :2], (5.0 * 10 * T + (10 * T) ** 2 + end * t_after)[:, None] * u, atol=1e-9
    )


# --------------------------------------------------------------------------- random family


def _check_family_sample(fam: RandomFamily, sc: Scenario) -> None:
    rng_m = math.hypot(*sc.position)
    assert fam.range_m[0] <= rng_m <= fam.range_m[1]
    speed = math.hypot(*sc.velocity)
    assert fam.speed[0] <= speed <= fam.speed[1]
    assert fam.n_segments[0] <= len(sc.segments) <= fam.n_segments[1]
    durations = [s.duration for s in sc.segments]
    assert all(d >= fam.min_duration for d in durations)
    assert sum(durations) == fam.horizon == sc.horizon
    for i, seg in enumerate(sc.segments):
        if i % 2 == 0:
            assert seg.turn_rate_deg == 0.0
            assert seg.motion == "straight"
        else:
            assert fam.turn_rate_deg[0] <= abs(seg.turn_rate_deg) <= fam.turn_rate_deg[1]
        assert seg.accel == 0.0


def test_random_family_bounds() -> None:
    fam = RandomFamily()
    rng = np.random.default_rng(2024)
    samples = [fam.sample(rng) for _ in range(400)]
    for sc in samples:
        _check_family_sample(fam, sc)
    # the draws actually cover the family
    assert {len(sc.segments) for sc in samples} == {3, 4, 5, 6}
    rates = np.array([s.turn_rate_deg for sc in samples for s in sc.segments[1::2]])
    assert (rates > 0).any() and (rates < 0).any()
    assert np.abs(rates).min() < 0.7 and np.abs(rates).max() > 2.8
    bearings = np.array([math.atan2(sc.position[1], sc.position[0]) for sc in samples])
    assert bearings.min() < -2.5 and bearings.max() > 2.5
    ranges = np.array([math.hypot(*sc.position) for sc in samples])
    assert ranges.min() < 3300 and ranges.max() > 7700


@pytest.mark.parametrize(
    "fam",
    [
        RandomFamily(horizon=60, n_segments=(6, 6), min_duration=10),  # tight: all durations 10
        RandomFamily(horizon=300, n_segments=(1, 2), min_duration=25, speed=(1.0, 2.0)),
        RandomFamily(horizon=10000, n_segments=(50, 200), min_duration=10),
    ],
)
def test_random_family_custom_bounds(fam: RandomFamily) -> None:
    rng = np.random.default_rng(11)
    for _ in range(30):
        _check_family_sample(fam, fam.sample(rng))


def test_random_family_same_seed_same_scenario() -> None:
    fam = RandomFamily()
    a = [fam.sample(np.random.default_rng(s)) for s in range(5)]
    b = [fam.sample(np.random.default_rng(s)) for s in range(5)]
    assert a == b
    assert len(set(a)) == 5  # different seeds, different scenarios


def test_generate_truth_batched_equals_single() -> None:
    fam = RandomFamily()
    rng = np.random.default_rng(3)
    scenarios = [fam.sample(rng) for _ in range(6)] + [paper_scenario()]
    batched = generate_truth(scenarios)
    assert batched.states.shape == (7, 151, 4)
    for n, sc in enumerate(scenarios):
        alone = generate_truth([sc])
        np.testing.assert_allclose(batched.states[n], alone.states[0], rtol=1e-13, atol=1e-9)
        np.testing.assert_array_equal(batched.turn_rate[n], alone.turn_rate[0])
        np.testing.assert_array_equal(batched.accel[n], alone.accel[0])


@pytest.mark.parametrize(
    "fam", [RandomFamily(), RandomFamily(horizon=60, n_segments=(1, 4), T=2.5, speed=(50, 300))]
)
def test_family_truth_equals_the_truth_of_its_samples(fam: RandomFamily) -> None:
    # the batch's arrays are built from the draws directly: the same numbers, bit for bit
    truth = fam.truth([np.random.default_rng(s) for s in range(9)])
    ref = generate_truth([fam.sample(np.random.default_rng(s)) for s in range(9)])
    for name in ("states", "turn_rate", "accel"):
        np.testing.assert_array_equal(getattr(truth, name), getattr(ref, name), name)
    assert truth.T == ref.T == fam.T


def test_a_noisy_family_cannot_draw_noise_free_varied_runs() -> None:
    """``varied_truth`` draws noise-free runs: a family with truth noise is refused, not flown
    without its noise."""
    family = RandomFamily(truth_q=(1.0, 1.0, 0.1, 0.1))
    with pytest.raises(ConfigError, match="truth_q"):
        family.varied_truth([np.random.default_rng(0)], T=np.array([2.0]))


def test_generate_truth_follows_ct_transition() -> None:
    fam = RandomFamily()
    sc = fam.sample(np.random.default_rng(8))
    tr = generate_truth([sc])
    F = ct_transition(tr.turn_rate[0], 1.0)
    for k in range(sc.horizon):
        np.testing.assert_allclose(tr.states[0, k + 1], F[k] @ tr.states[0, k], atol=1e-9)
    speed = np.linalg.norm(tr.states[0, :, 2:], axis=1)
    np.testing.assert_allclose(speed, math.hypot(*sc.velocity), rtol=1e-12)


def test_truth_noise_reproducible_and_batched() -> None:
    q = (4.0, 4.0, 0.25, 0.25)
    noisy = Scenario((Segment(100),), position=(1000.0, 0.0), velocity=(10.0, 0.0), truth_q=q)
    clean = paper_scenario()
    clean = Scenario(clean.segments[:2], clean.position, clean.velocity)  # horizon 70
    noisy70 = Scenario((Segment(70, 2.0),), position=(0.0, 1000.0), velocity=(0.0, 5.0), truth_q=q)

    def gens(seeds: list[int]) -> list[np.random.Generator]:
        return [np.random.default_rng(s) for s in seeds]

    a = generate_truth([noisy, noisy], gens([1, 2]))
    b = generate_truth([noisy, noisy], gens([1, 2]))
    np.testing.assert_array_equal(a.states, b.states)
    assert not np.allclose(a.states[0], a.states[1])  # different generators, different noise
    c = generate_truth([noisy], gens([2]))
    np.testing.assert_allclose(c.states[0], a.states[1], rtol=1e-13, atol=1e-9)

    # mixing clean and noisy scenarios in one batch: each equals its own run
    mixed = generate_truth([clean, noisy70], gens([5, 6]))
    np.testing.assert_allclose(mixed.states[0], generate_truth([clean]).states[0], atol=1e-9)
    np.testing.assert_allclose(
        mixed.states[1], generate_truth([noisy70], gens([6])).states[0], atol=1e-9
    )


def test_truth_noise_statistics() -> None:
    q = np.array([4.0, 9.0, 0.25, 0.04])
    sc = Scenario((Segment(400),), velocity=(10.0, 0.0), truth_q=tuple(q))
    tr = generate_truth([sc] * 20, [np.random.default_rng(100 + i) for i in range(20)])
    F = ct_transition(0.0, 1.0)
    w = tr.states[:, 1:] - np.einsum("ij,nkj->nki", F, tr.states[:, :-1])
    w = w.reshape(-1, 4)
    np.testing.assert_allclose(w.std(axis=0), np.sqrt(q), rtol=0.05)
    np.testing.assert_allclose(w.mean(axis=0), 0.0, atol=0.05 * np.sqrt(q).max())


def test_truth_noise_needs_generators() -> None:
    sc = Scenario((Segment(10),), truth_q=(1.0, 1.0, 1.0, 1.0))
    with pytest.raises(ConfigError, match="rngs"):
        generate_truth([sc])


@pytest.mark.parametrize("n_rngs", [1, 3])
def test_truth_noise_needs_one_generator_per_scenario(n_rngs: int) -> None:
    """Two noisy runs with one generator, or three: refused, not an IndexError or a generator
    silently left over."""
    sc = Scenario((Segment(10),), truth_q=(1.0, 1.0, 1.0, 1.0))
    with pytest.raises(ConfigError, match="one generator per scenario"):
        generate_truth([sc, sc], [np.random.default_rng(s) for s in range(n_rngs)])


# --------------------------------------------------------------------------- validation


def test_empty_segment_list() -> None:
    with pytest.raises(ConfigError, match=r"scenario\.segments"):
        Scenario(())


@pytest.mark.parametrize("duration", [-5, 0, 2.5])
def test_bad_segment_duration(duration: float) -> None:
    with pytest.raises(ConfigError, match=r"segment\.duration"):
        Segment(duration)  # type: ignore[arg-type]


def test_segment_turn_and_accel() -> None:
    with pytest.raises(ConfigError):
        Segment(10, turn_rate_deg=1.0, accel=1.0)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"turn_rate_deg": math.nan}, r"^segment\.turn_rate_deg must be finite, got nan"),
        ({"turn_rate_deg": -math.inf}, r"^segment\.turn_rate_deg must be finite, got -inf"),
        ({"accel": math.nan}, r"^segment\.accel must be finite, got nan"),
        ({"accel": math.inf}, r"^segment\.accel must be finite, got inf"),
    ],
)
def test_a_turn_rate_or_acceleration_that_is_not_finite_is_refused(fields, message) -> None:
    """A NaN or infinite turn rate or acceleration would fly a truth of NaNs: refused by name."""
    with pytest.raises(ConfigError, match=message):
        Segment(10, **fields)


@pytest.mark.parametrize("T", [0.5, 1.0, 2.5])
@pytest.mark.parametrize(
    ("segments", "speed", "message"),
    [
        ((Segment(10, accel=2.0),), 0.0, r"segments\[0\]\.accel: the target is at rest"),
        ((Segment(11, accel=-1.0),), 10.5,
         r"segments\[0\]\.accel: .* below 0 .*\(accel >= -0\.954545\)"),
        ((Segment(5, accel=-2.0), Segment(3, 1.0), Segment(2, accel=1.0)), 10.0,
         r"segments\[2\]\.accel: the target is at rest"),
    ],
)
def test_an_acceleration_the_target_cannot_fly_is_refused(segments, speed, message, T) -> None:
    """Speeding up from rest has no heading; slowing past zero would flip the velocity. The
    initial speed is ``speed * T`` m/s, so the speed after n steps of a, ``speed T + a n T``,
    is T times the same number at every T: 10.5 T - 11 T < 0 (the least acceleration
    -10.5 T / (11 T) = -0.954545), 10 T - 10 T = 0 (stopped exactly)."""
    with pytest.raises(ConfigError, match=message):
        Scenario(segments, velocity=(speed * T, 0.0), T=T)
    # stopping exactly, then going straight, is a target
    Scenario((Segment(5, accel=-2.0), Segment(3)), velocity=(10.0 * T, 0.0), T=T)


def test_segment_from_mapping() -> None:
    sc = Scenario(({"duration": 5, "turn_rate_deg": 1.0}, {"duration": 3}))  # type: ignore[arg-type]
    assert sc.segments == (Segment(5, 1.0), Segment(3))


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"duration": 0}, r"^scenario\.segments\[1\]: segment\.duration must be an integer"),
        ({"duration": 3, "turn_rate_deg": math.nan},
         r"^scenario\.segments\[1\]: segment\.turn_rate_deg must be finite"),
        ({"duraton": 3}, r"^scenario\.segments\[1\]: unknown key"),
    ],
)
def test_a_bad_segment_mapping_is_refused_naming_its_entry(entry, message) -> None:
    """A scenario file's segments are mappings: an error names the entry of the list it is in."""
    with pytest.raises(ConfigError, match=message):
        Scenario(({"duration": 5}, entry))  # type: ignore[arg-type]


def test_mixed_horizons_in_one_batch() -> None:
    with pytest.raises(ConfigError, match="horizon"):
        generate_truth([Scenario((Segment(10),)), Scenario((Segment(11),))])


def test_mixed_sampling_periods_in_one_batch() -> None:
    with pytest.raises(ConfigError):
        generate_truth([Scenario((Segment(10),)), Scenario((Segment(10),), T=0.5)])


def test_generate_truth_empty() -> None:
    with pytest.raises(ConfigError):
        generate_truth([])


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"horizon": 50, "n_segments": (3, 6), "min_duration": 10}, r"n_segments\[1\]"),
        ({"n_segments": (4, 3)}, r"n_segments\[1\]"),
        ({"n_segments": (0, 3)}, r"n_segments\[0\]"),
        ({"speed": (10.0, 5.0)}, r"family\.speed\[1\]"),
        ({"range_m": (-1.0, 5.0)}, r"family\.range_m\[0\]"),
        ({"turn_rate_deg": (1.0, 0.5)}, r"family\.turn_rate_deg\[1\]"),
        ({"horizon": 0}, r"family\.horizon"),
        ({"min_duration": 0}, r"family\.min_duration must be an integer in \[1, inf\)"),
        ({"T": 0.0}, r"family\.T"),
        ({"truth_q": (1.0, -1.0, 1.0, 1.0)}, r"family\.truth_q must be in \[0\.0, inf\)"),
    ],
)
def test_invalid_family(kwargs: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        RandomFamily(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"T": -1.0}, r"scenario\.T"),
        ({"position": (0.0, float("nan"))}, r"scenario\.position"),
        ({"velocity": (1.0,)}, r"scenario\.velocity"),
        ({"truth_q": (1.0, -1.0, 1.0, 1.0)}, r"scenario\.truth_q"),
        ({"truth_q": (1.0, 1.0)}, r"scenario\.truth_q"),
    ],
)
def test_invalid_scenario(kwargs: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        Scenario((Segment(10),), **kwargs)


def test_numpy_integers_are_accepted_as_durations() -> None:
    assert Segment(np.int64(7)).duration == 7
    assert RandomFamily(horizon=np.int32(150)).horizon == 150


@pytest.mark.parametrize(
    ("speed", "accel", "steps", "T"),
    [(0.3, -0.3, 10, 0.1), (0.3, -0.6, 5, 0.1), (0.3, -0.3, 5, 0.2)],
)
def test_stopping_exactly_in_decimal_is_a_target(speed, accel, steps, T) -> None:
    """An acceleration that stops the target exactly on paper, ``speed + a n T = 0``, but a few
    ulps below 0 in floating point (0.3 - 0.3 * 10 * 0.1 = -5.6e-17) is a target, not a speed
    driven below 0; it stops where the constant-deceleration formula ``v t + a t² / 2`` worked
    by hand puts it (0.3 * 1 - 0.3 / 2 = 0.15 m; 0.3 * 0.5 - 0.6 * 0.25 / 2 = 0.075 m; 0.3 * 1
    - 0.3 / 2 = 0.15 m) and stays there."""
    assert speed + accel * steps * T < 0.0  # the rounding the check must tolerate
    scenario = Scenario((Segment(steps, accel=accel), Segment(3)), velocity=(speed, 0.0), T=T)
    t = steps * T
    states = generate_truth([scenario]).states[0]
    np.testing.assert_allclose(states[steps:, 0], speed * t + accel * t * t / 2, rtol=1e-12)
    np.testing.assert_allclose(states[steps:, 2:], 0.0, atol=1e-15)


def test_the_default_family_draws_the_spec_ranges() -> None:
    """SPEC §6's randomized family, read off the truth a user gets from ``RandomFamily()``: start
    range U(3, 8) km, speed U(5, 25) m/s (constant), 150 steps of T = 1 s, 3-6 segments of at
    least 10 steps (a segment ends where the turn rate changes: straight and turn alternate),
    straight first, turn rates ±U(0.5, 3) °/s; 400 runs reach within a few percent of each end."""
    truth = RandomFamily().truth([np.random.default_rng(s) for s in range(400)])
    assert truth.states.shape == (400, 151, 4) and truth.T == 1.0
    ranges = np.linalg.norm(truth.states[:, 0, :2], axis=-1)
    assert ranges.min() >= 3000.0 and ranges.max() <= 8000.0
    assert ranges.min() < 3100.0 and ranges.max() > 7900.0
    speeds = np.linalg.norm(truth.states[:, :, 2:], axis=-1)
    assert np.all(np.abs(speeds - speeds[:, :1]) <= 1e-12 * speeds[:, :1])
    assert speeds.min() >= 5.0 and speeds.max() <= 25.0
    assert speeds.min() < 5.5 and speeds.max() > 24.5
    rates = np.degrees(np.abs(truth.turn_rate))
    turning = rates[rates > 0]
    assert turning.min() >= 0.5 and turning.max() <= 3.0
    assert turning.min() < 0.55 and turning.max() > 2.95
    counts, shortest = [], []
    for omega in truth.turn_rate:
        edges = np.flatnonzero(np.diff(omega)) + 1
        durations = np.diff(np.concatenate([[0], edges, [omega.size]]))
        assert omega[0] == 0.0
        counts.append(durations.size)
        shortest.append(durations.min())
    assert set(counts) == {3, 4, 5, 6}
    assert min(shortest) == 10
