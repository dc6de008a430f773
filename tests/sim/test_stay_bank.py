"""The stay bank (one classical IMM per stay of a grid, :mod:`imm_gym.sim.stay_bank`): its
evidence against separate IMMs on the numpy engine, the centre of the ``stay`` action it gives,
both engines, varied conditions, inactive slots and failed filters."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import stay_core
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from imm_gym import EnvConfig, TrackingCore, paper_bank
from imm_gym.sim.features import EVIDENCE_SCALE, EVIDENCE_STAYS
from imm_gym.sim.imm_batch import BatchStep
from imm_gym.sim.presets import CONTINUOUS_BANK
from imm_gym.sim.stay_bank import (
    STAY_BANK_FACTOR,
    STAY_BANK_FLOOR,
    StayBank,
    detector_tpm_rows,
    grid_stays,
)
from imm_gym.tracking.hetero import make_tracker
from imm_gym.tracking.imm import IMMState
from imm_gym.tracking.models import PAPER_Q, MotionModel
from imm_gym.tracking.tpm import stay_tpm, stay_tpm_rows
from imm_gym.validation import ConfigError

M = 3
STAYS = (1.0 / M, *EVIDENCE_STAYS)


@pytest.mark.parametrize("grid", ["stays", "pairs"])
def test_the_evidence_is_that_of_one_classical_imm_per_stay(grid: str) -> None:
    # the reference: each prior's IMM alone on the numpy engine, the predictive density of each
    # measurement summed directly, the relative evidence floored and discounted step by step
    core = stay_core(2, stay_base="evidence", stay_grid=grid)
    reference = make_tracker(core.config.bank, core.config.sensor, "ukf", 1.0, engine="numpy")
    priors = [tuple(row) for row in grid_stays(M, grid)]
    states = [core.state_a for _ in priors]
    total = np.zeros((2, len(priors)))
    rng = np.random.default_rng(0)
    missed = 0
    for _ in range(80):
        k1 = core.k + 1
        z, det = core.z[np.arange(2), k1], core.detected[np.arange(2), k1]
        missed += int((~det).sum())
        e = np.zeros((2, len(priors)))
        for s, stay in enumerate(priors):
            states[s], out = reference.step(states[s], stay_tpm(M, stay), z, det)
            e[:, s] = np.where(det, np.log(np.sum(out.cbar * np.exp(out.loglik), axis=1)), 0.0)
        total = STAY_BANK_FACTOR * total + np.maximum(
            e - e.max(axis=1, keepdims=True), -STAY_BANK_FLOOR
        )
        obs = core.step(rng.uniform(-1, 1, (2, M))).obs
        np.testing.assert_allclose(core.stay_bank.evidence, total, rtol=1e-9, atol=1e-9)
        relative = total - total.max(axis=1, keepdims=True)
        np.testing.assert_allclose(
            obs[:, 2 * M :], np.tanh(relative[:, : len(STAYS)] / EVIDENCE_SCALE), atol=1e-6
        )
    for s in range(len(priors)):
        np.testing.assert_allclose(
            core.stay_bank.state.x[s :: len(priors)], states[s].x, rtol=1e-9, atol=1e-6
        )
    assert missed > 0 and np.ptp(total[:, 1:]) > 1.0  # missed detections; the stays disagree


def test_the_zero_action_of_the_evidence_base_is_the_evidence_s_stay() -> None:
    core = stay_core(3, stay_base="evidence")
    stays = []
    for _ in range(60):
        centre = core.stay_bank.centre()
        tpm = core.step(np.zeros((3, M))).info["tpm"]
        np.testing.assert_allclose(tpm, stay_tpm_rows(centre, M), rtol=0, atol=1e-15)
        stays.append(centre)
    # the first step: the logit stays' mean; then each target's own
    first = 1.0 / (1.0 + np.exp(-np.mean(np.log(STAYS) - np.log1p(-np.asarray(STAYS)))))
    np.testing.assert_allclose(stays[0], first, rtol=1e-12)
    assert np.ptp(stays[-1]) > 0.01
    # bank B and the shadow keep the tracker's TPM
    np.testing.assert_array_equal(core.fixed_tpms, stay_tpm_rows(np.full(3, 0.995), M))


def test_the_best_base_is_the_stay_with_the_largest_evidence() -> None:
    core = stay_core(3, stay_base="evidence_best")
    bank = core.stay_bank
    assert np.all(bank.best() == 1.0 / M)  # no evidence yet: the grid's first stay
    chosen = []
    for _ in range(60):
        best = bank.stays[np.argmax(bank.evidence, axis=1)]
        np.testing.assert_array_equal(bank.best(), best)
        tpm = core.step(np.zeros((3, M))).info["tpm"]
        np.testing.assert_allclose(tpm, stay_tpm_rows(best, M), rtol=0, atol=1e-15)
        chosen.append(best)
    assert len(np.unique(chosen)) > 1  # the evidence moved the base
    with pytest.raises(ConfigError, match="stay_base 'evidence_best' needs action_mode 'stay'"):
        EnvConfig(action_mode="set", stay_base="evidence_best")


def test_an_action_moves_the_stay_from_the_evidence_s() -> None:
    core = stay_core(2, stay_base="evidence")
    for _ in range(10):
        core.step(np.zeros((2, M)))
    centre = core.stay_bank.centre()
    tpm = core.step(np.full((2, M), 0.5)).info["tpm"]
    logit = np.log(centre) - np.log1p(-centre) + 0.5 * core.config.logit_scale
    expected = 1.0 / (1.0 + np.exp(-logit))
    np.testing.assert_allclose(np.diagonal(tpm, axis1=1, axis2=2), expected, rtol=1e-12)


@pytest.mark.parametrize("stay_base", ["tracker", "evidence"])
def test_both_engines_run_the_same_stay_bank(stay_base: str) -> None:
    fused, general = stay_core(3, stay_base=stay_base), stay_core(3, "numpy", stay_base=stay_base)
    rng = np.random.default_rng(2)
    for _ in range(80):
        action = rng.uniform(-1, 1, (3, M))
        a, b = fused.step(action), general.step(action)
        np.testing.assert_allclose(a.obs, b.obs, atol=1e-6)
        np.testing.assert_allclose(a.info["tpm"], b.info["tpm"], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(
            fused.stay_bank.evidence, general.stay_bank.evidence, rtol=1e-9, atol=1e-9
        )


def test_a_slot_of_a_varied_batch_is_the_scalar_core_s_episode() -> None:
    vary = {"T": (0.5, 5.0), "sigma_r": (10.0, 100.0), "speed": (5.0, 300.0)}
    batch = stay_core(3, vary=vary, stay_base="evidence", bank=CONTINUOUS_BANK)
    T = batch.sampling_period.copy()
    assert np.ptp(T) > 0.1  # the slots run at different sampling periods
    alone = [stay_core(1, vary=vary, stay_base="evidence", bank=CONTINUOUS_BANK) for _ in range(3)]
    for i, core in enumerate(alone):
        core.reset(np.array([0]), [20 + i])
    rng = np.random.default_rng(4)
    for _ in range(40):
        action = rng.uniform(-1, 1, (3, M))
        batch.step(action)
        for i, core in enumerate(alone):
            core.step(action[i : i + 1])
            np.testing.assert_allclose(
                batch.stay_bank.evidence[i], core.stay_bank.evidence[0], rtol=1e-12, atol=1e-12
            )


def test_inactive_slots_keep_their_stay_bank() -> None:
    core = stay_core(3, stay_base="evidence")
    for _ in range(5):
        core.step(np.zeros((3, M)))
    bank = core.stay_bank
    x, evidence = bank.state.x.copy(), bank.evidence.copy()
    core.step(np.zeros((3, M)), active=np.array([True, False, True]))
    S = bank.S
    np.testing.assert_array_equal(bank.state.x[S : 2 * S], x[S : 2 * S])
    np.testing.assert_array_equal(bank.evidence[1], evidence[1])
    assert not np.array_equal(bank.evidence[0], evidence[0])


def test_a_failed_filter_gets_the_floor_and_restarts_from_bank_a() -> None:
    core = stay_core(2)
    bank = core.stay_bank
    S, n = bank.S, core.n
    before = bank.evidence.copy()
    real = bank.batch._advance

    def failing(tpm_rows, z, det):  # the second slot's stay-0.9 IMM fails this step
        state, out = real(tpm_rows, z, det)
        row = S + 3
        state.x[row], out.failed[row] = np.nan, True
        return state, out

    bank.batch._advance = failing  # type: ignore[method-assign]
    fallback = IMMState(np.full((2, M, n), 7.0), np.repeat(np.eye(n)[None, None], 2 * M, 0)
                        .reshape(2, M, n, n), np.full((2, M), 1.0 / M))
    k1 = core.k + 1
    det = np.array([True, True])
    bank.step(core.z[np.arange(2), k1], det, fallback)
    assert bank.evidence[1, 3] == STAY_BANK_FACTOR * before[1, 3] - STAY_BANK_FLOOR
    assert np.all(bank.state.x[S + 3] == 7.0) and np.all(np.isfinite(bank.state.x))
    assert bank.evidence[0].max() == 0.0 and bank.evidence[1].max() == 0.0


@settings(max_examples=200, deadline=None)
@given(
    st.sampled_from(["stays", "pairs"]).flatmap(
        lambda grid: st.tuples(
            st.just(grid),
            arrays(np.float64, (4, len(grid_stays(M, grid))), elements=st.floats(-500.0, 0.0)),
        )
    )
)
def test_the_centre_is_a_stay_between_the_grid_s_ends(drawn) -> None:
    """Each row's centre lies between its smallest and largest stay of the grid, and where
    one prior's evidence is far ahead of the others', it is that prior's stays."""
    grid, evidence = drawn
    tracker = make_tracker(EnvConfig().bank, EnvConfig().sensor, "ukf", 1.0)
    bank = StayBank(tracker, 4, None, grid=grid)
    bank.evidence = evidence
    centre = bank.centre()
    assert centre.shape == (4, M)
    stays = grid_stays(M, grid)
    assert np.all(centre >= stays.min(axis=0) - 1e-12)
    assert np.all(centre <= stays.max(axis=0) + 1e-12)
    tpm = stay_tpm_rows(centre, M)
    np.testing.assert_allclose(tpm.sum(axis=-1), 1.0, rtol=0, atol=1e-15)
    winner = np.argmax(evidence, axis=1)
    clear = np.sort(evidence, axis=1)[:, -2] < evidence.max(axis=1) - 60.0
    np.testing.assert_allclose(centre[clear], stays[winner[clear]], rtol=1e-12)
    np.testing.assert_array_equal(bank.best(), stays[winner])


