"""Observation features in the tracker's own units: turn rates in units of the bank's, and how
distinguishable a bank turn is from the measurement noise in one step."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.features import TURN_RATE_SCALE, bank_turn_rate
from imm_gym.sim.presets import BANK_PRESETS
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
