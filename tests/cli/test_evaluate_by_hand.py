"""The evaluation's flow checked by hand: which policy the paired differences are taken against,
on which runs the clairvoyant filter runs, and which seeds the tuners train on."""

from __future__ import annotations

import numpy as np
import pytest

import imm_gym.cli.comparison as comparison
import imm_gym.cli.policies as policies
from imm_gym.cli.comparison import evaluate, paired_difference
from imm_gym.cli.suite import evaluate_suite, suite_tally
from imm_gym.evaluation.clairvoyant import clairvoyant_filter, hold_diverged
from imm_gym.evaluation.metrics import tracking_errors
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.validation import ConfigError


def _armse(err2: np.ndarray) -> float:
    """Position ARMSE by hand: the RMSE over the runs at each step, averaged over the steps."""
    return float(np.mean([np.sqrt(np.mean(err2[:, k])) for k in range(err2.shape[1])]))


def test_the_reference_is_fixed_wherever_it_is_listed() -> None:
    """Without ``--reference`` the differences are against ``fixed`` when it is evaluated, even
    listed second (not the first policy): ``window`` minus ``fixed``, the ARMSEs by hand from
    the roll-outs' squared errors."""
    results, rollouts = evaluate(["window", "fixed"], "paper", 3, 4, clairvoyant=False)
    paired = results["paired"]
    assert paired["reference"] == "fixed" and set(paired["differences"]) == {"window"}
    window = _armse(rollouts["window"].squared_position_error)
    fixed = _armse(rollouts["fixed"].squared_position_error)
    d = paired["differences"]["window"]
    assert abs(d["diff"] - (window - fixed)) < 1e-9
    assert abs(d["relative"] - (window - fixed) / fixed) < 1e-12


def test_the_clairvoyant_filter_tracks_the_policies_runs() -> None:
    """The clairvoyant row is the filter run on the very measurements the policies' trackers
    were given (the roll-out's record, steps 1..K, missed detections predicted through): its
    errors recomputed from the ``fixed`` roll-out's truth and measurements equal the row's. Run
    on other seeds, or on the measurements of steps 0..K-1, it would differ."""
    env = {"sensor": {"detection_prob": 0.8}}
    runs, seed = 3, 9
    results, rollouts = evaluate(["fixed"], "paper", runs, seed, env_config=env)
    run = rollouts["fixed"]
    base = EnvConfig.build({**env, "scenario": "paper"})
    z = run.measurements[:, 1:]
    detected = ~np.isnan(z).any(axis=-1)
    assert not detected.all() and detected.any()
    # the start (x0, P0) and the truth's turn rates: the run's own draw, seed + r
    batch = draw_batch(base.source, base.sensor, runs, seed, base.velocity_std,
                       bank=base.linear_bank)
    np.testing.assert_array_equal(batch.truth.states[:, 1:], run.truth)
    xs, Ps = clairvoyant_filter(batch.truth, np.nan_to_num(z), base.sensor, base.bank,
                                batch.x0, batch.P0, base.filter, detected)
    xs, _ = hold_diverged(xs, Ps, run.truth, base.divergence_error, base.divergence_cov)
    expected = tracking_errors(xs, run.truth)
    for key in ("armse_pos", "armse_pos_x", "armse_vel_y"):
        assert abs(results["clairvoyant"][key] - expected[key]) < 1e-9, key


def test_a_tuner_trains_on_its_own_seeds(monkeypatch) -> None:
    """``best-fixed``'s search rolls out on training seeds ``seed + 1_000_000 + r`` (SPEC: never
    the evaluation's ``seed + r``): every roll-out the tuner starts begins at 1_000_005 for
    ``--seed 5``."""
    calls = []
    real = policies.rollout

    def recording(policy, config, runs, seed, **kwargs):
        calls.append((runs, seed))
        return real(policy, config, runs, seed, **kwargs)

    monkeypatch.setattr(policies, "rollout", recording)
    policies.make_policy("best-fixed", EnvConfig(scenario="paper"), 5, train_runs=2)
    assert calls and all(c == (2, 1_000_005) for c in calls)