def test_the_pairs_grid_adds_per_model_priors_and_its_base_is_per_row() -> None:
    """``stay_grid: pairs``: the single stays first (the observed block keeps its size), then
    each (a, b, b) with a sticky first model; the evidence base's TPM has a stay per row."""
    stays = grid_stays(M, "pairs")
    np.testing.assert_array_equal(stays[: 1 + len(EVIDENCE_STAYS)], np.repeat(
        np.array(STAYS)[:, None], M, axis=1))
    pairs = stays[1 + len(EVIDENCE_STAYS) :]
    # every (a, b) of a in (0.95, 0.99, 0.999) and b in (1/M, 0.6, 0.8, 0.9), a on the sticky row
    literal = [[a, b, b] for a in (0.95, 0.99, 0.999) for b in (1 / 3, 0.6, 0.8, 0.9)]
    np.testing.assert_array_equal(pairs, literal)
    np.testing.assert_array_equal(grid_stays(M, "pairs", sticky=2)[1 + len(EVIDENCE_STAYS) :],
                                  [[b, b, a] for a, b, _ in literal])
    plain, paired = stay_core(2, stay_base="evidence"), stay_core(2, stay_base="evidence",
                                                                  stay_grid="pairs")
    assert paired.obs_dim == plain.obs_dim and paired.stay_bank.S == len(stays)
    moved = False
    for _ in range(60):
        centre = paired.stay_bank.centre()
        tpm = paired.step(np.zeros((2, M))).info["tpm"]
        np.testing.assert_allclose(tpm, stay_tpm_rows(centre, M), rtol=0, atol=1e-15)
        moved |= bool(np.any(np.abs(centre[:, 0] - centre[:, 1]) > 0.01))
    assert moved  # the first model's stay apart from the others'
    with pytest.raises(ConfigError, match="stay_grid 'pairs' needs stay_base 'evidence'"):
        EnvConfig(action_mode="stay", stay_base="tracker", stay_grid="pairs")
    with pytest.raises(ConfigError, match="stay_grid must be one of"):
        EnvConfig(stay_grid="grid")


