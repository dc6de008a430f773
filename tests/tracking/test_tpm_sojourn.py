"""Tests of imm_gym.tracking.tpm's constructions: tpm_from_sojourn, a TPM from the models' mean
sojourn times (the continuous-time Markov generator discretized as exp(A T)), and stay_tpm with
one stay per model."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from imm_gym import ConfigError, EnvConfig, TrackingCore
from imm_gym.tracking.tpm import (
    MAX_T_OVER_SOJOURN,
    row_divergence,
    sojourn_generator,
    stay_tpm,
    tpm_from_sojourn,
    validate_tpm,
)


@st.composite
def chains(draw: st.DrawFn) -> tuple[list[float], float, np.ndarray | None]:
    """Sojourn times 0.1-1000 s of 2-5 models, T 0.01-100 s, equal or random switch shares."""
    M = draw(st.integers(2, 5))
    taus = draw(st.lists(st.floats(0.1, 1000.0), min_size=M, max_size=M))
    T = draw(st.floats(0.01, 100.0))
    if draw(st.booleans()):
        return taus, T, None
    weights = draw(st.lists(st.floats(0.0, 1.0), min_size=M * M, max_size=M * M))
    w = np.array(weights).reshape(M, M)
    np.fill_diagonal(w, 0.0)
    w[w.sum(axis=1) == 0.0, :] = 1.0  # a row without weight: equal shares
    np.fill_diagonal(w, 0.0)
    return taus, T, w / w.sum(axis=1, keepdims=True)


@settings(max_examples=80, deadline=None)
@given(chain=chains(), T2=st.floats(0.01, 100.0))
def test_exp_tpm_invariants(chain: tuple[list[float], float, np.ndarray | None], T2: float) -> None:
    taus, T, switch = chain
    tpm = tpm_from_sojourn(taus, T, switch)
    M = len(taus)
    assert tpm.shape == (M, M)
    assert tpm.min() >= 0.0 and tpm.max() <= 1.0
    np.testing.assert_allclose(tpm.sum(axis=1), 1.0, rtol=0, atol=1e-14)
    validate_tpm(tpm, M)
    # staying throughout has probability exp(-T/τ_i); leaving and coming back adds to it
    assert np.all(np.diag(tpm) >= np.exp(-T / np.array(taus)) - 1e-12)
    # the generator: rows sum to 0, the diagonal is -1/τ
    A = sojourn_generator(taus, switch)
    np.testing.assert_allclose(A.sum(axis=1), 0.0, atol=1e-12 / min(taus))
    np.testing.assert_allclose(np.diag(A), -1.0 / np.array(taus), rtol=1e-15)
    # Chapman-Kolmogorov: T then T2 is T + T2
    np.testing.assert_allclose(
        tpm @ tpm_from_sojourn(taus, T2, switch), tpm_from_sojourn(taus, T + T2, switch), atol=1e-9
    )


@pytest.mark.parametrize(
    ("tau1", "tau2", "T"), [(60.0, 20.0, 1.0), (10.0, 10.0, 5.0), (3.0, 200.0, 0.1)]
)
def test_two_models_closed_form(tau1: float, tau2: float, T: float) -> None:
    """Two models, a = 1/τ1, b = 1/τ2: Π11 = (b + a e^{-(a+b)T}) / (a + b)."""
    a, b = 1.0 / tau1, 1.0 / tau2
    decay = math.exp(-(a + b) * T)
    expected = np.array(
        [
            [(b + a * decay) / (a + b), a * (1 - decay) / (a + b)],
            [b * (1 - decay) / (a + b), (a + b * decay) / (a + b)],
        ]
    )
    np.testing.assert_allclose(tpm_from_sojourn([tau1, tau2], T), expected, rtol=1e-12)


@pytest.mark.parametrize("tau", [5.0, 60.0, 600.0])
def test_stay_probability_is_exp_minus_T_over_tau_for_short_steps(tau: float) -> None:
    T = tau * 1e-3
    tpm = tpm_from_sojourn([tau, 2 * tau, 0.5 * tau], T)
    for i, t in enumerate((tau, 2 * tau, 0.5 * tau)):
        # equal to first order: 1 - Π_ii = T/τ (1 + O(T/τ))
        assert tpm[i, i] == pytest.approx(math.exp(-T / t), abs=(T / t) ** 2)
        assert 1 - tpm[i, i] == pytest.approx(T / t, rel=3 * T / t)


@pytest.mark.parametrize("switch", [None, [[0, 1, 0], [0, 0, 1], [0.25, 0.75, 0]]])
def test_mean_sojourn_of_the_discrete_chain_tends_to_tau(switch: list | None) -> None:
    """The chain stays a geometric number of steps, of mean T / (1 - Π_ii) -> τ_i as T -> 0."""
    taus = np.array([60.0, 20.0, 5.0])
    errors = []
    for T in (1.0, 0.1, 0.01, 0.001):
        tpm = tpm_from_sojourn(taus, T, switch)
        mean = T / (1.0 - np.diag(tpm))
        errors.append(np.abs(mean / taus - 1.0).max())
    assert errors == sorted(errors, reverse=True)
    assert errors[-1] < 1e-3
    assert errors[0] > 1e-3  # at T = 1 s the 5 s sojourn is visibly longer: the test can fail


def test_switch_shares_and_the_time_shares() -> None:
    taus = [40.0, 10.0, 10.0]
    switch = [[0, 1, 0], [0, 0, 1], [1, 0, 0]]  # a cycle
    A = sojourn_generator(taus, switch)
    np.testing.assert_array_equal(A, [[-1 / 40, 1 / 40, 0], [0, -0.1, 0.1], [0.1, 0, -0.1]])
    tpm = tpm_from_sojourn(taus, 0.01, switch)
    # over a short step the first jump goes where the shares say: 0 -> 1, never straight to 2
    assert tpm[0, 1] > 1e3 * tpm[0, 2]
    # the time each model holds in the long run is proportional to its sojourn (equal shares)
    long = np.linalg.matrix_power(tpm_from_sojourn(taus, 10.0), 1000)
    np.testing.assert_allclose(long, np.tile([2 / 3, 1 / 6, 1 / 6], (3, 1)), atol=1e-12)
    # the default splits departures equally
    np.testing.assert_array_equal(
        sojourn_generator(taus),
        sojourn_generator(taus, [[0, 0.5, 0.5], [0.5, 0, 0.5], [0.5, 0.5, 0]]),
    )
    np.testing.assert_array_equal(
        tpm_from_sojourn(taus, 1.0, np.array(switch, dtype=float)),
        tpm_from_sojourn(taus, 1.0, switch),
    )


def test_long_steps_forget_the_model() -> None:
    tpm = tpm_from_sojourn([1e-3, 1e-3, 1e-3], 1e5)
    np.testing.assert_allclose(tpm, 1 / 3, rtol=1e-12)


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (([60.0, 0.0], 1.0), r"sojourn_s\[1\]"),
        (([60.0, -5.0], 1.0), r"sojourn_s\[1\]"),
        (([float("nan"), 5.0], 1.0), r"sojourn_s\[0\]"),
        (([float("inf"), 5.0], 1.0), r"sojourn_s\[0\]"),
        ((["60", 5.0], 1.0), r"sojourn_s\[0\]"),
        (([60.0], 1.0), "sojourn_s"),
        (([], 1.0), "sojourn_s"),
        ((60.0, 1.0), "sojourn_s"),
        (([60.0, 20.0], 0.0), "^T must be"),
        (([60.0, 20.0], -1.0), "^T must be"),
        (([60.0, 20.0], float("nan")), "^T must be"),
        (([60.0, 20.0], "1"), "^T must be"),
        (([1e-9, 20.0], 1e4), r"T / sojourn_s\[0\]"),
        (([60.0, 20.0], 1.0, [[0, 1]]), "switch must have 2 entries"),
        (([60.0, 20.0], 1.0, [[0, 1], [1]]), r"switch\[1\] must have 2 entries"),
        (([60.0, 20.0], 1.0, [[0, 1], [1, 0, 0]]), r"switch\[1\] must have 2 entries"),
        (([60.0, 20.0], 1.0, np.zeros((2, 3))), r"switch\[0\] must have 2 entries"),
        (([60.0, 20.0], 1.0, [[0, 1], [1.5, -0.5]]), r"switch\[1\]\[0\]"),
        (([60.0, 20.0], 1.0, [[0, 1], [1, "0"]]), r"switch\[1\]\[1\]"),
        (
            ([60.0, 20.0, 5.0], 1.0, [[0.5, 0.5, 0], [0.5, 0, 0.5], [0.5, 0.5, 0]]),
            r"switch\[0\]\[0\] must be 0",
        ),
        (
            ([60.0, 20.0, 5.0], 1.0, [[0, 0.5, 0.4], [0.5, 0, 0.5], [0.5, 0.5, 0]]),
            r"switch\[0\] must sum to 1",
        ),
        (([60.0, 20.0], 1.0, "ab"), "switch must be a list"),
    ],
)
def test_invalid_inputs_name_the_field(args: tuple, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        tpm_from_sojourn(*args)


def test_largest_step_ratio_is_accepted() -> None:
    tpm = tpm_from_sojourn([1.0, 1.0], MAX_T_OVER_SOJOURN)
    np.testing.assert_allclose(tpm, 0.5, rtol=1e-12)


def test_stay_tpm_takes_one_stay_per_model() -> None:
    """Row i keeps ``stay[i]`` and spreads the rest evenly; one stay for all is every row's."""
    tpm = stay_tpm(3, (0.99, 0.5, 0.8))
    np.testing.assert_allclose(
        tpm, [[0.99, 0.005, 0.005], [0.25, 0.5, 0.25], [0.1, 0.1, 0.8]], rtol=1e-14
    )
    np.testing.assert_array_equal(stay_tpm(3, (0.9, 0.9, 0.9)), stay_tpm(3, 0.9))
    with pytest.raises(ConfigError, match="stay must have 3 entries"):
        stay_tpm(3, (0.9, 0.5))
    with pytest.raises(ConfigError, match=r"stay\[1\]"):
        stay_tpm(3, (0.9, 1.5, 0.5))
    with pytest.raises(ConfigError, match=r"stay must be a real number"):
        stay_tpm(3, "0.9")  # type: ignore[arg-type]


