"""The TIP-IMM rule (SPEC §4, eqs. 13-17) worked by hand, as a factor matrix and as a ``scale``
action of the environment core."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym import ConfigError, EnvConfig, TrackingCore
from imm_gym.tracking.tip import tip_factors

ALPHA, BETA = 1.1, 0.9
TPM = [[0.8, 0.1, 0.1], [0.2, 0.7, 0.1], [0.1, 0.1, 0.8]]


def hand_tip(tpm, mu_prev, mu_now, reading="literal", alpha=ALPHA, beta=BETA):
    """SPEC §4 step by step in plain Python: returns (factors, adapted TPM)."""
    M = len(tpm)
    main_now = max(range(M), key=lambda j: (mu_now[j], -j))  # ties: the first model
    main_prev = max(range(M), key=lambda j: (mu_prev[j], -j))
    f = [[1.0] * M for _ in range(M)]
    if main_now == main_prev:
        i = main_now
        d = [mu_now[j] - mu_prev[j] for j in range(M)]
        f[i][i] = alpha if d[i] >= 0 else beta
        for j in range(M):
            if j == i:
                continue
            if d[i] >= 0:
                eq15 = d[j] > d[i]
            elif reading == "literal":
                eq15 = d[j] < d[i]  # the equation number as printed
            else:
                eq15 = not d[j] < d[i]  # the sentence: j decaying faster -> (16)
            if eq15:  # (15)
                f[i][j], f[j][i] = alpha, beta
            else:  # (16)
                f[i][j], f[j][i] = beta, alpha
    raw = [[tpm[r][c] * f[r][c] for c in range(M)] for r in range(M)]
    adapted = [[v / sum(row) for v in row] for row in raw]  # eq. (17)
    return f, adapted


def _core(max_factor: float = 2.0, p_min: float = 1e-3) -> TrackingCore:
    return TrackingCore(EnvConfig(scenario="paper", max_factor=max_factor, p_min=p_min), 1)


def _as_action(factors: np.ndarray, max_factor: float) -> np.ndarray:
    return (np.log(factors) / math.log(max_factor)).reshape(1, -1).astype(np.float64)


CASES = {
    # main model 0 grows, the others shrink: (16) for both
    "grow_eq16": ([0.5, 0.3, 0.2], [0.6, 0.25, 0.15]),
    # main model 0 grows; model 1 grows faster -> (15), model 2 shrinks -> (16)
    "grow_eq15_and_eq16": ([0.40, 0.35, 0.25], [0.46, 0.44, 0.10]),
    # main model 1 decays; model 2 decays faster (literal/intent differ), model 0 grows
    "decay_mixed": ([0.2, 0.5, 0.3], [0.45, 0.47, 0.08]),
    # main model 2 decays; nobody decays faster
    "decay_no_faster": ([0.1, 0.2, 0.7], [0.15, 0.25, 0.6]),
    # main model changed (0 -> 1): no update
    "main_changed": ([0.5, 0.3, 0.2], [0.3, 0.5, 0.2]),
    # first step: mu_prev ties (uniform) -> model 0 is the previous main model
    "first_step": ([1 / 3, 1 / 3, 1 / 3], [0.5, 0.3, 0.2]),
    # mu_now ties between 0 and 1 -> model 0
    "tie_now": ([0.5, 0.3, 0.2], [0.4, 0.4, 0.2]),
    # main model 0 decays; model 1 decays exactly as fast (Delta = -1/8, -1/8, +1/4, exact in
    # binary): not "j decays faster", so literal (16) and intent (15) for model 1
    "decay_tie": ([0.75, 0.125, 0.125], [0.625, 0.0, 0.375]),
    # main model 0 holds (Delta_0 = 0 counts as growing: f_00 = alpha); model 1 grows -> (15),
    # model 2 shrinks -> (16)
    "steady_main": ([0.5, 0.25, 0.25], [0.5, 0.375, 0.125]),
    # main model 0 grows; model 1 grows exactly as fast (Delta = 1/8, 1/8, -1/4): not "grows
    # faster", so (16) for model 1 in both readings
    "grow_tie": ([0.5, 0.25, 0.25], [0.625, 0.375, 0.0]),
    # nothing moves (Delta = 0 everywhere): the main model counts as growing (f_00 = alpha), no
    # other grows faster, so (16) for both in both readings
    "steady_all": ([0.5, 0.25, 0.25], [0.5, 0.25, 0.25]),
}


@pytest.mark.parametrize("reading", ["literal", "intent"])
@pytest.mark.parametrize("case", sorted(CASES))
def test_tip_factors_and_scale_action_match_the_hand_rule(case: str, reading: str) -> None:
    mu_prev, mu_now = CASES[case]
    f_hand, adapted = hand_tip(TPM, mu_prev, mu_now, reading)
    f = tip_factors(np.array([mu_now]), np.array([mu_prev]), ALPHA, BETA, reading)
    assert f.shape == (1, 3, 3)
    np.testing.assert_array_equal(f[0], np.array(f_hand))
    for max_factor in (2.0, 1.5):
        core = _core(max_factor)
        tpm = core.tpm_from_action(_as_action(f[0], max_factor), np.array([TPM]))
        np.testing.assert_allclose(tpm[0], np.array(adapted), rtol=1e-12, atol=0)


def test_hand_worked_values_of_the_spec_example() -> None:
    """The brief's example written out entry by entry (M = 3, main model 0 grows by 0.1)."""
    f = tip_factors(np.array([[0.6, 0.25, 0.15]]), np.array([[0.5, 0.3, 0.2]]))[0]
    np.testing.assert_array_equal(f, [[1.1, 0.9, 0.9], [1.1, 1.0, 1.0], [1.1, 1.0, 1.0]])
    row0 = [0.88, 0.09, 0.09]
    row1 = [0.22, 0.7, 0.1]
    row2 = [0.11, 0.1, 0.8]
    expected = np.array([[v / sum(r) for v in r] for r in (row0, row1, row2)])
    tpm = _core().tpm_from_action(_as_action(f, 2.0), np.array([TPM]))[0]
    np.testing.assert_allclose(tpm, expected, rtol=1e-12)
    np.testing.assert_allclose(tpm[0], [0.88 / 1.06, 0.09 / 1.06, 0.09 / 1.06], rtol=1e-12)


