"""Observation features in the tracker's own units: turn rates in units of the bank's, how
distinguishable a bank turn is from the measurement noise in one step, and how wide a band of
turns the CT models absorb."""

from __future__ import annotations

import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from imm_gym.seeding import streams
from imm_gym.sim.conditions import draw_conditions
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.features import TURN_RATE_SCALE, bank_turn_rate, log_decades, turn_band
from imm_gym.sim.presets import BANK_PRESETS, CONTINUOUS_BANK
from imm_gym.tracking.models import MotionModel
from imm_gym.validation import ConfigError

FEATURES = ("turn_rate_bank", "shadow_turn_rate_bank", "turn_magnitude_bank_ema", "maneuver_snr")


def test_the_bank_turn_rate_is_its_fastest_ct_model() -> None:
    bank = (MotionModel("cv"), MotionModel("ct", 3.0), MotionModel("ct", -6.0))
    assert bank_turn_rate(bank) == math.radians(6.0)
    assert bank_turn_rate((MotionModel("cv"), MotionModel("cv", q=(1.0,) * 4))) == TURN_RATE_SCALE
    assert bank_turn_rate(EnvConfig(**BANK_PRESETS["hetero"]).bank) == TURN_RATE_SCALE


def test_the_features_by_hand() -> None:
    config = EnvConfig(obs_features=FEATURES)
    core = TrackingCore(config, 5)
    core.reset(np.arange(5), list(range(5)))
    P0 = core.state_a.P[:, 0]
    accuracy = np.sqrt(0.5 * (P0[:, 0, 0] + P0[:, 1, 1]))
    np.testing.assert_array_equal(core.position_accuracy, accuracy)
    omega = math.radians(4.0)  # the paper bank's CT models
    lam = np.array([0.9, 0.97])
    magnitude = np.zeros((5, 2))
    for _ in range(30):
        v0, s0 = core.velocity.copy(), core.velocity_s.copy()
        obs = core.step(np.zeros((5, 9))).obs
        v1, s1 = core.velocity, core.velocity_s

        def rate(a, b):
            return np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], np.sum(a * b, axis=-1))

        own, shadow = rate(v0, v1) / omega, rate(s0, s1) / omega
        magnitude = lam * magnitude + (1 - lam) * np.minimum(np.abs(shadow), 1.0)[:, None]
        speed = np.hypot(v1[:, 0], v1[:, 1])
        snr = np.clip(np.log10(np.maximum(speed * omega / (2 * accuracy), 1e-3)) / 3, -1, 1)
        expected = np.column_stack([
            np.clip(own, -2, 2) / 2, np.clip(shadow, -2, 2) / 2, magnitude, snr
        ])
        np.testing.assert_allclose(obs[:, 6:], expected, rtol=1e-5, atol=1e-6)


def test_the_tracking_index_of_a_bank_with_per_step_noise() -> None:
    """The paper bank's ``Q`` is per step: velocity variances 0.12 (CV) and 0.06 (CT) at
    T = 1 s, whatever the sensor; the index is their root over the first measurement's
    accuracy."""
    core = TrackingCore(EnvConfig(obs_features=("tracking_index",)), 4)
    core.reset(np.arange(4), list(range(4)))
    obs = core.step(np.zeros((4, 9))).obs[:, 6:]
    sigma_v = np.sqrt([0.12, 0.06, 0.06])
    expected = np.log10(sigma_v[None] / core.position_accuracy[:, None]) / 4
    np.testing.assert_allclose(obs, expected, rtol=1e-5, atol=1e-6)


def test_the_tracking_index_needs_a_linear_bank() -> None:
    with pytest.raises(ConfigError, match="'tracking_index' needs a linear bank"):
        EnvConfig(**BANK_PRESETS["hetero"], obs_features=("tracking_index",))


def test_the_turn_band_follows_each_slots_drawn_tracker_and_speed() -> None:
    """``turn_band`` by hand: white-noise acceleration of intensity ``q`` absorbs
    ``sqrt(q / T)`` of acceleration, here the CT models' ``q`` times the slot's ``q_scale`` and
    ``q_maneuver``; a turn at the bank's 4°/s takes ``|v| ω``, ``v`` the combined estimate."""
    N = 6
    vary = {"T": (0.5, 5.0), "speed": (20.0, 400.0), "q_scale": (0.1, 30.0),
            "q_maneuver": (0.5, 50.0)}
    config = EnvConfig(bank=CONTINUOUS_BANK, vary=vary, obs_features=("turn_band",))
    core = TrackingCore(config, N)
    seeds = list(range(40, 40 + N))
    core.reset(np.arange(N), seeds)
    drawn = draw_conditions(config.vary, 1.0, config.sensor, [streams(s)[0] for s in seeds])
    q_ct = CONTINUOUS_BANK[1].intensity * drawn.q_scale * drawn.q_maneuver
    for _ in range(3):
        obs = core.step(np.zeros((N, 9))).obs[:, 6]
        speed = np.hypot(core.velocity[:, 0], core.velocity[:, 1])
        ratio = np.sqrt(q_ct / drawn.T) / (speed * math.radians(4.0))
        np.testing.assert_allclose(obs, np.clip(np.log10(ratio) / 2, -1, 1), rtol=1e-5,
                                   atol=1e-6)