def test_an_environment_starts_from_one_stay_per_model() -> None:
    """``initial_stay`` per model is the fixed TPM of the core and the shadow's, checked by
    name."""
    from imm_gym import EnvConfig, TrackingCore

    config = EnvConfig(initial_stay=(0.995, 0.5, 0.5))
    core = TrackingCore(config, 2)
    np.testing.assert_array_equal(core.fixed_tpms[0], stay_tpm(3, (0.995, 0.5, 0.5)))
    np.testing.assert_array_equal(config.shadow_tpm(1.0), stay_tpm(3, (0.995, 0.5, 0.5)))
    with pytest.raises(ConfigError, match=r"initial_stay must have 3 entries"):
        EnvConfig(initial_stay=(0.9, 0.5))
    with pytest.raises(ConfigError, match=r"initial_stay\[2\]"):
        EnvConfig(initial_stay=(0.9, 0.5, -0.1))
    with pytest.raises(ConfigError, match=r"initial_stay must be a real number"):
        EnvConfig(initial_stay="0.9")  # type: ignore[arg-type]


def test_an_empty_batch_of_tpms_is_valid() -> None:
    """No TPM to check is no error (a core reset of no slot validates its ``initial_tpms``)."""
    assert validate_tpm(np.zeros((0, 3, 3)), 3).shape == (0, 3, 3)
    core = TrackingCore(EnvConfig(scenario="paper"), 2)
    core.reset(np.array([], dtype=int), [], initial_tpms=np.zeros((0, 3, 3)))