def test_ties_with_the_main_models_change_take_eq16() -> None:
    """``Delta_j = Delta_i`` is not ``Delta_j > Delta_i``: (16), ``f_ij = beta, f_ji = alpha``,
    whether the main model grows (1/8 each) or holds (all 0), in both readings."""
    for name in ("grow_tie", "steady_all"):
        mu_prev, mu_now = CASES[name]
        for reading in ("literal", "intent"):
            f = tip_factors(np.array([mu_now]), np.array([mu_prev]), reading=reading)[0]
            expected = [[ALPHA, BETA, BETA], [ALPHA, 1.0, 1.0], [ALPHA, 1.0, 1.0]]
            np.testing.assert_array_equal(f, expected)


def test_main_model_changed_gives_all_ones_and_keeps_the_tpm() -> None:
    f = tip_factors(np.array([[0.2, 0.7, 0.1]]), np.array([[0.7, 0.2, 0.1]]))
    np.testing.assert_array_equal(f, np.ones((1, 3, 3)))
    tpm = _core().tpm_from_action(_as_action(f[0], 2.0), np.array([TPM]))
    np.testing.assert_allclose(tpm[0], TPM, rtol=1e-15)


def test_eq15_and_eq16_entries_when_the_main_model_grows() -> None:
    mu_prev, mu_now = CASES["grow_eq15_and_eq16"]
    f = tip_factors(np.array([mu_now]), np.array([mu_prev]))[0]
    assert f[0, 0] == ALPHA  # Delta_0 = 0.06 >= 0
    assert (f[0, 1], f[1, 0]) == (ALPHA, BETA)  # Delta_1 = 0.09 > 0.06: eq. (15)
    assert (f[0, 2], f[2, 0]) == (BETA, ALPHA)  # Delta_2 = -0.15: eq. (16)
    assert f[1, 1] == f[1, 2] == f[2, 1] == f[2, 2] == 1.0


