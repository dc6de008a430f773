"""A family drawn for its tracker (``RandomFamily.designed_share``): a share of the runs turn at
the rates their bank's CT models are designed to fly.

The draws are held against a run-by-run reference written from the docstrings, the tracker's
design (:func:`turn_design`) against the closed form of white-noise acceleration, and the
environment against the bands of each slot's own drawn tracker.
"""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import imm_gym  # noqa: F401  (registers the envs)
from imm_gym import MotionModel, RandomFamily, paper_bank
from imm_gym.scenarios.segments import TurnDesign
from imm_gym.seeding import streams
from imm_gym.sim.conditions import Variation, draw_conditions, turn_design
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.sim.presets import CONTINUOUS_BANK, SONAR_HETERO_BANK
from imm_gym.tracking.sensors import Sonar
from imm_gym.validation import ConfigError

#: CV and CT(±4°/s), white-noise acceleration of intensities 1 and 20 m²/s³ (vsmm-s1's bank).
SURVEILLANCE = (
    MotionModel("cv", noise="continuous", intensity=1.0),
    MotionModel("ct", 4.0, noise="continuous", intensity=20.0),
    MotionModel("ct", -4.0, noise="continuous", intensity=20.0),
)


def _reference_rates(
    family: RandomFamily, design: TurnDesign, rng: np.random.Generator, r: int
) -> np.ndarray:
    """Run ``r``'s signed turn rates (°/s, 0 on straight legs), drawn call by call as the
    family's docstrings order them."""
    rng.uniform(*family.range_m)
    rng.uniform(-math.pi, math.pi)
    speed = rng.uniform(*family.speed)
    rng.uniform(-math.pi, math.pi)
    n = int(rng.integers(family.n_segments[0], family.n_segments[1] + 1))
    extra = family.horizon - n * family.min_duration
    rng.choice(extra + n - 1, size=n - 1, replace=False)
    rates = rng.uniform(*family.turn_rate_deg, size=n)
    rates *= np.array([-1.0, 1.0])[rng.integers(0, 2, size=n)]
    if family.designed_share > 0.0 and rng.uniform() < family.designed_share:
        models = rng.integers(0, design.rates.shape[1], size=n)
        fractions = rng.uniform(size=n)
        lo_family, hi_family = family.turn_rate_deg
        for i, (j, f) in enumerate(zip(models, fractions, strict=True)):
            omega = math.degrees(design.rates[r, j])
            half = family.designed_width * math.degrees(design.accel_std[r, j]) / speed
            lo = min(max(abs(omega) - half, lo_family), hi_family)
            hi = min(max(abs(omega) + half, lo_family), hi_family)
            rates[i] = math.copysign(lo + f * (hi - lo), omega)
    rates[0::2] = 0.0
    return rates


@pytest.mark.parametrize("share", [0.0, 0.4, 1.0])
def test_the_designed_draws_match_a_run_by_run_reference(share: float) -> None:
    """Every run's turns, and the generators' states after them, equal the reference's."""
    family = RandomFamily(
        speed=(20.0, 300.0), turn_rate_deg=(0.5, 6.0), n_segments=(1, 6), designed_share=share
    )
    R = 60
    rng = np.random.default_rng(3)
    design = TurnDesign(
        rates=np.radians(rng.choice([-4.0, -2.0, 3.0, 6.0], size=(R, 3))),
        accel_std=rng.uniform(0.01, 5.0, size=(R, 3)),
    )
    rngs = [streams(s)[0] for s in range(R)]
    references = [streams(s)[0] for s in range(R)]
    truth = family.varied_truth(rngs, design=design)
    for r in range(R):
        expected = _reference_rates(family, design, references[r], r)
        segments = np.flatnonzero(np.diff(truth.turn_rate[r], prepend=np.nan) != 0)
        got = np.degrees(truth.turn_rate[r, segments])
        np.testing.assert_allclose(got[got != 0], expected[expected != 0], rtol=1e-12)
        assert rngs[r].uniform() == references[r].uniform()