def test_a_model_never_reentered_keeps_exact_zeros() -> None:
    """Model 0 (0.5 s) is left for model 1, and models 1 and 2 (2 s each) only swap: nothing
    returns to model 0, so ``Π_10 = Π_20 = 0``. ``expm`` rounds them to about ``-1e-16``; they are
    set to 0, not refused as negative entries. By hand: ``Π_00 = e^{-T/0.5}``, and the pair 1-2
    is the two-model chain with ``a = b = 1/2``: ``Π_11 = (1 + e^{-T}) / 2``."""
    T = 4.0
    tpm = tpm_from_sojourn([0.5, 2.0, 2.0], T, [[0, 1, 0], [0, 0, 1], [0, 1, 0]])
    np.testing.assert_array_equal(tpm[1:, 0], [0.0, 0.0])
    assert tpm.min() == 0.0
    assert tpm[0, 0] == pytest.approx(math.exp(-T / 0.5), rel=1e-9)
    np.testing.assert_allclose(np.diag(tpm)[1:], (1 + math.exp(-T)) / 2, rtol=1e-12)
    np.testing.assert_allclose(tpm[1:, 1:].sum(axis=1), 1.0, rtol=0, atol=1e-15)


@pytest.mark.parametrize("shape", [(3,), (2, 3), (3, 2), (4, 3, 2), (3, 3, 3, 1)])
def test_validate_tpm_refuses_a_matrix_that_is_not_m_by_m(shape: tuple[int, ...]) -> None:
    """Only the last two axes ``(M, M)`` make a TPM: rows of the right length are not enough
    (``(2, 3)`` entries of 1/3 have rows summing to 1)."""
    with pytest.raises(ConfigError, match=r"tpm must have shape \(\.\.\., 3, 3\)"):
        validate_tpm(np.full(shape, 1.0 / shape[-1]), 3)
    assert validate_tpm(np.full((4, 3, 3), 1.0 / 3), 3).shape == (4, 3, 3)


