"""The turn-rate detector (imm_gym.sim.detectors): its belief by hand and as an interpolation,
the core's smoothed turn rate against the estimates it reports, the zero action's TPM, and the
configuration's errors."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from imm_gym import EnvConfig
from imm_gym.sim.detectors import (
    model_turn_rates,
    true_turn_rates,
    turn_rate_belief,
)
from imm_gym.sim.features import heading_rate
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.sim.stay_bank import detector_tpm_rows
from imm_gym.validation import ConfigError
from tests.helpers import stay_core

M = 3
PAPER_RATES = np.radians([0.0, 4.0, -4.0])  # CV, CT(+4 °/s), CT(-4 °/s)


def test_the_belief_by_hand() -> None:
    rates = np.radians([0.0, 1.0, -2.0, 4.0, -8.0, 3.0])
    expected = np.array([
        [1.0, 0.0, 0.0],
        [0.75, 0.25, 0.0],  # a quarter of the way to CT(+4)
        [0.5, 0.0, 0.5],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],  # beyond the bank's fastest turn: that turn
        [0.25, 0.75, 0.0],
    ])
    np.testing.assert_allclose(turn_rate_belief(rates, PAPER_RATES), expected, atol=1e-15)


def test_true_turn_rates_are_the_heading_changes() -> None:
    T, omega = 2.0, np.array([0.0, 0.01, -0.03])
    heading = np.concatenate([[3.1], 3.1 + np.cumsum(omega * T)])  # crosses +-pi
    truth = np.zeros((1, 4, 4))
    truth[0, :, 2], truth[0, :, 3] = 20.0 * np.cos(heading), 20.0 * np.sin(heading)
    np.testing.assert_allclose(true_turn_rates(truth, T)[0], omega, atol=1e-12)
    np.testing.assert_allclose(true_turn_rates(np.repeat(truth, 2, 0), np.array([T, 2 * T])),
                               [omega, omega / 2], atol=1e-12)


def test_models_of_one_rate_share_its_weight() -> None:
    rates = np.radians([1.0, 0.0])
    two_cv = np.radians([0.0, 0.0, 4.0])
    np.testing.assert_allclose(
        turn_rate_belief(rates, two_cv), [[0.375, 0.375, 0.25], [0.5, 0.5, 0.0]], atol=1e-15
    )
    np.testing.assert_array_equal(turn_rate_belief(rates, np.zeros(2)), np.full((2, 2), 0.5))


@settings(max_examples=200, deadline=None)
@given(
    rates=arrays(np.float64, 5, elements=st.floats(-0.2, 0.2)),
    omegas=arrays(np.float64, 4, elements=st.floats(-0.1, 0.1), unique=True),
)
def test_the_belief_interpolates_the_turn_rate(rates, omegas) -> None:
    belief = turn_rate_belief(rates, omegas)
    assert np.all(belief >= 0.0)
    np.testing.assert_allclose(belief.sum(axis=1), 1.0, atol=1e-12)
    # the belief's mean turn rate is the rate, clipped to the bank's
    clipped = np.clip(rates, omegas.min(), omegas.max())
    np.testing.assert_allclose(belief @ omegas, clipped, atol=1e-12)
    # at most two models, neighbours in turn rate, carry weight
    order = np.argsort(omegas)
    for row in belief[:, order]:
        carried = np.flatnonzero(row > 0.0)
        assert carried.size <= 2 and (carried.size < 2 or carried[1] - carried[0] == 1)


def _core(n: int, **changes: object):
    return stay_core(
        n, **{"stay_base": "evidence", "detector_share": 0.5, "detector": "turn_rate", **changes}
    )


def test_the_core_smooths_the_heading_rate_of_its_estimate() -> None:
    """``w(t) = lam w(t-1) + (1 - lam) psi_dot(t)`` with the documented ``lam = 0.7`` (README,
    ``detector: turn_rate``)."""
    core = _core(2)
    rate = np.zeros(2)
    velocity = core.velocity.copy()
    for _ in range(40):
        info = core.step(np.random.default_rng(0).uniform(-1, 1, (2, M))).info
        new = info["estimate"][:, 2:4]
        rate = 0.7 * rate + 0.3 * heading_rate(velocity, new, 1.0)
        velocity = new
        np.testing.assert_allclose(core.turn_rate_estimate, rate, rtol=1e-12, atol=1e-15)
    assert np.any(np.abs(rate) > 1e-3)


def test_the_zero_action_leans_the_evidence_s_stay_toward_the_turn_rate() -> None:
    core = _core(3)
    leaned = 0
    for _ in range(60):
        belief = turn_rate_belief(core.turn_rate_estimate, PAPER_RATES)
        np.testing.assert_array_equal(core.detector_belief, belief)
        expected = detector_tpm_rows(core.stay_bank.centre(), belief, 0.5)
        tpm = core.step(np.zeros((3, M))).info["tpm"]
        np.testing.assert_allclose(tpm, expected, rtol=0, atol=1e-15)
        leaned += int(np.sum(belief.max(axis=1) < 0.99))
    assert leaned > 0


def test_the_shadow_detector_is_the_default() -> None:
    core = stay_core(2, stay_base="evidence", detector_share=0.5)
    assert core.config.detector == "shadow"
    np.testing.assert_array_equal(core.detector_belief, core.mu_s)


def test_the_configuration_names_what_the_detector_needs() -> None:
    with pytest.raises(ConfigError, match="detector must be one of"):
        EnvConfig(action_mode="stay", stay_base="evidence", detector_share=0.5, detector="imm")
    with pytest.raises(ConfigError, match="detector_share must be in \\(0, 1\\], got 0"):
        EnvConfig(action_mode="stay", stay_base="evidence", detector="turn_rate")
    with pytest.raises(ConfigError, match="detector 'turn_rate' needs a linear bank"):
        EnvConfig(**BANK_PRESETS["hetero"], action_mode="stay", stay_base="uniform",
                  detector_share=0.5, detector="turn_rate")
    # the turn rate needs no shadow IMM
    config = EnvConfig(action_mode="stay", stay_base="uniform", detector_share=0.5,
                       detector="turn_rate", shadow="none", reward="error")
    np.testing.assert_allclose(model_turn_rates(config.bank), PAPER_RATES)



@pytest.mark.parametrize("name", ["turn-rate", "Shadow", "x"])
def test_a_misspelled_detector_is_refused_listing_the_three(name: str) -> None:
    """The refusal lists exactly the three detectors the module docstring documents (shadow,
    turn_rate, learned), and no other name is accepted."""
    listed = re.escape("['shadow', 'turn_rate', 'learned']")
    with pytest.raises(ConfigError, match=rf"detector must be one of {listed}, got '{name}'"):
        EnvConfig(action_mode="stay", stay_base="evidence", detector_share=0.5, detector=name)

def test_the_tracker_base_leans_stays_of_at_least_one_in_m() -> None:
    """A tracker TPM whose stay is below 1/M gives the detector's rows at the stay 1/M (a
    switching prior, every entry non-negative), not a row of negative entries."""
    core = _core(2, stay_base="tracker", initial_stay=0.1)
    for _ in range(10):
        belief = core.detector_belief
        expected = detector_tpm_rows(np.full(2, 1.0 / M), belief, 0.5)
        np.testing.assert_allclose(core.stay_base_tpms, expected, rtol=0, atol=1e-15)
        core.step(np.zeros((2, M)))
    assert np.all(core.stay_base_tpms >= 0.0)