def test_without_a_designed_share_the_family_draws_as_before() -> None:
    """``designed_share = 0`` draws no number more: the truth of the family with and without the
    bank is the same, bit for bit."""
    family = RandomFamily()
    plain = draw_batch(family, Sonar(), 20, 4)
    with_bank = draw_batch(family, Sonar(), 20, 4, bank=CONTINUOUS_BANK)
    np.testing.assert_array_equal(plain.truth.states, with_bank.truth.states)
    np.testing.assert_array_equal(plain.measurements.z, with_bank.measurements.z)


def test_a_design_is_each_ct_model_rate_and_the_acceleration_its_noise_absorbs() -> None:
    """White-noise acceleration of intensity ``q`` adds ``q T`` to each velocity's variance per
    step, so the design's acceleration is ``sqrt(q s a / T)`` (``s``: q_scale, ``a``:
    q_maneuver); a per-step ``Q``'s is ``sqrt(q_v) / T``."""
    T = np.array([0.5, 1.0, 5.0])
    q_scale, q_maneuver = np.array([1.0, 2.0, 0.1]), np.array([1.0, 10.0, 3.0])
    design = turn_design(SURVEILLANCE, T, q_scale, q_maneuver)
    np.testing.assert_allclose(design.rates, np.radians([[4.0, -4.0]] * 3))
    expected = np.sqrt(20.0 * q_scale * q_maneuver / T)
    np.testing.assert_allclose(design.accel_std, np.stack([expected, expected], axis=1))
    paper = turn_design(paper_bank(), np.array([1.0, 2.0]), np.ones(2), np.ones(2))
    np.testing.assert_allclose(paper.accel_std, [[math.sqrt(0.06)] * 2, [math.sqrt(0.06) / 2] * 2])


@settings(max_examples=25, deadline=None)
@given(
    speed=st.floats(1.0, 500.0),
    q=st.floats(1e-3, 100.0),
    T=st.floats(0.2, 5.0),
    width=st.floats(0.1, 4.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_a_fully_designed_family_turns_within_its_trackers_bands(
    speed: float, q: float, T: float, width: float, seed: int
) -> None:
    """With ``designed_share = 1`` every turn lies in the band of a CT model of the bank, turns
    the model's way, and stays within the family's range."""
    bank = (
        MotionModel("cv", noise="continuous", intensity=0.1),
        MotionModel("ct", 3.0, noise="continuous", intensity=q),
        MotionModel("ct", -3.0, noise="continuous", intensity=q),
    )
    family = RandomFamily(
        speed=(speed, speed), turn_rate_deg=(0.5, 5.0), T=T, designed_share=1.0,
        designed_width=width,
    )
    truth = draw_batch(family, Sonar(), 8, seed % 2**31, bank=bank).truth
    rates = np.abs(np.degrees(truth.turn_rate[truth.turn_rate != 0]))
    half = math.degrees(width * math.sqrt(q / T) / speed)
    lo, hi = np.clip([3.0 - half, 3.0 + half], 0.5, 5.0)
    assert np.all((rates >= lo - 1e-9) & (rates <= hi + 1e-9))


def test_about_the_share_of_the_runs_fly_the_designed_turns() -> None:
    """A band of nearly zero width puts a designed run's turns at the bank's rates: about
    ``designed_share`` of the runs fly only ±4°/s."""
    family = RandomFamily(n_segments=(2, 6), turn_rate_deg=(0.5, 6.0), designed_share=0.3,
                          designed_width=1e-9)
    truth = draw_batch(family, Sonar(), 2000, 0, bank=CONTINUOUS_BANK).truth
    turning = truth.turn_rate != 0
    at_bank = np.isclose(np.abs(truth.turn_rate), math.radians(4.0), rtol=0, atol=1e-9)
    designed = np.all(at_bank | ~turning, axis=1)
    assert abs(designed.mean() - 0.3) < 0.04


def test_each_slot_turns_within_the_band_of_its_own_drawn_tracker() -> None:
    """In the environment, with conditions drawn per episode, every turn lies in the band of
    the slot's tracker at its drawn ``T``, ``q_scale``, ``q_maneuver`` and speed."""
    vary = {"T": (0.5, 5.0), "speed": (50.0, 400.0), "q_scale": (0.1, 30.0),
            "q_maneuver": (1.0, 50.0)}
    config = EnvConfig(
        bank=SURVEILLANCE, vary=vary,
        family={"turn_rate_deg": (0.5, 6.0), "designed_share": 1.0, "n_segments": (3, 3)},
    )
    rngs = [streams(s)[0] for s in range(30)]
    conditions = draw_conditions(config.vary, config.source.T, config.sensor, rngs)
    batch = draw_batch(config.source, config.sensor, 30, 0, variation=config.vary,
                       bank=config.linear_bank)
    np.testing.assert_array_equal(batch.conditions.T, conditions.T)  # type: ignore[union-attr]
    speed = np.linalg.norm(batch.truth.states[:, 0, 2:], axis=-1)
    half = np.degrees(2.0 * np.sqrt(20.0 * conditions.q_scale * conditions.q_maneuver
                                    / conditions.T) / speed)
    lo, hi = np.clip(4.0 - half, 0.5, 6.0), np.clip(4.0 + half, 0.5, 6.0)
    rates = np.abs(np.degrees(batch.truth.turn_rate))
    turning = rates > 0
    assert turning.any()
    assert np.all(~turning | ((rates >= lo[:, None] - 1e-9) & (rates <= hi[:, None] + 1e-9)))
    env = gymnasium.make("imm_gym/TPMAdapt-v0", config=config)
    env.reset(seed=0)
    np.testing.assert_array_equal(env.unwrapped.core.truth[0], batch.truth.states[0])
    env.close()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"family": {"designed_share": 1.5}}, r"family.designed_share .*\[0(\.0)?, 1(\.0)?\]"),
        ({"family": {"designed_width": 0.0}}, r"family.designed_width"),
        ({"family": {"designed_share": 0.5, "truth_q": (1.0, 1.0, 0.1, 0.1)}},
         r"designed_share needs a noise-free family"),
        ({"family": {"designed_share": 0.5}, "bank": (MotionModel("cv"), MotionModel("cv"))},
         r"designed_share needs a linear bank with a CT model"),
        ({"family": {"designed_share": 0.5}, "bank": dict(SONAR_HETERO_BANK), "filter": "ekf"},
         r"designed_share needs a linear bank with a CT model"),
    ],
)
def test_a_designed_family_that_cannot_apply_is_a_config_error(changes, message) -> None:
    with pytest.raises(ConfigError, match=message):
        EnvConfig(**changes)