def test_the_evidence_base_needs_the_stay_mode() -> None:
    with pytest.raises(ConfigError, match="stay_base 'evidence' needs action_mode 'stay'"):
        EnvConfig(action_mode="scale", stay_base="evidence")
    with pytest.raises(ConfigError, match="stay_base"):
        EnvConfig(action_mode="stay", stay_base="posterior")
    assert TrackingCore(EnvConfig(action_mode="stay")).stay_bank is None


@pytest.mark.parametrize("n", [1, 3])
def test_the_kernel_gets_the_same_array_types_at_every_n(n: int) -> None:
    """The TPM rows are a fresh C-contiguous, writable array for one slot too: a read-only view
    at N = 1 made numba compile a second specialization of imm_step (two minutes, cold)."""
    bank = StayBank(make_tracker(EnvConfig().bank, EnvConfig().sensor, "ukf", 1.0), n, None)
    rows = bank._tpm_rows
    assert rows.flags.c_contiguous and rows.flags.writeable
    np.testing.assert_array_equal(rows, np.concatenate([bank.tpms] * n))


def test_priors_with_a_stay_per_row() -> None:
    """``stay_tpm_rows`` and ``detector_tpm_rows`` take one stay per row: without the detector
    each row keeps its own stay and spreads the rest evenly; with it every row still sums to 1
    and keeps at least its share ``r_i`` on the diagonal."""
    stays = np.array([[0.999, 0.4, 0.4], [0.9, 0.6, 0.8]])
    tpm = stay_tpm_rows(stays, M)
    np.testing.assert_allclose(tpm[1], stay_tpm(M, (0.9, 0.6, 0.8)), rtol=1e-15)
    belief = np.array([[0.1, 0.8, 0.1], [0.2, 0.2, 0.6]])
    np.testing.assert_allclose(detector_tpm_rows(stays, belief, 0.0), tpm, rtol=1e-12)
    leaning = detector_tpm_rows(stays, belief, 0.7)
    np.testing.assert_allclose(leaning.sum(axis=-1), 1.0, rtol=0, atol=1e-15)
    keep = (stays - 1 / M) / (1 - 1 / M)
    assert np.all(np.diagonal(leaning, axis1=1, axis2=2) >= keep - 1e-15)


