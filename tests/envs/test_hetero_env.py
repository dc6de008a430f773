"""The environments with the heterogeneous NCV/CT/CTRA bank (imm_gym/TPMAdaptHetero-v0)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from imm_gym import ConfigError, EnvConfig, TrackingCore
from imm_gym.tracking.hetero import SONAR_HETERO_BANK, HeteroBank, HeteroIMM

ENV_ID = "imm_gym/TPMAdaptHetero-v0"


def test_hetero_id_runs_the_heterogeneous_imm() -> None:
    env = gym.make(ENV_ID)
    core = env.unwrapped.core
    assert isinstance(core.imm, HeteroIMM)
    assert [m.kind for m in core.imm.models] == ["ncv", "ct", "ctra"]
    obs, info = env.reset(seed=3)
    assert obs.shape == env.observation_space.shape
    total = 0.0
    for _ in range(150):
        obs, reward, terminated, truncated, info = env.step(np.zeros(9, dtype=np.float32))
        total += reward
        assert env.observation_space.contains(obs)
        assert info["estimate"].shape == (4,)
        if terminated or truncated:
            break
    assert truncated and not terminated
    assert info["position_error"] < 200.0
    assert total == pytest.approx(0.0, abs=1e-9)  # zero action = the shadow classical IMM
    env.close()


def test_hetero_scalar_and_vector_env_agree() -> None:
    env = gym.make(ENV_ID)
    venv = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point")
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=11)
    vobs, _ = venv.reset(seed=10)
    np.testing.assert_array_equal(obs, vobs[1])
    for _ in range(20):
        a = rng.uniform(-1, 1, size=(2, 9)).astype(np.float32)
        obs, r, *_ = env.step(a[1])
        vobs, vr, *_ = venv.step(a)
        np.testing.assert_array_equal(obs, vobs[1])
        assert r == vr[1]
    env.close()
    venv.close()


def test_true_model_of_the_heterogeneous_bank() -> None:
    core = TrackingCore(EnvConfig(bank=SONAR_HETERO_BANK, filter="ekf", scenario="paper"))
    core.reset(np.array([0]), [0])
    tm = core.true_model[0]
    assert set(np.unique(tm)) == {0, 1}  # straight -> NCV, turns -> CT (no acceleration here)
    assert tm[0] == 0 and tm[50] == 1


def test_heterogeneous_env_config_is_validated() -> None:
    with pytest.raises(ConfigError, match="ekf"):
        EnvConfig(bank=SONAR_HETERO_BANK)  # default filter is the UKF
    with pytest.raises(ConfigError, match="unknown key"):
        EnvConfig(bank={"modles": ("ncv", "ct")}, filter="ekf")
    cfg = EnvConfig(bank=HeteroBank(q_scale=(1.0, 2.0, 0.5)), filter="ekf")
    assert cfg.bank.q_scale == (1.0, 2.0, 0.5)


def test_hetero_parallel_banks_fuse_in_cartesian_space() -> None:
    """Bank B and entropy fusion (TIP-IMM §3.3) with the heterogeneous bank: the output is
    bank A's models combined with the fused probabilities in the common Cartesian state."""
    core = TrackingCore(EnvConfig(bank=SONAR_HETERO_BANK, filter="ekf", parallel=True), 1)
    core.reset(np.array([0]), [5])
    for _ in range(30):
        res = core.step(np.zeros((1, 9)))
    x, P = core.imm.combine(core.state_a.mu, core.state_a.x, core.state_a.P)
    np.testing.assert_allclose(res.info["estimate"], x)
    np.testing.assert_allclose(res.info["covariance"], P)
    assert res.info["position_error"][0] < 200.0
