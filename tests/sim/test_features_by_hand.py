"""Fourteen of the observation blocks (the others in their own modules' tests) recomputed by
hand from the core's per-step quantities (mu, the models' log-likelihoods, NIS and whitened
innovations, the combined and shadow estimates' velocities): a
bank of CV, CA and two CT models at T = 2 s over four slots, random actions so that bank A and
the shadow IMM differ, the memories carried from their documented starts."""

from __future__ import annotations

import math

import numpy as np

from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.features import heading_rate

FEATURES = (
    "loglik", "nis", "time", "turn_rate", "shadow_turn_rate", "turn_rate_ema", "prob_ema",
    "shadow_turn_rate_ema", "turn_magnitude_ema", "speed", "model_turn_rate", "model_kind",
    "maneuver_snr", "innovation",
)
BANK = [
    {"kind": "cv", "noise": "continuous", "intensity": 0.1},
    {"kind": "ca", "noise": "continuous", "intensity": 0.05},
    {"kind": "ct", "turn_rate_deg": 3.0, "noise": "continuous", "intensity": 0.1},
    {"kind": "ct", "turn_rate_deg": -6.0, "noise": "continuous", "intensity": 0.1},
]
N, M, T, STEPS = 4, 4, 2.0, 40


def rate(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The heading change (rad) from velocities ``a`` to ``b``, by the angle between them."""
    return np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], np.sum(a * b, axis=-1))


def test_every_block_by_hand_over_an_episode() -> None:
    # turns of 8-14 °/s: the shadow's heading rate passes 10 °/s, the memories' clip
    config = EnvConfig.build({"scenario": "random", "bank": BANK,
                              "family": {"T": T, "turn_rate_deg": [8.0, 14.0]},
                              "obs_features": FEATURES})
    core = TrackingCore(config, N)
    core.reset(np.arange(N), [11, 12, 13, 14])
    rng = np.random.default_rng(0)
    lam, lam_magnitude = np.array([0.7, 0.9]), np.array([0.9, 0.97])
    own_ema, shadow_ema, magnitude = np.zeros((N, 2)), np.zeros((N, 2)), np.zeros((N, 2))
    prob_ema = np.repeat(core.mu[:, None, :], 2, axis=1)  # starts at mu(0)
    clip, scale = config.loglik_clip, math.radians(10.0)
    omega_bank = math.radians(6.0)
    accuracy = core.position_accuracy.copy()
    beyond = 0
    for step in range(1, STEPS + 1):
        v0, s0, mu0 = core.velocity.copy(), core.velocity_s.copy(), core.mu.copy()
        obs = core.step(rng.uniform(-1.0, 1.0, (N, M * M))).obs.astype(np.float64)
        v1, s1, mu = core.velocity, core.velocity_s, core.mu
        own, shadow = rate(v0, v1) / T / scale, rate(s0, s1) / T / scale
        beyond += int(np.sum(np.abs(shadow) > 1.0))
        own_ema = lam * own_ema + (1 - lam) * own[:, None]
        shadow_ema = lam * shadow_ema + (1 - lam) * np.clip(shadow, -1, 1)[:, None]
        magnitude = lam_magnitude * magnitude + (1 - lam_magnitude) * np.minimum(
            np.abs(shadow), 1.0)[:, None]
        prob_ema = lam[None, :, None] * prob_ema + (1 - lam[None, :, None]) * mu[:, None, :]
        L, nis = core.loglik, core.model_nis
        speed = np.hypot(v1[:, 0], v1[:, 1])
        offset = speed * omega_bank * T * T / (2 * accuracy)
        blocks = [
            mu, mu0,
            np.clip(L - L.max(axis=1, keepdims=True), -clip, 0.0) / clip,
            nis / (nis + 2.0),
            np.full((N, 1), step / core.horizon),
            np.clip(own, -1, 1)[:, None], np.clip(shadow, -1, 1)[:, None],
            np.clip(own_ema, -1, 1), prob_ema.reshape(N, -1), shadow_ema, magnitude,
            np.clip(speed / 30.0, 0, 1)[:, None],
            np.tile([0.0, 0.0, 0.5, -1.0], (N, 1)),
            np.tile([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0], (N, 1)),
            np.clip(np.log10(np.maximum(offset, 1e-3)) / 3, -1, 1)[:, None],
            np.clip(core.innovation, -5.0, 5.0).reshape(N, -1) / 5.0,
        ]
        expected = np.concatenate(blocks, axis=1)
        assert obs.shape == expected.shape
        np.testing.assert_allclose(obs, expected, rtol=1e-5, atol=1e-6, err_msg=f"step {step}")
    assert not np.array_equal(core.velocity, core.velocity_s)  # bank A is not the shadow
    assert beyond > 0  # the memories' per-step clip was exercised


def test_the_heading_rate_is_the_signed_angle_between_the_velocities() -> None:
    v = np.array([[10.0, 0.0], [10.0, 0.0], [10.0, 0.0], [3.0, 4.0], [0.0, 0.0]])
    w = np.array([[0.0, 5.0], [0.0, -5.0], [-10.0, 0.01], [-3.0, -4.0], [1.0, 0.0]])
    expected = np.array([math.pi / 2, -math.pi / 2, math.pi - 0.001, math.pi, 0.0]) / 2.0
    np.testing.assert_allclose(heading_rate(v, w, 2.0), expected, rtol=1e-6, atol=1e-12)


def test_the_heading_rate_from_or_to_rest_is_zero_whatever_the_quadrant() -> None:
    """A zero velocity against one heading south-west makes a dot product of -0, where atan2
    reads a half turn (the replay path's first step starts from rest)."""
    rest = np.zeros((4, 2))
    v = np.array([[-1.0, -1.0], [-3.0, -0.5], [1.0, 1.0], [-1.0, 1.0]])
    assert heading_rate(rest, v, 1.0).tolist() == [0.0] * 4
    assert np.abs(heading_rate(v, rest, 1.0)).tolist() == [0.0] * 4


def test_the_observation_size_is_the_bounds_length_for_every_feature() -> None:
    from imm_gym.sim.features import FEATURES, bounds, observation_size

    for M, dim_z in ((2, 2), (3, 2), (5, 4)):
        for name in FEATURES:
            assert observation_size((name,), M, dim_z) == bounds((name,), M, dim_z)[0].size
        every = tuple(FEATURES)
        assert observation_size(every, M, dim_z) == bounds(every, M, dim_z)[0].size


def test_the_innovation_block_is_the_whitened_innovation_by_hand() -> None:
    """Bank A's cycle by hand (mixing, prediction, the EKF's sonar residual): the block is each
    model's ``L⁻¹ν`` (``S = L Lᵀ``) clipped to ±5 and divided by 5, model-major; the sonar's
    outliers push some components past the clip."""
    bank = [BANK[0], BANK[2], BANK[3]]
    config = EnvConfig.build({"scenario": "random", "bank": bank, "filter": "ekf",
                              "sensor": {"outlier_prob": 0.3, "outlier_scale": 30.0},
                              "family": {"T": T, "turn_rate_deg": [8.0, 14.0]},
                              "obs_features": ("innovation",)})
    n_slots, n_models = 2, len(bank)
    core = TrackingCore(config, n_slots)
    core.reset(np.arange(n_slots), [21, 22])
    F, Q, R = core.imm.F, core.imm.Q, np.diag([50.0**2, math.radians(0.05) ** 2])
    rng = np.random.default_rng(1)
    clipped = 0
    for step in range(1, 16):
        x, P, mu = core.state_a.x.copy(), core.state_a.P.copy(), core.mu.copy()
        obs = core.step(rng.uniform(-1.0, 1.0, (n_slots, n_models**2))).obs
        for s in range(n_slots):
            white = np.empty((n_models, 2))
            for j in range(n_models):
                weights = core.tpm[s, :, j] * mu[s] / (core.tpm[s, :, j] @ mu[s])
                x0 = weights @ x[s]
                P0 = sum(w * (P[s, i] + np.outer(x[s, i] - x0, x[s, i] - x0))
                         for i, w in enumerate(weights))
                xp, Pp = F[j] @ x0, F[j] @ P0 @ F[j].T + Q[j]
                r = math.hypot(xp[0], xp[1])
                H = np.zeros((2, 4))
                H[0, :2] = xp[0] / r, xp[1] / r
                H[1, :2] = -xp[1] / r**2, xp[0] / r**2
                z = core.z[s, step]
                nu = np.array([z[0] - r, z[1] - math.atan2(xp[1], xp[0])])
                nu[1] = (nu[1] + math.pi) % (2 * math.pi) - math.pi
                S = H @ Pp @ H.T + R
                # L⁻¹ν by forward substitution, L the Cholesky factor of the 2x2 S
                l11 = math.sqrt(S[0, 0])
                l21 = S[1, 0] / l11
                l22 = math.sqrt(S[1, 1] - l21**2)
                white[j] = nu[0] / l11, (nu[1] - l21 * nu[0] / l11) / l22
            clipped += int(np.sum(np.abs(white) > 5.0))
            np.testing.assert_allclose(core.innovation[s], white, rtol=1e-6, atol=1e-8,
                                       err_msg=f"step {step}, slot {s}")
            expected = np.clip(white, -5.0, 5.0).reshape(-1) / 5.0
            np.testing.assert_allclose(obs[s, 2 * n_models:], expected, rtol=1e-5, atol=1e-6,
                                       err_msg=f"step {step}, slot {s}")
    assert clipped > 0