@pytest.mark.parametrize("grid", ["stays", "pairs"])
def test_the_detectors_priors_are_detector_tpm_rows_of_every_stay(grid: str) -> None:
    """The bank builds each step's priors for all its stays at once (the belief broadcast over
    the grid): the same numbers as :func:`detector_tpm_rows` of every slot's stays, row by row,
    bit for bit."""
    rng = np.random.default_rng(4)
    N, share = 3, 0.6
    config = EnvConfig()
    bank = StayBank(make_tracker(config.bank, config.sensor, "ukf", 1.0), N, None,
                    detector_share=share, grid=grid)
    x0 = np.tile([2000.0, 3000.0, 10.0, -5.0], (N, 1))
    bank.start(np.arange(N), IMMState(np.repeat(x0[:, None], M, 1),
                                      np.tile(np.diag([100.0, 100.0, 25.0, 25.0]), (N, M, 1, 1)),
                                      np.full((N, M), 1.0 / M)), None)
    belief = rng.dirichlet(np.ones(M), size=N)
    z = np.column_stack([np.hypot(2000.0, 3000.0) + rng.normal(0, 25, N),
                         np.arctan2(3000.0, 2000.0) + rng.normal(0, 0.003, N)])
    bank.step(z, np.ones(N, dtype=bool), IMMState(*(a[::bank.S] for a in (
        bank.state.x, bank.state.P, bank.state.mu))), belief)
    expected = detector_tpm_rows(np.tile(bank.stays, (N, 1)), np.repeat(belief, bank.S, axis=0),
                                 share)
    np.testing.assert_array_equal(bank._tpm_rows, expected)


def test_resetting_one_slot_clears_its_evidence_and_keeps_the_others() -> None:
    """A vector env's autoreset of one slot: its evidence starts again at 0 (the centre back at
    the grid's mean logit), the other slot's is untouched bit for bit."""
    core = stay_core(2, stay_base="evidence")
    rng = np.random.default_rng(0)
    for _ in range(30):
        core.step(rng.uniform(-1, 1, (2, 3)))
    bank = core.stay_bank
    other = bank.evidence[1].copy()
    assert np.ptp(bank.evidence[0]) > 0
    core.reset(np.array([0]), [99])
    assert np.all(bank.evidence[0] == 0.0)
    np.testing.assert_array_equal(bank.evidence[1], other)
    np.testing.assert_allclose(bank.centre()[0],
                               1 / (1 + np.exp(-bank.logits.mean(axis=0))), rtol=1e-12)


