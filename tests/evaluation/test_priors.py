"""``imm_gym.evaluation.priors``: priors given step by step run the evaluation's tracker, run
for run, prior-major."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from baselines.fixed import FixedTPM
from imm_gym import EnvConfig
from imm_gym.evaluation.metrics import mode_accuracy, mode_prob_tv
from imm_gym.evaluation.priors import prior_core, run_priors
from imm_gym.evaluation.rollout import armse_from_squared, evaluation_config, rollout
from imm_gym.tracking.tpm import stay_tpm
from imm_gym.validation import ConfigError

RUNS, SEED = 6, 11


def test_fixed_rows_are_the_evaluations_fixed_tpm_and_the_slots_prior_major() -> None:
    stays = (0.5, 0.98, 0.5)  # the first and last prior alike: same runs, same numbers
    slots = prior_core({"scenario": "paper"}, len(stays), RUNS, SEED)
    tpms = np.repeat(np.stack([stay_tpm(3, s) for s in stays]), RUNS, axis=0)
    seen: list[Any] = []

    def rows(k: int, info: dict[str, Any] | None) -> np.ndarray:
        seen.append((k, None if info is None else info["step"][0]))
        return tpms

    result = run_priors(slots, rows)
    K = slots.core.horizon
    assert seen[:2] == [(0, None), (1, 1)] and len(seen) == K  # the previous step's info
    assert result.squared_error.shape == (3, RUNS, K) and result.mode_probs.shape == (3, RUNS, K, 3)
    np.testing.assert_array_equal(result.squared_error[0], result.squared_error[2])
    for p, stay in enumerate(stays[:2]):
        policy = FixedTPM(3, stay)
        config = evaluation_config(EnvConfig.build({"scenario": "paper"}), policy.env_overrides)
        run = rollout(policy, config, RUNS, SEED)
        armse, accuracy, tv = result.scores(p)
        np.testing.assert_allclose(armse, armse_from_squared(run.squared_position_error),
                                   rtol=1e-9)
        np.testing.assert_allclose(accuracy, mode_accuracy(run.mode_probs, run.true_model),
                                   atol=0.005)
        np.testing.assert_allclose(tv, mode_prob_tv(run.mode_probs), atol=0.005)
    assert result.scores(0)[0] != result.scores(1)[0]


def test_a_prior_runs_exactly_at_the_floor_and_above_and_floored_below() -> None:
    """The module docstring's account: a row whose entries are all at least ``P_MIN`` is the TPM
    the tracker runs (to rounding); share 1 with a one-hot belief (detector_headroom's true
    turn rate on a model's own) has exact zeros, which run at ``P_MIN``."""
    from imm_gym.evaluation.priors import P_MIN
    from imm_gym.sim.stay_bank import detector_tpm_rows
    from imm_gym.tracking.tpm import apply_floor

    one_hot = np.tile([1.0, 0.0, 0.0], (4, 1))
    stays, shares = np.array([0.995, 0.995, 0.9, 1 / 3]), np.array([0.95, 1.0, 1.0, 0.5])
    asked = np.repeat(detector_tpm_rows(stays, one_hot, shares), RUNS, axis=0)
    slots = prior_core({"scenario": "paper"}, len(stays), RUNS, SEED)
    used: list[np.ndarray] = []

    def rows(k: int, info: dict[str, Any] | None) -> np.ndarray:
        if info is not None:
            used.append(info["tpm"].copy())
        return asked

    run_priors(slots, rows)
    ran = used[-1]
    exact = asked.min(axis=(1, 2)) >= P_MIN
    assert exact.reshape(4, RUNS)[:, 0].tolist() == [True, False, False, True]
    np.testing.assert_allclose(ran[exact], asked[exact], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ran[~exact], apply_floor(asked[~exact], P_MIN), rtol=1e-12)
    assert ran[~exact].min() == pytest.approx(P_MIN) and asked[~exact].min() == 0.0


def test_a_run_that_diverges_is_scored_as_the_evaluation_scores_it() -> None:
    """Missed detections and a tight divergence cap make some trackers diverge: from that step
    on the run is held at the cap with uniform mode probabilities, as ``rollout`` holds it (the
    core refuses to step a slot whose episode ended)."""
    over = {"scenario": "random", "divergence_error": 60.0, "sensor": {"detection_prob": 0.7}}
    stays = (0.98, 0.5)
    slots = prior_core(over, len(stays), 8, 3)
    tpms = np.repeat(np.stack([stay_tpm(3, s) for s in stays]), 8, axis=0)
    result = run_priors(slots, lambda k, info: tpms)
    assert result.diverged.shape == (2, 8) and result.diverged[0].any()
    policy = FixedTPM(3, stays[0])
    run = rollout(policy, evaluation_config(EnvConfig.build(over), policy.env_overrides), 8, 3)
    np.testing.assert_array_equal(result.diverged[0], run.diverged)
    np.testing.assert_array_equal(result.live[0], run.live)
    np.testing.assert_allclose(result.squared_error[0], run.squared_position_error, rtol=1e-9)
    np.testing.assert_allclose(result.mode_probs[0], run.mode_probs, rtol=1e-9, atol=1e-12)
    # the held steps' uniform probabilities do not count as an IMM that does not move
    tv = result.scores(0)[2]
    np.testing.assert_allclose(tv, mode_prob_tv(run.mode_probs, run.live), rtol=1e-9)
    assert tv > mode_prob_tv(run.mode_probs)


def test_runs_go_on_held_once_every_tracker_has_diverged() -> None:
    """A cap of 5 m loses every run within a few steps: the held errors and uniform mode
    probabilities fill the rest of the horizon (the rows' check had nothing left to read)."""
    slots = prior_core({"scenario": "paper", "divergence_error": 5.0}, 2, 3, SEED)
    tpms = np.repeat(np.stack([stay_tpm(3, s) for s in (0.5, 0.98)]), 3, axis=0)
    result = run_priors(slots, lambda k, info: tpms)
    assert result.diverged.all()
    np.testing.assert_array_equal(result.squared_error[..., -1], 25.0)
    np.testing.assert_array_equal(result.mode_probs[..., -1, :], 1.0 / 3.0)


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        (lambda tpm: tpm[:-1], r"rows\(0\) must have shape \(12, 3, 3\)"),
        (lambda tpm: 5.0 * tpm, r"rows\(0\) rows must sum to 1"),
        (lambda tpm: tpm + np.where(np.eye(3) > 0, 0.5, -0.25), r"rows\(0\) entries must be >= 0"),
        (lambda tpm: np.full_like(tpm, np.nan), r"rows\(0\) must be finite"),
    ],
)
def test_rows_that_are_not_the_slots_tpms_are_refused(rows: Any, message: str) -> None:
    slots = prior_core({"scenario": "paper"}, 4, 3, SEED)
    tpm = np.repeat(stay_tpm(3, 0.9)[None], 12, axis=0)
    with pytest.raises(ConfigError, match=message):
        run_priors(slots, lambda k, info: rows(tpm))