def test_the_turn_band_of_the_paper_bank_and_its_checks() -> None:
    """The paper bank's CT velocity noise is 0.06 m²/s² per step at T = 1 s."""
    core = TrackingCore(EnvConfig(obs_features=("turn_band",)), 3)
    core.reset(np.arange(3), [0, 1, 2])
    obs = core.step(np.zeros((3, 9))).obs[:, 6]
    speed = np.hypot(core.velocity[:, 0], core.velocity[:, 1])
    expected = np.log10(math.sqrt(0.06) / (speed * math.radians(4.0))) / 2
    np.testing.assert_allclose(obs, np.clip(expected, -1, 1), rtol=1e-5, atol=1e-6)
    with pytest.raises(ConfigError, match="'turn_band' needs a linear bank"):
        EnvConfig(**BANK_PRESETS["hetero"], obs_features=("turn_band",))
    cv_only = (MotionModel("cv"), MotionModel("cv", q=(1.0,) * 4))
    with pytest.raises(ConfigError, match="'turn_band' needs a linear bank with a CT model"):
        EnvConfig(bank=cv_only, obs_features=("turn_band",))


#: CT models of unequal noise at T = 2 s
UNEQUAL = (
    {"kind": "cv", "noise": "continuous", "intensity": 0.1},
    {"kind": "ct", "turn_rate_deg": 4.0, "noise": "continuous", "intensity": 0.02},
    {"kind": "ct", "turn_rate_deg": -4.0, "noise": "continuous", "intensity": 0.5},
)


def test_the_turn_band_is_the_ct_models_mean_noise() -> None:
    """CT models of intensities 0.02 and 0.5 at T = 2 s absorb ``sqrt(0.02 / 2)`` and
    ``sqrt(0.5 / 2)`` of acceleration: the band is their mean, 0.3 m/s², over ``|v| ω``."""
    config = EnvConfig(bank=UNEQUAL, family={"T": 2.0}, obs_features=("turn_band",))
    core = TrackingCore(config, 3)
    core.reset(np.arange(3), [5, 6, 7])
    for _ in range(3):
        obs = core.step(np.zeros((3, 9))).obs[:, 6]
        speed = np.hypot(core.velocity[:, 0], core.velocity[:, 1])
        expected = np.log10(0.3 / (speed * math.radians(4.0))) / 2
        assert np.all(np.abs(expected) < 1.0)  # no slot at the clip
        np.testing.assert_allclose(obs, expected, rtol=1e-5, atol=1e-6)


def test_the_features_of_the_shadows_estimate_need_the_shadow() -> None:
    """Without the shadow IMM (``shadow="none"``) a feature computed from its estimate is
    refused; the combined estimate's are not."""
    shadows = ("shadow_turn_rate_bank", "turn_magnitude_bank_ema", "shadow_turn_rate",
               "shadow_turn_rate_ema", "turn_magnitude_ema", "shadow_probs", "shadow_evidence",
               "stay_evidence")
    for name in shadows:
        with pytest.raises(ConfigError, match=f"'{name}' needs shadow 'fixed'"):
            EnvConfig(obs_features=(name,), shadow="none", reward="error")
    for name in ("turn_rate_bank", "maneuver_snr", "turn_rate"):
        EnvConfig(obs_features=(name,), shadow="none", reward="error")


def test_the_turn_band_of_a_target_at_rest_is_its_top_without_a_warning() -> None:
    """At zero estimated speed a turn takes no acceleration: any noise absorbs it, the band is
    at its top, 1, with no division by zero (slot 1 moving: the band by hand)."""
    view = SimpleNamespace(
        config=EnvConfig(bank=CONTINUOUS_BANK), sampling_period=np.array([1.0, 1.0]),
        velocity_noise=np.full((2, 3), 0.3), velocity=np.array([[0.0, 0.0], [100.0, 0.0]]),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        band = turn_band(view)
    assert band[0] == 1.0
    np.testing.assert_allclose(band[1], math.log10(0.3 / (100.0 * math.radians(4.0))) / 2)


def test_a_ratio_on_a_log_scale_reaches_both_ends() -> None:
    """``log10 x / d`` clipped to [-1, 1]: ``d = 3`` decades either side of 1 are resolved, a
    ratio of 10³ or more is 1, one of 10⁻³ or less (0 too) is -1."""
    x = np.array([0.0, 1e-5, 1e-3, 0.1, 1.0, 10.0, 1e3, 1e5])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = log_decades(x, 3.0)
    np.testing.assert_allclose(got, [-1.0, -1.0, -1.0, -1 / 3, 0.0, 1 / 3, 1.0, 1.0], atol=1e-15)