def test_probability_moved_onto_a_zero_entry_costs_27_6_nats() -> None:
    """The documented ceiling: a reference entry 0 counts as 1e-12, so each unit of probability
    moved onto it costs ``-ln 1e-12 = 12 ln 10 = 27.63`` nats. Every row of the swap moves all of
    its probability onto a zero of the identity; half of it in ``[[0.5, 0.5], [0, 1]]``'s row 0."""
    swap = np.array([[0.0, 1.0], [1.0, 0.0]])
    assert row_divergence(swap, np.eye(2)) == pytest.approx(12 * math.log(10), rel=1e-12)
    assert 27.6 < row_divergence(swap, np.eye(2)) < 27.7
    half = np.array([[0.5, 0.5], [0.0, 1.0]])
    by_hand = (0.5 * math.log(0.5) + 0.5 * math.log(0.5 / 1e-12)) / 2  # row 1 is the reference's
    assert row_divergence(half, np.eye(2)) == pytest.approx(by_hand, rel=1e-12)


@pytest.mark.parametrize("stay", [0.0, 0.5, 0.9, 1.0, (0.3,)])
def test_one_model_always_stays(stay: float | tuple[float]) -> None:
    """With one model there is nowhere to switch: the TPM is ``[[1]]`` whatever the stay."""
    tpm = stay_tpm(1, stay)
    np.testing.assert_array_equal(tpm, [[1.0]])
    validate_tpm(tpm, 1)


@pytest.mark.parametrize("n_models", [0, -1])
def test_stay_tpm_needs_a_model(n_models: int) -> None:
    with pytest.raises(ConfigError, match="n_models"):
        stay_tpm(n_models, 0.9)