def test_readings_differ_only_where_the_main_model_decays() -> None:
    mu_prev, mu_now = np.array([[0.2, 0.5, 0.3]]), np.array([[0.45, 0.47, 0.08]])
    # main model 1: Delta = (0.25, -0.03, -0.22); Delta_2 < Delta_1 < 0 <= Delta_0
    lit = tip_factors(mu_now, mu_prev, reading="literal")[0]
    intent = tip_factors(mu_now, mu_prev, reading="intent")[0]
    assert lit[1, 1] == intent[1, 1] == BETA
    assert (lit[1, 2], lit[2, 1]) == (ALPHA, BETA)  # literal: eq. (15) for the faster decay
    assert (intent[1, 2], intent[2, 1]) == (BETA, ALPHA)  # intent: eq. (16)
    assert (lit[1, 0], lit[0, 1]) == (BETA, ALPHA)  # the other case: the other equation
    assert (intent[1, 0], intent[0, 1]) == (ALPHA, BETA)
    core = _core()
    t_lit = core.tpm_from_action(_as_action(lit, 2.0), np.array([TPM]))[0]
    t_int = core.tpm_from_action(_as_action(intent, 2.0), np.array([TPM]))[0]
    assert not np.allclose(t_lit, t_int)
    # both readings agree when the main model grows
    mu_prev, mu_now = CASES["grow_eq15_and_eq16"]
    np.testing.assert_array_equal(
        tip_factors(np.array([mu_now]), np.array([mu_prev]), reading="literal"),
        tip_factors(np.array([mu_now]), np.array([mu_prev]), reading="intent"),
    )


def test_tip_factors_are_batched_row_by_row() -> None:
    names = sorted(CASES)
    mu_prev = np.array([CASES[n][0] for n in names])
    mu_now = np.array([CASES[n][1] for n in names])
    for reading in ("literal", "intent"):
        batched = tip_factors(mu_now, mu_prev, reading=reading)
        assert batched.shape == (len(names), 3, 3)
        for i in range(len(names)):
            np.testing.assert_array_equal(
                batched[i], tip_factors(mu_now[i : i + 1], mu_prev[i : i + 1], reading=reading)[0]
            )


def test_tip_as_a_scale_action_through_the_core_matches_the_hand_rule_on_a_batch() -> None:
    """Several steps of the rule carried over (each step multiplies the current TPM)."""
    rng = np.random.default_rng(4)
    N = 6
    core = TrackingCore(EnvConfig(scenario="paper", max_factor=2.0, p_min=1e-6), N)
    tpm = np.repeat(np.array([TPM]), N, axis=0)
    hand = [[row[:] for row in TPM] for _ in range(N)]
    mu_prev = rng.dirichlet(np.ones(3), N)
    for _ in range(10):
        mu_now = 0.7 * mu_prev + 0.3 * rng.dirichlet(np.ones(3), N)
        f = tip_factors(mu_now, mu_prev)
        tpm = core.tpm_from_action(np.log(f).reshape(N, 9) / math.log(2.0), tpm)
        for n in range(N):
            _, hand[n] = hand_tip(hand[n], list(mu_prev[n]), list(mu_now[n]))
        mu_prev = mu_now
    np.testing.assert_allclose(tpm, np.array(hand), rtol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "word"),
    [
        ({"alpha": 1.0}, "alpha"),
        ({"beta": 1.0}, "beta"),
        ({"beta": 0.0}, "beta"),
        ({"reading": "poetic"}, "reading"),
    ],
)
def test_tip_factors_validate_parameters(kwargs: dict, word: str) -> None:
    with pytest.raises(ConfigError, match=word):
        tip_factors(np.array([[0.5, 0.3, 0.2]]), np.array([[0.5, 0.3, 0.2]]), **kwargs)