def test_a_ci_whose_upper_bound_is_zero_is_level() -> None:
    """The tally's "below" needs the CI's upper bound below zero: a policy whose errors are the
    reference's, run for run (a difference and a CI of exactly 0, as a tuner that picks the
    reference's TPM gives), or a CI ending at 0, includes zero: level, not below (nor above)."""
    err2 = np.random.default_rng(0).gamma(2.0, 50.0, (6, 5))
    same = paired_difference(err2, err2)
    assert same["diff"] == same["low"] == same["high"] == 0.0
    ending_at_zero = {"diff": -0.5, "low": -1.0, "high": 0.0}
    scenarios = {
        "same": {"paired": {"differences": {"p": same}}},
        "edge": {"paired": {"differences": {"p": ending_at_zero}}},
    }
    assert suite_tally(scenarios, ["p"]) == {
        "p": {"below": [], "level": ["same", "edge"], "above": [], "skipped": []}
    }


def test_one_run_has_no_confidence_interval_and_two_have_one() -> None:
    """With R = 1 every resample is the one run, so the interval is undefined: ``low`` and
    ``high`` are None (JSON null), the difference itself the ARMSEs' by hand; with R = 2 they
    are numbers around it."""
    rng = np.random.default_rng(1)
    a, b = rng.gamma(2.0, 50.0, (2, 7)), rng.gamma(2.0, 50.0, (2, 7))
    one = paired_difference(a[:1], b[:1])
    assert one["low"] is None and one["high"] is None
    assert abs(one["diff"] - (_armse(a[:1]) - _armse(b[:1]))) < 1e-9
    two = paired_difference(a, b)
    assert two["low"] is not None and two["low"] <= two["diff"] <= two["high"]


def test_the_clairvoyant_filter_is_skipped_where_conditions_vary() -> None:
    """Runs drawn at other sampling periods (``vary: {T: ...}``) are not the one sensor and
    period the filter runs: the row is skipped, naming what varies, not computed on runs drawn
    without the variation (other runs than the policies')."""
    results, _ = evaluate(["fixed"], "random", 2, 0, bank="cv-ct-continuous",
                          env_config={"vary": {"T": (0.5, 2.0)}})
    assert results["clairvoyant"] == {
        "role": "skipped",
        "note": "skipped: conditions vary per run (T); the filter runs one sensor and sampling "
        "period",
    }


def test_a_bar_policy_a_case_does_not_admit_is_refused_before_any_work(
    tmp_path, monkeypatch
) -> None:
    """A policy of ``--bar`` must run on every case (the bar is the better of them there): the
    learned detector rule on a bank with two models of rate zero is refused, naming the case,
    before any roll-out (not skipped there, leaving the case without its bar)."""
    folder = tmp_path / "cases"
    folder.mkdir()
    (folder / "ca.yaml").write_text(
        "scenario: random\n"
        "bank: [{kind: cv, noise: continuous, intensity: 0.1},\n"
        "       {kind: ca, noise: continuous, intensity: 0.05},\n"
        "       {kind: ct, turn_rate_deg: 4.0, noise: continuous, intensity: 0.05}]\n"
    )
    (folder / "paper.yaml").write_text("scenario: random\n")

    def refuse(*args, **kwargs):
        raise AssertionError("a roll-out ran before the error")

    for module in (comparison, policies):
        monkeypatch.setattr(module, "rollout", refuse)
    with pytest.raises(ConfigError, match="ca: a policy of --bar, learned-prior, cannot run"):
        evaluate_suite(["fixed", "learned-prior"], str(folder), 2, 0, clairvoyant=False,
                           bar=["learned-prior"])


def test_with_a_bar_the_tally_sorts_the_cases_by_the_difference_against_it(tmp_path) -> None:
    """With ``bar`` the tally is against the bar, not the reference: the reference ``fixed``
    itself is tallied (run on every case, never skipped), each case sorted by hand from its
    bar difference's CI (high < 0 below, low > 0 above, else level)."""
    folder = tmp_path / "cases"
    folder.mkdir()
    (folder / "one.yaml").write_text("scenario: random\n")
    (folder / "two.yaml").write_text("scenario: paper\n")
    suite = evaluate_suite(["fixed", "window", "tip-imm"], str(folder), 3, 0,
                               clairvoyant=False, bar=["tip-imm"])
    assert set(suite["tally"]) == {"fixed", "window"}
    for name in ("fixed", "window"):
        expected = {"below": [], "level": [], "above": [], "skipped": []}
        for case in ("one", "two"):
            d = suite["scenarios"][case]["bar"]["differences"][name]
            where = "below" if d["high"] < 0 else "above" if d["low"] > 0 else "level"
            expected[where].append(case)
        assert suite["tally"][name] == expected
