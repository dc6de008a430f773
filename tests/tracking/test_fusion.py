"""Entropy fusion of the parallel banks (SPEC §4, eqs. 18-19; §6 feedback) by hand and inside
the parallel environment."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from imm_gym import IMM, IMMState, Sonar, combine, draw_batch, paper_bank, stay_tpm
from imm_gym.envs import TPMAdaptEnv, TPMAdaptVectorEnv
from imm_gym.sim.kernels import _fuse_into
from imm_gym.tracking.fusion import entropy, fuse


def h_bits(u: list[float]) -> float:
    return -sum(p * math.log2(p) for p in u if p > 0)


def test_entropy_by_hand() -> None:
    assert entropy(np.array([1.0, 0.0, 0.0])) == 0.0
    np.testing.assert_allclose(entropy(np.array([0.5, 0.5])), 1.0, rtol=1e-15)
    np.testing.assert_allclose(entropy(np.full(3, 1 / 3)), math.log2(3), rtol=1e-15)
    np.testing.assert_allclose(entropy(np.full(4, 0.25)), 2.0, rtol=1e-15)
    u = np.array([[0.7, 0.2, 0.1], [0.6, 0.4, 0.0]])
    np.testing.assert_allclose(entropy(u), [h_bits([0.7, 0.2, 0.1]), h_bits([0.6, 0.4])])


@pytest.mark.parametrize(
    ("u_a", "u_b"),
    [
        ([0.7, 0.2, 0.1], [0.4, 0.3, 0.3]),
        ([0.05, 0.9, 0.05], [0.3, 0.3, 0.4]),
        ([0.2, 0.2, 0.6], [0.98, 0.01, 0.01]),
        ([1 / 3, 1 / 3, 1 / 3], [0.5, 0.25, 0.25]),
    ],
)
def test_fuse_against_eq_19_by_hand(u_a: list[float], u_b: list[float]) -> None:
    ha, hb = h_bits(u_a), h_bits(u_b)
    expected = [hb / (ha + hb) * a + ha / (ha + hb) * b for a, b in zip(u_a, u_b, strict=True)]
    out = fuse(np.array([u_a]), np.array([u_b]))
    np.testing.assert_allclose(out[0], expected, rtol=1e-13)
    assert abs(out.sum() - 1.0) <= 1e-15
    # the more certain bank (lower entropy) weighs more
    closer_to_a = np.abs(out[0] - u_a).sum() < np.abs(out[0] - u_b).sum()
    assert closer_to_a == (ha < hb)


def test_fuse_edge_cases() -> None:
    e = np.eye(3)
    # both banks certain: equal weights
    np.testing.assert_array_equal(fuse(e[:1], e[1:2]), [[0.5, 0.5, 0.0]])
    np.testing.assert_array_equal(fuse(e[2:3], e[2:3]), e[2:3])
    # one bank certain: it takes all the weight
    np.testing.assert_allclose(fuse(e[:1], np.array([[0.2, 0.5, 0.3]])), e[:1], atol=0)
    np.testing.assert_allclose(fuse(np.array([[0.2, 0.5, 0.3]]), e[1:2]), e[1:2], atol=0)
    # identical inputs are a fixed point; symmetric in its arguments
    u = np.array([[0.6, 0.3, 0.1]])
    np.testing.assert_allclose(fuse(u, u), u, rtol=1e-15)
    v = np.array([[0.1, 0.1, 0.8]])
    np.testing.assert_allclose(fuse(u, v), fuse(v, u), rtol=1e-15)


def test_compiled_fusion_equals_fuse_on_the_edge_cases() -> None:
    """The compiled engine's fusion (kernels._fuse_into, slot by slot) against :func:`fuse` on
    the edge cases above and on a vector with an exact zero (0 log 0 = 0): two certain banks
    get equal weights, a zero probability adds no entropy."""
    e = np.eye(3)
    u, v = [0.6, 0.3, 0.1], [0.1, 0.1, 0.8]
    pairs = [
        (e[0], e[1]), (e[2], e[2]), (e[0], [0.2, 0.5, 0.3]), ([0.2, 0.5, 0.3], e[1]), (u, u),
        (u, v), (v, u), ([0.7, 0.3, 0.0], [0.2, 0.3, 0.5]), ([0.2, 0.3, 0.5], [0.0, 0.4, 0.6]),
    ]
    u_a = np.array([a for a, _ in pairs], dtype=float)
    u_b = np.array([b for _, b in pairs], dtype=float)
    got = np.empty_like(u_a)
    for t in range(len(pairs)):
        _fuse_into(t, u_a, u_b, got)
    expected = fuse(u_a, u_b)
    np.testing.assert_allclose(got, expected, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(got[0], [0.5, 0.5, 0.0])
    # eq. 19 by hand for the zero entry: H(0.7, 0.3, 0) weighs u_b, H(0.2, 0.3, 0.5) u_a
    h_a, h_b = h_bits([0.7, 0.3]), h_bits([0.2, 0.3, 0.5])
    by_hand = (h_b * u_a[7] + h_a * u_b[7]) / (h_a + h_b)
    np.testing.assert_allclose(got[7], by_hand, rtol=1e-14)


@settings(max_examples=100, deadline=None)
@given(
    a=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3).filter(lambda x: sum(x) > 1e-6),
    b=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3).filter(lambda x: sum(x) > 1e-6),
)
def test_fuse_is_a_probability_vector_between_its_inputs(a, b) -> None:
    u_a = np.array([a]) / sum(a)
    u_b = np.array([b]) / sum(b)
    out = fuse(u_a, u_b)
    assert np.all(np.isfinite(out)) and np.all(out >= 0.0)
    assert abs(out.sum() - 1.0) <= 1e-12
    lo, hi = np.minimum(u_a, u_b), np.maximum(u_a, u_b)
    assert np.all(out >= lo - 1e-12) and np.all(out <= hi + 1e-12)


def test_parallel_env_runs_two_banks_fused_with_feedback() -> None:
    """Replay the parallel env with the IMM directly: bank A runs the TPM of ``info["tpm"]``, bank
    B the fixed TPM; ``U = fuse(mu_A, mu_B)`` replaces both banks' probabilities (SPEC §6) and the
    output is bank A's model estimates weighted by ``U``."""
    seed = 6
    env = TPMAdaptEnv(scenario="paper", parallel=True, p_min=0.05, obs_features=("bank_b", "tpm"))
    env.reset(seed=seed)
    config = env.config
    batch = draw_batch(config.source, config.sensor, 1, seed)
    imm = IMM(paper_bank(), Sonar())
    fixed = stay_tpm(3, 0.995)
    state_a = state_b = imm.init(batch.x0, batch.P0)
    rng = np.random.default_rng(0)
    prev_u = np.full(3, 1 / 3)
    differs = 0
    for k in range(1, 151):
        obs, *_, info = env.step(rng.uniform(-1, 1, 9))
        z = batch.measurements.z[:, k]
        det = batch.measurements.detected[:, k]
        state_a, out_a = imm.step(state_a, info["tpm"][None], z, det)
        state_b, out_b = imm.step(state_b, fixed, z, det)
        u = fuse(out_a.mode_probs, out_b.mode_probs)
        x_hat, _ = combine(u, state_a.x, state_a.P)
        np.testing.assert_allclose(info["mode_probs"], u[0], rtol=1e-12, atol=1e-15)
        # rounding of the two combinations: relative to the state's scale (a velocity near 0
        # is a difference of the models' velocities)
        np.testing.assert_allclose(
            info["estimate"], x_hat[0], rtol=1e-12, atol=1e-12 * np.abs(x_hat).max()
        )
        np.testing.assert_allclose(obs[:3], u[0], rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(obs[3:6], prev_u, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(obs[6:9], out_b.mode_probs[0], rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(obs[9:], info["tpm"].ravel(), rtol=1e-6, atol=1e-7)
        assert abs(float(obs[:3].sum(dtype=np.float64)) - 1.0) < 1e-5
        differs += not np.allclose(obs[6:9], obs[:3], atol=1e-4)
        # feedback: the fused probabilities replace both banks' before the next mixing
        state_a = IMMState(state_a.x, state_a.P, u)
        state_b = IMMState(state_b.x, state_b.P, u.copy())
        prev_u = u[0]
    assert differs > 20  # bank B's probabilities are not the fused ones


def test_parallel_fused_probabilities_in_the_vector_env() -> None:
    venv = TPMAdaptVectorEnv(
        8, config={"scenario": "random", "parallel": True, "obs_features": ("bank_b",)}
    )
    obs, _ = venv.reset(seed=0)
    rng = np.random.default_rng(1)
    for _ in range(30):
        obs, *_, info = venv.step(rng.uniform(-1, 1, (8, 9)))
        np.testing.assert_allclose(obs[:, :3].sum(axis=1), 1.0, atol=1e-5)
        np.testing.assert_allclose(obs[:, 6:9].sum(axis=1), 1.0, atol=1e-5)
        np.testing.assert_allclose(info["mode_probs"].sum(axis=1), 1.0, atol=1e-12)
    assert not np.allclose(obs[:, 6:9], obs[:, :3], atol=1e-4)
