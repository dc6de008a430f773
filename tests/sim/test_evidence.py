"""The measurement log-likelihood of an IMM and the features built from it: ``shadow_evidence``
(each measurement's evidence for the shadow's TPM against bank A's) and ``stay_evidence`` (for
a grid of stays, on the shadow's probabilities and likelihoods)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from imm_gym import EnvConfig, TrackingCore
from imm_gym.scenarios.catalog import SUITE_CONFIGS
from imm_gym.sim.config_file import read_env_config
from imm_gym.sim.features import (
    EVIDENCE_FACTORS,
    EVIDENCE_SCALE,
    EVIDENCE_STAYS,
    EVIDENCE_STEP_CLIP,
    FEATURES,
    STAY_EVIDENCE_FACTOR,
    evidence_stays,
    shadow_evidence_step,
    stay_evidence_step,
    stay_tpms,
)
from imm_gym.tracking.imm import measurement_loglik, update_mode_probs

M = 3


@settings(max_examples=200, deadline=None)
@given(
    loglik=arrays(np.float64, (4, M), elements=st.floats(-40.0, 10.0)),
    weights=arrays(np.float64, (4, M), elements=st.floats(1e-3, 1.0)),
)
def test_the_measurement_loglik_is_the_mode_update_normalizer(loglik, weights) -> None:
    cbar = weights / weights.sum(axis=-1, keepdims=True)
    value = measurement_loglik(loglik, cbar)
    np.testing.assert_allclose(value, np.log(np.sum(cbar * np.exp(loglik), axis=-1)),
                               rtol=1e-12, atol=1e-12)
    # mu_j = cbar_j Lambda_j / p(z): the posterior of update_mode_probs
    np.testing.assert_allclose(
        np.exp(loglik + np.log(cbar) - value[:, None]), update_mode_probs(loglik, cbar), atol=1e-12
    )


def test_a_missed_detection_carries_no_evidence() -> None:
    cbar = np.array([[0.2, 0.3, 0.5]])
    assert measurement_loglik(np.zeros((1, M)), cbar)[0] == 0.0
    # far-out log-likelihoods do not overflow: the log-sum-exp is shifted by the largest
    assert np.isclose(measurement_loglik(np.array([[-1e4, -1e4 + 1.0, -2e4]]), cbar)[0],
                      -1e4 + np.log(0.2 + 0.3 * np.e))


def _evidence_core(config: EnvConfig, n: int, feature: str = "shadow_evidence") -> TrackingCore:
    """A core of ``n`` slots observing only ``feature``, reset with seeds ``0..n-1``."""
    core = TrackingCore(config.replace(shadow="fixed", obs_features=(feature,)), n)
    core.reset(np.arange(n), list(range(n)))
    return core


def test_the_feature_by_hand_under_random_actions() -> None:
    core = _evidence_core(EnvConfig(action_mode="set", sensor={"detection_prob": 0.8}), 4)
    rng = np.random.default_rng(1)
    lam, total = np.asarray(EVIDENCE_FACTORS), np.zeros((4, len(EVIDENCE_FACTORS)))
    for _ in range(40):
        obs = core.step(rng.uniform(-1, 1, (4, core.action_dim))).obs
        step = measurement_loglik(core.loglik_s, core.cbar_s) - measurement_loglik(
            core.loglik, core.cbar
        )
        total = lam * total + np.clip(step, -EVIDENCE_STEP_CLIP, EVIDENCE_STEP_CLIP)[:, None]
        np.testing.assert_allclose(obs[:, 2 * M :], np.tanh(total / EVIDENCE_SCALE), atol=1e-6)
    assert np.abs(total).max() > 0.1  # the two trackers did disagree


def test_a_shadow_with_bank_a_s_tpm_has_no_evidence_either_way() -> None:
    # bank A at its fixed TPM (the zero action of the scale mode) and the shadow at the same TPM:
    # the same tracker twice, so every measurement is as likely under both
    config = EnvConfig(action_mode="scale", shadow_stay=None, sensor={"outlier_prob": 0.05})
    core = _evidence_core(config, 3)
    for _ in range(50):
        obs = core.step(np.zeros((3, core.action_dim))).obs
        assert np.all(obs[:, 2 * M :] == 0.0)


def test_the_evidence_points_to_the_tpm_that_tracks_better() -> None:
    """A uniform shadow against the classical IMM: on the paper scenario the uniform TPM tracks
    better (16.2 m against 18.1 m ARMSE over 100 runs) and the measurements say so; on the VSMM
    guide's S1 (300 m/s) it tracks worse (67.0 against 51.0 m) and they say that."""
    for name, sign in (("paper", 1.0), ("vsmm-s1", -1.0)):
        config = EnvConfig(**read_env_config(SUITE_CONFIGS / f"{name}.yaml"))
        core = _evidence_core(config.replace(shadow_stay=1.0 / 3.0, action_mode="scale"), 16)
        while not core.done.any():
            core.step(np.zeros((16, core.action_dim)))
        slow = core.memories["shadow_evidence"][:, 1]
        assert np.mean(sign * slow > 0) >= 0.9, (name, slow)