@pytest.mark.parametrize("field", ["n_priors", "runs"])
def test_a_core_without_priors_or_runs_is_refused(field: str) -> None:
    sizes = {"n_priors": 2, "runs": 3, field: 0}
    with pytest.raises(ConfigError, match=f"{field} must be an integer >= 1, got 0"):
        prior_core({"scenario": "paper"}, sizes["n_priors"], sizes["runs"], SEED)


def test_every_prior_s_scores_are_its_own_runs_evaluation() -> None:
    """Each prior's ARMSE, mode accuracy and total variation are the evaluation's of a fixed
    TPM on the same runs, its own diverged steps left out: random targets (every run its own
    modes) and a tight cap (the priors lose other runs)."""
    over = {"scenario": "random", "divergence_error": 60.0, "sensor": {"detection_prob": 0.7}}
    stays = (0.98, 0.5)
    slots = prior_core(over, len(stays), 8, 3)
    tpms = np.repeat(np.stack([stay_tpm(3, s) for s in stays]), 8, axis=0)
    result = run_priors(slots, lambda k, info: tpms)
    assert not np.array_equal(result.live[0], result.live[1])  # the priors lose other runs
    assert len({tuple(m) for m in result.true_model}) > 1  # the runs switch differently
    for p, stay in enumerate(stays):
        policy = FixedTPM(3, stay)
        run = rollout(policy, evaluation_config(EnvConfig.build(over), policy.env_overrides), 8, 3)
        armse, accuracy, tv = result.scores(p)
        assert armse == pytest.approx(armse_from_squared(run.squared_position_error), rel=1e-9)
        assert accuracy == pytest.approx(mode_accuracy(run.mode_probs, run.true_model), rel=1e-9)
        assert tv == pytest.approx(mode_prob_tv(run.mode_probs, run.live), rel=1e-9)


@pytest.mark.parametrize(("field", "value"), [("n_priors", True), ("runs", 2.0), ("runs", "3")])
def test_a_count_that_is_not_an_integer_is_refused(field: str, value: Any) -> None:
    """True is not a count of 1 (nor 2.0 one of 2): the sizes are integers or refused."""
    sizes: dict[str, Any] = {"n_priors": 2, "runs": 3, field: value}
    with pytest.raises(ConfigError, match=f"{field} must be an integer >= 1, got {value!r}"):
        prior_core({"scenario": "paper"}, sizes["n_priors"], sizes["runs"], SEED)


def test_a_lost_run_s_rows_are_not_read_and_the_others_still_checked() -> None:
    """From the step a run's tracker diverged at, its slot is no longer stepped and its rows are
    not read: NaN rows there give the very result of valid ones. The slots still tracking are
    checked to the end: a row of theirs not summing to 1 is refused after other runs were lost.
    """
    over = {"scenario": "random", "divergence_error": 60.0, "sensor": {"detection_prob": 0.7}}
    stays = (0.98, 0.5)
    tpms = np.repeat(np.stack([stay_tpm(3, s) for s in stays]), 8, axis=0)
    clean = run_priors(prior_core(over, len(stays), 8, 3), lambda k, info: tpms)
    live = clean.live.reshape(len(tpms), -1)  # (P * R, K), slot p * R + r
    lost_at = int(np.flatnonzero(~live.all(axis=0))[0])  # the first step a run was lost at
    assert lost_at < live.shape[1] - 2 and live[:, lost_at + 1].any()

    def nan_when_lost(k: int, info: dict[str, Any] | None) -> np.ndarray:
        rows = tpms.copy()
        if k > 0:
            rows[~live[:, k - 1]] = np.nan
        return rows

    result = run_priors(prior_core(over, len(stays), 8, 3), nan_when_lost)
    np.testing.assert_array_equal(result.live, clean.live)
    np.testing.assert_array_equal(result.squared_error, clean.squared_error)
    np.testing.assert_array_equal(result.mode_probs, clean.mode_probs)

    def unnormalized_after_a_loss(k: int, info: dict[str, Any] | None) -> np.ndarray:
        return 5.0 * tpms if k == lost_at + 1 else tpms

    with pytest.raises(ConfigError, match=rf"rows\({lost_at + 1}\) rows must sum to 1"):
        run_priors(prior_core(over, len(stays), 8, 3), unnormalized_after_a_loss)