def _stub_cycle(bank, loglik_per_stay) -> None:
    """Bank's IMMs replaced by a cycle whose measurement log-likelihood is ``loglik_per_stay[s]``
    for every model of stay ``s`` (uniform predicted probabilities): each step's evidence."""
    N, S, M = bank.n_envs, bank.S, bank.stays.shape[1]

    def step(tpm, z, detected, fallback):
        ll = np.repeat(np.tile(np.asarray(loglik_per_stay, float), N)[:, None], M, axis=1)
        return BatchStep(np.full((N * S, M), 1.0 / M), ll, np.zeros(N * S),
                         np.zeros((N * S, 4)), np.zeros(N * S, bool))

    bank.batch.step = step


def test_the_evidence_recursion_with_its_floor_and_discount_by_literals() -> None:
    """A stay 50 nats behind in one step (an outlier) moves by the floor, 10 nats; one 3 nats
    behind at every step reaches -3 (1 - 0.99^100) / 0.01 = -190.2 after 100 steps: the
    documented floor and discount (README: λ = 0.99) as numbers, not the module's constants."""
    core = stay_core(2, stay_base="evidence")
    bank = core.stay_bank
    gains = np.zeros(bank.S)
    gains[1], gains[2] = -50.0, -3.0
    _stub_cycle(bank, gains)
    bank.evidence[:] = 0.0
    z, detected = np.zeros((2, 2)), np.ones(2, dtype=bool)
    bank.step(z, detected, None)
    np.testing.assert_allclose(bank.evidence[:, 1:3], [[-10.0, -3.0]] * 2, rtol=1e-12)
    for _ in range(99):
        bank.step(z, detected, None)
    np.testing.assert_allclose(bank.evidence[:, 2], -190.2, atol=0.05)


def test_a_diverged_stay_counts_as_the_cap_in_the_position_error() -> None:
    """A stay whose estimate is NaN scores the cap (it would poison bank_advantage's reward)."""
    core = stay_core(2, stay_base="evidence")
    bank = core.stay_bank
    S = bank.S
    estimates = np.zeros((2, S, 4))
    estimates[0, 3, :2] = np.nan
    estimates[1, :, 0] = 500.0
    bank.estimates = lambda: estimates
    bank.weights = np.full((2, S), 1.0 / S)
    np.testing.assert_allclose(bank.position_error(np.zeros((2, 2)), cap=100.0),
                               [100.0 / S, 100.0], rtol=1e-12)


def test_the_pairs_make_straight_flight_sticky_whatever_the_listing() -> None:
    """The pairs' sticky stay goes to the model first in the canonical order (CV), not to the
    first listed: a bank listed CT(+4), CV, CT(-4) runs the same priors on the same rows'
    models, and with ``model_order: canonical`` tracks as the default listing (the first-listed
    rule made CT(+4) sticky there: 16.5 m apart)."""
    bank = paper_bank()
    listings = (bank, (bank[1], bank[0], bank[2]))
    cores = [TrackingCore(EnvConfig(scenario="paper", bank=b, stay_base="evidence",
                                    stay_grid="pairs", action_mode="stay",
                                    model_order="canonical"), 2) for b in listings]
    first, second = (c.stay_bank.stays for c in cores)
    np.testing.assert_array_equal(second, first[:, [1, 0, 2]])
    assert (first[1 + len(EVIDENCE_STAYS):, 0] > 0.9).all()
    for core in cores:
        core.reset(np.arange(2), [3, 4])
    for _ in range(40):
        a, b = (core.step(np.zeros((2, core.action_dim))) for core in cores)
        np.testing.assert_allclose(a.info["estimate"], b.info["estimate"], atol=1e-6)


def test_with_twin_cv_models_the_quieter_is_sticky_whatever_the_listing() -> None:
    """Twins (two CV models told apart by their noise) are ordered as the policy's canonical
    order orders them, by velocity noise: the quiet CV is sticky in either listing (without the
    noise the first listed was)."""
    quiet = MotionModel("cv", q=tuple(0.1 * v for v in PAPER_Q))
    loud = MotionModel("cv", q=tuple(10.0 * v for v in PAPER_Q))
    ct = MotionModel("ct", 4.0, tuple(0.5 * v for v in PAPER_Q))
    for bank in ((quiet, loud, ct), (loud, quiet, ct)):
        core = TrackingCore(EnvConfig(bank=bank, stay_base="evidence", stay_grid="pairs",
                                      action_mode="stay", model_order="canonical"), 1)
        assert int(np.argmax(core.stay_bank.stays[-1])) == bank.index(quiet)