def test_a_designed_family_without_its_tracker_is_a_config_error() -> None:
    family = RandomFamily(designed_share=0.5)
    with pytest.raises(ConfigError, match=r"designed_share .*bank"):
        draw_batch(family, Sonar(), 2, 0)
    with pytest.raises(ConfigError, match=r"designed_share"):
        family.sample(np.random.default_rng(0))
    with pytest.raises(ConfigError, match=r"designed_share"):
        draw_batch(family, Sonar(), 2, 0, variation=Variation(speed=(5.0, 50.0)))


def test_a_band_at_rest_is_the_family_range_and_in_flight_its_closed_form() -> None:
    """``designed_band`` by hand: at 0 m/s no lateral acceleration bounds a turn, so every
    model's band is the family's whole range (0.5, 3) °/s; at 50 m/s a CT model of 2 °/s with
    0.5 m/s² of noise, c = 2, spans 2 ± 2 * 0.5 / 50 rad/s = 2 ± 1.1459 °/s, clipped to
    (0.8541, 3); one of -0.6 °/s with 1 m/s² spans 0.6 ± 2.2918 °/s, clipped to (0.5, 2.8918)."""
    family = RandomFamily(turn_rate_deg=(0.5, 3.0), designed_share=1.0, designed_width=2.0)
    rate = np.radians([2.0, -0.6])
    accel_std = np.array([0.5, 1.0])
    low, high = family.designed_band(rate, accel_std, 0.0)
    np.testing.assert_array_equal(low, [0.5, 0.5])
    np.testing.assert_array_equal(high, [3.0, 3.0])
    half = 2.0 * accel_std / 50.0 * 180.0 / math.pi
    low, high = family.designed_band(rate, accel_std, 50.0)
    np.testing.assert_allclose(low, [2.0 - half[0], 0.5], rtol=1e-12)
    np.testing.assert_allclose(high, [3.0, 0.6 + half[1]], rtol=1e-12)
