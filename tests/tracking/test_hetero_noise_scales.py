"""Per-tracker measurement-noise factors of the heterogeneous engine (``r_scale``, the BBSCA
tuner's knob): each tracker runs as it would alone with a sensor whose ``R`` is scaled."""

from __future__ import annotations

import math

import numpy as np

from imm_gym import PositionSensor, stay_tpm
from imm_gym.tracking.hetero import HeteroBank, HeteroIMM
from imm_gym.tracking.imm import run


def test_per_tracker_r_scale_is_a_sensor_with_scaled_noise() -> None:
    """``r_scale[i] = c`` is tracker i alone with standard deviations times ``sqrt(c)``
    (``R`` times ``c``), built as another sensor; a factor of 1 is the sensor itself."""
    rng = np.random.default_rng(8)
    sigma_pos, sigma_vel = 0.5, 0.3
    z = rng.normal(size=(3, 30, 4)) * 0.5 + np.array([0.0, 0.0, 5.0, 0.0])
    z[..., 0] += 0.5 * np.arange(30)
    tpm = stay_tpm(3, 0.9)
    x0, P0 = np.tile([0.0, 0.0, 5.0, 0.0], (3, 1)), 0.25 * np.eye(4)
    scales = np.array([4.0, 1.0, 0.09])
    sensor = PositionSensor(sigma_pos=sigma_pos, sigma_vel=sigma_vel)
    batched = run(HeteroIMM(HeteroBank(), sensor, T=0.1), z, tpm, x0, P0, r_scale=scales)
    for i, c in enumerate(scales):
        scaled = PositionSensor(
            sigma_pos=sigma_pos * math.sqrt(c), sigma_vel=sigma_vel * math.sqrt(c)
        )
        alone = run(HeteroIMM(HeteroBank(), scaled, T=0.1), z[i : i + 1], tpm, x0[:1], P0)
        np.testing.assert_allclose(batched.x[i], alone.x[0], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(batched.mode_probs[i], alone.mode_probs[0], atol=1e-12)
        np.testing.assert_allclose(batched.nis[i], alone.nis[0], rtol=1e-9)
    assert not np.allclose(batched.x[0], batched.x[2], atol=1e-3)