def test_the_stay_evidence_by_hand() -> None:
    config = EnvConfig(action_mode="set", shadow_stay=None, sensor={"detection_prob": 0.8})
    core = _evidence_core(config, 4, "stay_evidence")
    tpms = stay_tpms(M)
    assert tpms.shape == (1 + len(EVIDENCE_STAYS), M, M)
    np.testing.assert_allclose(tpms[0], 1.0 / M)
    np.testing.assert_allclose(np.diagonal(tpms[1:], axis1=1, axis2=2)[:, 0], EVIDENCE_STAYS)
    rng = np.random.default_rng(2)
    total = np.zeros((4, len(tpms)))
    for _ in range(40):
        mu_s = core.mu_s.copy()
        obs = core.step(rng.uniform(-1, 1, (4, core.action_dim))).obs
        e = np.stack([np.log(np.sum((mu_s @ tpm) * np.exp(core.loglik_s), axis=1))
                      for tpm in tpms], axis=1)
        total = STAY_EVIDENCE_FACTOR * total + np.maximum(
            e - e.max(axis=1, keepdims=True), -EVIDENCE_STEP_CLIP
        )
        expected = np.tanh((total - total.max(axis=1, keepdims=True)) / EVIDENCE_SCALE)
        np.testing.assert_allclose(obs[:, 2 * M :], expected, atol=1e-6)
    assert expected.min() < -0.1  # the stays were told apart


def test_one_step_moves_a_stays_evidence_by_at_most_the_clip() -> None:
    """A step whose measurement only the (unlikely) sticky stays cannot explain: the shadow was
    sure of model 2, the measurement fits models 0 and 1 (log-likelihoods -2, -2, -80). Stay
    s's evidence is log((1 - s) e^-2 + s e^-80) minus the best's, floored at -EVIDENCE_STEP_CLIP
    (the stays 0.98 and 0.995, at -3.9 and -4.9 nats unfloored)."""
    view = SimpleNamespace(mu_s_prev=np.array([[0.0, 0.0, 1.0]]),
                           loglik_s=np.array([[-2.0, -2.0, -80.0]]))
    stays = np.array([1 / 3, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995])
    e = np.logaddexp(np.log1p(-stays) - 2.0, np.log(stays) - 80.0)
    expected = np.maximum(e - e.max(), -EVIDENCE_STEP_CLIP)
    assert expected[-1] == -EVIDENCE_STEP_CLIP and (e - e.max())[-1] < -4.8
    np.testing.assert_allclose(stay_evidence_step(view)[0], expected, rtol=1e-12, atol=1e-12)


def test_the_stay_evidence_points_to_the_stay_that_tracks_better() -> None:
    """The classical IMM as the shadow: the paper scenario's measurements support a low stay
    (the best fixed TPM there is the uniform one), the 300 m/s target of the VSMM guide's S1 a
    high one (its best fixed stay is above 0.9)."""
    stays = np.array([1.0 / M, *EVIDENCE_STAYS])
    for name, low in (("paper", True), ("vsmm-s1", False)):
        config = EnvConfig(**read_env_config(SUITE_CONFIGS / f"{name}.yaml"))
        core = _evidence_core(
            config.replace(shadow_stay=None, action_mode="scale"), 16, "stay_evidence"
        )
        while not core.done.any():
            core.step(np.zeros((16, core.action_dim)))
        best = stays[core.memories["stay_evidence"].argmax(axis=1)]
        assert np.mean(best <= 0.8 if low else best >= 0.9) >= 0.8, (name, best)


