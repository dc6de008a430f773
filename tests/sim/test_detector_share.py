"""A switching prior whose jumps follow a maneuver detector (``EnvConfig.detector_share``,
:func:`imm_gym.sim.stay_bank.detector_tpm_rows`): the rows by hand and against the stay rows,
the predicted mode probabilities they give, the zero action of a core on both engines, the stay
action's clip around a base that leans a row away from its mode, and the configuration's checks."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import stay_core
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from imm_gym import EnvConfig, TrackingCore
from imm_gym.evaluation.rollout import evaluation_config
from imm_gym.sim import kernels
from imm_gym.sim.actions import tpm_from_action
from imm_gym.sim.stay_bank import detector_tpm_rows
from imm_gym.tracking.tpm import stay_tpm_rows
from imm_gym.validation import ConfigError

M = 3


def test_the_rows_by_hand() -> None:
    # s = 0.8: keep r = (0.8 - 1/3) / (2/3) = 0.7; q = 0.25 / 3 + 0.75 (0.6, 0.3, 0.1)
    belief = np.array([[0.6, 0.3, 0.1]])
    q = np.array([0.25 / 3 + 0.45, 0.25 / 3 + 0.225, 0.25 / 3 + 0.075])
    expected = 0.3 * np.tile(q, (3, 1)) + 0.7 * np.eye(3)
    rows = detector_tpm_rows(np.array([0.8]), belief, 0.75)
    np.testing.assert_allclose(rows[0], expected, rtol=1e-14)
    assert rows[0, 2, 0] > rows[0, 2, 1]  # a row leaves toward the detector's mode



def test_one_share_per_prior_by_hand() -> None:
    """``share`` may be one per prior: prior 0 at v = 0 is the evenly spread stay row, prior 1
    at v = 1 redraws from the belief alone, prior 2 at v = 0.75 is the row by hand above (the
    shares are not spread over the models' columns)."""
    belief = np.array([[0.6, 0.3, 0.1], [0.2, 0.5, 0.3], [0.6, 0.3, 0.1]])
    rows = detector_tpm_rows(np.full(3, 0.8), belief, np.array([0.0, 1.0, 0.75]))
    np.testing.assert_allclose(rows[0], stay_tpm_rows(np.array([0.8]), M)[0], rtol=1e-14)
    np.testing.assert_allclose(rows[1], 0.3 * np.tile(belief[1], (3, 1)) + 0.7 * np.eye(3),
                               rtol=1e-14)
    q = np.array([0.25 / 3 + 0.45, 0.25 / 3 + 0.225, 0.25 / 3 + 0.075])
    np.testing.assert_allclose(rows[2], 0.3 * np.tile(q, (3, 1)) + 0.7 * np.eye(3), rtol=1e-14)

@settings(max_examples=200, deadline=None)
@given(
    stays=arrays(np.float64, 4, elements=st.floats(1.0 / M, 1.0)),
    raw=arrays(np.float64, (4, M), elements=st.floats(1e-6, 1.0)),
    share=st.floats(0.0, 1.0),
    mu=arrays(np.float64, (4, M), elements=st.floats(1e-6, 1.0)),
)
def test_the_rows_are_a_switching_prior_leaning_toward_the_detector(stays, raw, share, mu) -> None:
    belief = raw / raw.sum(axis=1, keepdims=True)
    rows = detector_tpm_rows(stays, belief, share)
    assert np.all(rows >= 0.0)
    np.testing.assert_allclose(rows.sum(axis=-1), 1.0, rtol=0, atol=1e-14)
    # the predicted mode probabilities: c = r mu + (1 - r) q
    mu = mu / mu.sum(axis=1, keepdims=True)
    keep = (stays - 1.0 / M) / (1.0 - 1.0 / M)
    q = (1.0 - share) / M + share * belief
    cbar = np.einsum("ni,nij->nj", mu, rows)
    np.testing.assert_allclose(cbar, keep[:, None] * mu + (1 - keep[:, None]) * q, atol=1e-14)
    # no share, or a detector that knows nothing: the evidence's stay rows
    uniform = np.full((4, M), 1.0 / M)
    plain = stay_tpm_rows(stays, M)
    np.testing.assert_allclose(detector_tpm_rows(stays, belief, 0.0), plain, atol=1e-15)
    np.testing.assert_allclose(detector_tpm_rows(stays, uniform, share), plain, atol=1e-15)


def _core(n: int, engine: str = "auto", **changes: object) -> TrackingCore:
    """:func:`tests.helpers.stay_core` with the evidence base and half of the jumps led by the
    shadow IMM."""
    return stay_core(n, engine, **{"stay_base": "evidence", "detector_share": 0.5, **changes})


def test_the_zero_action_is_the_evidence_s_stay_with_the_shadow_s_jumps() -> None:
    core = _core(3)
    leaned = 0
    for _ in range(60):
        expected = detector_tpm_rows(core.stay_bank.centre(), core.mu_s, 0.5)
        tpm = core.step(np.zeros((3, M))).info["tpm"]
        np.testing.assert_allclose(tpm, expected, rtol=0, atol=1e-15)
        off = tpm[:, ~np.eye(M, dtype=bool)].reshape(3, M, M - 1)
        leaned += int(np.sum(np.ptp(off, axis=-1) > 0.05))
    assert leaned > 0  # the jumps were not spread evenly


def test_both_engines_step_the_same() -> None:
    fused, general = _core(3), _core(3, "numpy")
    rng = np.random.default_rng(5)
    for _ in range(60):
        action = rng.uniform(-1, 1, (3, M))
        a, b = fused.step(action), general.step(action)
        np.testing.assert_allclose(a.info["tpm"], b.info["tpm"], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(a.obs, b.obs, atol=1e-6)


def test_a_small_action_moves_a_leaning_row_a_little() -> None:
    """The stay modes keep a stay at or above 1/M only where the base's is: a base row whose
    stay is below 1/M (it leans toward the detector's mode) moves continuously with the action,
    in the numpy reference and in the compiled kernel alike."""
    base = detector_tpm_rows(np.array([0.4, 0.4]), np.array([[0.9, 0.05, 0.05]] * 2), 1.0)
    assert base[0, 1, 1] < 1.0 / M
    config = EnvConfig(action_mode="stay", stay_base="evidence", logit_scale=6.0, p_min=1e-4)
    tpm = np.repeat(np.eye(M)[None], 2, axis=0)
    for a in (1e-7, -1e-7):
        action = np.full((2, M), a)
        ref = tpm_from_action(action, tpm, config, base)
        fast = kernels.tpm_from_action(action, tpm, kernels.STAY, 6.0, 1e-4, base)
        np.testing.assert_allclose(ref, base, atol=1e-5)
        np.testing.assert_allclose(fast, ref, rtol=1e-12, atol=1e-15)
    # a large negative action still stops at the base's own stay, not above it
    low = tpm_from_action(np.full((2, M), -1.0), tpm, config, base)
    np.testing.assert_allclose(np.diagonal(low, axis1=1, axis2=2)[:, 1], base[:, 1, 1], rtol=1e-12)


def test_the_configuration_names_what_the_share_needs() -> None:
    with pytest.raises(ConfigError, match=r"detector_share must be in \[0.0, 1.0\]"):
        EnvConfig(action_mode="stay", stay_base="evidence", detector_share=1.5)
    with pytest.raises(ConfigError, match="detector_share > 0 needs action_mode 'stay'"):
        EnvConfig(detector_share=0.5)
    with pytest.raises(ConfigError, match="need shadow 'fixed'"):
        EnvConfig(action_mode="stay", stay_base="evidence", detector_share=0.5, shadow="none")


def test_the_evaluation_keeps_the_detector() -> None:
    base = EnvConfig()
    overrides = {"action_mode": "stay", "stay_base": "evidence", "detector_share": 0.5}
    assert evaluation_config(base, overrides).shadow == "fixed"
    assert evaluation_config(base, {"action_mode": "stay"}).shadow == "none"


def test_the_stay_bank_weighs_the_detector_priors() -> None:
    # the reference: each stay's IMM alone on the numpy engine with the prior of its stay and
    # the shadow's probabilities before each step, the evidence summed directly
    from imm_gym.sim.stay_bank import STAY_BANK_FACTOR, STAY_BANK_FLOOR
    from imm_gym.tracking.hetero import make_tracker

    core = _core(2)
    bank = core.stay_bank
    reference = make_tracker(core.config.bank, core.config.sensor, "ukf", 1.0, engine="numpy")
    states = [core.state_a for _ in bank.stays]
    total = np.zeros((2, bank.S))
    rng = np.random.default_rng(1)
    for _ in range(50):
        k1 = core.k + 1
        z, det = core.z[np.arange(2), k1], core.detected[np.arange(2), k1]
        e = np.zeros((2, bank.S))
        for s, stay in enumerate(bank.stays):
            prior = detector_tpm_rows(np.tile(stay, (2, 1)), core.mu_s, 0.5)
            states[s], out = reference.step(states[s], prior, z, det)
            e[:, s] = np.where(det, np.log(np.sum(out.cbar * np.exp(out.loglik), axis=1)), 0.0)
        total = STAY_BANK_FACTOR * total + np.maximum(
            e - e.max(axis=1, keepdims=True), -STAY_BANK_FLOOR
        )
        core.step(rng.uniform(-1, 1, (2, M)))
        np.testing.assert_allclose(bank.evidence, total, rtol=1e-9, atol=1e-9)
    assert np.ptp(total) > 1.0


def test_the_uniform_base_is_the_detector_s_prior_alone() -> None:
    core = _core(2, stay_base="uniform")
    for _ in range(20):
        expected = detector_tpm_rows(np.full(2, 1.0 / M), core.mu_s, 0.5)
        tpm = core.step(np.zeros((2, M))).info["tpm"]
        np.testing.assert_allclose(tpm, expected, rtol=0, atol=1e-15)
    # every row is the same prediction q: the mode redrawn each step from the detector's lean
    np.testing.assert_allclose(tpm[:, 0], tpm[:, 2], rtol=0, atol=1e-15)
    assert TrackingCore(EnvConfig(action_mode="stay", stay_base="uniform")).stay_bank is None


def test_the_tracker_base_keeps_the_tracker_s_stays_of_at_least_one_over_m() -> None:
    """``stay_base="tracker"`` with a share: the base is :func:`detector_tpm_rows` of the
    tracker's own stays raised to 1/M, by hand from ``initial_stay`` (0.9 and 0.6 kept, 0.2
    raised to 1/3): at the reset, whose shadow probabilities are uniform, its diagonal is those
    stays; later, the rows of those stays leaning toward the shadow's probabilities."""
    config = EnvConfig(action_mode="stay", detector_share=0.5, initial_stay=(0.9, 0.2, 0.6))
    core = TrackingCore(config, 2)
    core.reset(np.arange(2), [0, 1])
    fixed = np.diagonal(core.fixed_tpms, axis1=1, axis2=2)
    np.testing.assert_array_equal(fixed, np.tile([0.9, 0.2, 0.6], (2, 1)))
    stays = np.tile([0.9, 1.0 / M, 0.6], (2, 1))
    base = np.diagonal(core.stay_base_tpms, axis1=1, axis2=2)
    np.testing.assert_allclose(base, stays, rtol=1e-14)
    rng = np.random.default_rng(2)
    for _ in range(20):
        core.step(rng.uniform(-1, 1, (2, M)))
        expected = detector_tpm_rows(stays, core.mu_s, 0.5)
        np.testing.assert_allclose(core.stay_base_tpms, expected, rtol=0, atol=1e-15)
