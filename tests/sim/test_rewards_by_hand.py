"""The reward terms of a vector core (:mod:`imm_gym.sim.rewards`) against their equations
computed by hand from the step's errors (``info``), the shadow's, the scale and the TPMs, on
both engines."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import EnvConfig, TrackingCore
from imm_gym.tracking.tpm import stay_tpm

N = 3
M = 3
SCALE = 7.0
TPM_COST = 0.05


def _divergence_by_hand(tpm: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``(1/M) Σ_i Σ_j π_ij ln(π_ij / ρ_ij)`` of each slot's TPM ``π`` from ``ρ`` (every entry
    of both is positive here: ``p_min`` floors the TPMs, the shadow's stay is below 1)."""
    return np.sum(tpm * np.log(tpm / reference), axis=(-2, -1)) / M


@pytest.mark.parametrize("reward", ["error", "advantage", "squared_advantage"])
def test_each_reward_term_is_its_equation(engine: str, reward: str) -> None:
    """``error = -e / s``, ``advantage = (e_s - e) / s``, ``squared_advantage = (e_s^2 - e^2) /
    s^2`` and the reward the named term minus ``tpm_cost`` times the divergence of the TPM's
    rows from the shadow's fixed ``stay_tpm(M, initial_stay)``, KL(TPM || shadow's), all by
    hand from ``info``'s errors at every step of random actions."""
    config = EnvConfig(engine=engine, reward=reward, reward_scale=SCALE, tpm_cost=TPM_COST)
    core = TrackingCore(config, N)
    core.reset(np.arange(N), [5, 6, 7])
    shadow = stay_tpm(M, config.initial_stay)
    rng = np.random.default_rng(0)
    for _ in range(30):
        result = core.step(rng.uniform(-1, 1, (N, M * M)))
        assert not result.terminated.any()
        info = result.info
        e, e_s = info["position_error"], info["shadow_position_error"]
        assert np.all(np.abs(e_s - e) > 1e-9)  # the tracker and the shadow differ
        by_hand = {
            "error": -e / SCALE,
            "advantage": (e_s - e) / SCALE,
            "squared_advantage": (e_s**2 - e**2) / SCALE**2,
        }
        for name, value in by_hand.items():
            np.testing.assert_allclose(info[f"reward_{name}"], value, rtol=1e-12, atol=0)
        divergence = _divergence_by_hand(info["tpm"], shadow)
        assert np.all(divergence > 1e-6)  # the TPMs moved from the shadow's
        np.testing.assert_allclose(info["tpm_divergence"], divergence, rtol=1e-10, atol=0)
        np.testing.assert_allclose(
            result.reward, by_hand[reward] - TPM_COST * divergence, rtol=1e-10, atol=1e-15
        )