def test_one_step_moves_the_shadow_evidence_by_at_most_the_clip_either_way() -> None:
    """Bank A sure of model 0, the shadow of model 2: a measurement that fits model 0 (slot 0,
    log-likelihoods 0, -20, -20) is evidence against the shadow's TPM, one that fits model 2
    (slot 1) for it, each of about 20 nats, floored and capped at ``±EVIDENCE_STEP_CLIP``; a
    measurement that fits every model alike (slot 2) is evidence of ``log 1 = 0``, and one that
    fits models 0 and 1 (slot 3) is ``log 0.5`` against the shadow (which weighs them 0.5)."""
    cbar = np.array([[1.0, 1e-12, 1e-12]] * 4)
    cbar_s = np.array([[1e-12, 1e-12, 1.0]] * 3 + [[0.25, 0.25, 0.5]])
    loglik = np.array([[0.0, -20.0, -20.0], [-20.0, -20.0, 0.0], [-1.0] * 3, [-1.0, -1.0, -30.0]])
    view = SimpleNamespace(loglik=loglik, cbar=cbar, loglik_s=loglik, cbar_s=cbar_s)
    by_hand = np.log(np.sum(cbar_s * np.exp(loglik), axis=1)) - np.log(
        np.sum(cbar * np.exp(loglik), axis=1)
    )
    assert by_hand[0] < -19.0 and by_hand[1] > 19.0
    expected = [-EVIDENCE_STEP_CLIP, EVIDENCE_STEP_CLIP, 0.0, by_hand[3]]
    np.testing.assert_allclose(by_hand[3], np.log(0.5), atol=1e-6)
    np.testing.assert_allclose(shadow_evidence_step(view), expected, rtol=1e-9, atol=1e-9)


def test_the_stay_evidence_is_discounted_by_0_97_a_step() -> None:
    """The memory's advance by hand (the feature's documented λ = 0.97): a measurement every
    model fits alike adds nothing, so ``-1`` becomes ``-0.97``; the measurement of the clip's
    example adds each stay's floored evidence."""
    advance = FEATURES["stay_evidence"].memory.advance
    even = SimpleNamespace(mu_s_prev=np.array([[0.2, 0.3, 0.5]]), loglik_s=np.full((1, M), -4.0))
    np.testing.assert_allclose(advance(np.full((1, 7), -1.0), even), np.full((1, 7), -0.97),
                               rtol=1e-12)
    view = SimpleNamespace(mu_s_prev=np.array([[0.0, 0.0, 1.0]]),
                           loglik_s=np.array([[-2.0, -2.0, -80.0]]))
    stays = np.array([1 / 3, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995])
    e = np.logaddexp(np.log1p(-stays) - 2.0, np.log(stays) - 80.0)
    before = np.linspace(-2.0, 0.0, 7)[None]
    np.testing.assert_allclose(advance(before, view), 0.97 * before + np.maximum(e - e.max(), -3),
                               rtol=1e-12, atol=1e-12)


def test_the_shadow_evidence_is_discounted_by_0_9_and_0_97_a_step() -> None:
    """The memory's advance by hand (the feature's documented λ = 0.9, 0.97): a shadow that
    predicts the measurement as bank A does adds nothing, so ``[2, -2]`` becomes
    ``[1.8, -1.94]``."""
    advance = FEATURES["shadow_evidence"].memory.advance
    loglik, cbar = np.array([[-3.0, -1.0, -7.0]]), np.array([[0.2, 0.3, 0.5]])
    view = SimpleNamespace(loglik=loglik, cbar=cbar, loglik_s=loglik, cbar_s=cbar)
    np.testing.assert_allclose(advance(np.array([[2.0, -2.0]]), view), [[1.8, -1.94]],
                               rtol=1e-12)


def test_the_evidence_blocks_are_tanh_of_a_quarter_of_the_sums() -> None:
    """4 nats of evidence read tanh(1) ≈ 0.76: the shadow's sums ``[4, -8]`` are
    ``tanh(1), tanh(-2)``; the stays' sums are taken from the best's first, so ``[-1, 3, -5]``
    reads ``tanh(-1), 0, tanh(-2)``."""
    shadow = FEATURES["shadow_evidence"].observe(
        SimpleNamespace(memories={"shadow_evidence": np.array([[4.0, -8.0]])})
    )
    np.testing.assert_allclose(shadow, [[math.tanh(1.0), math.tanh(-2.0)]], rtol=1e-12)
    stays = FEATURES["stay_evidence"].observe(
        SimpleNamespace(memories={"stay_evidence": np.array([[-1.0, 3.0, -5.0]])})
    )
    np.testing.assert_allclose(stays, [[math.tanh(-1.0), 0.0, math.tanh(-2.0)]], rtol=1e-12)


def test_the_stays_weighed_are_the_documented_grid() -> None:
    """The uniform stay ``1/M``, then 0.6, 0.8, 0.9, 0.95, 0.98 and 0.995 (the features'
    descriptions); each TPM spreads the rest of its rows evenly."""
    grid = [1 / 4, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995]
    np.testing.assert_allclose(evidence_stays(4), grid, rtol=1e-15)
    tpms = stay_tpms(4)
    off = 0.005 / 3
    np.testing.assert_allclose(tpms[-1], np.full((4, 4), off) + np.eye(4) * (0.995 - off),
                               rtol=1e-12)
