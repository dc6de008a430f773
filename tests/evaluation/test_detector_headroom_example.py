"""``examples/detector_headroom.py``: its ``tracker (env)`` and ``learned (env)`` rows are the
``turn-rate-prior`` and ``learned-prior`` baselines' roll-outs, run for run (under varied
conditions too); the turn rate known sooner leads the prior better."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import load_example

from baselines.turn_rate_prior import TurnRatePrior
from imm_gym import EnvConfig
from imm_gym.evaluation.metrics import mode_accuracy
from imm_gym.evaluation.rollout import armse_from_squared, evaluation_config, rollout
from imm_gym.sim.config_file import read_env_config

EXAMPLES = Path(__file__).parents[2] / "examples"


def test_the_trackers_rows_are_the_baselines_and_a_sooner_rate_leads_better() -> None:
    example = load_example("detector_headroom")
    scores = example.detector_runs({"scenario": "random"}, (0, 8), 12, 3)
    for stay, share in ((1 / 3, 0.5), (0.9, 0.25), (0.995, 0.75)):
        policy = TurnRatePrior(3, stay, share)
        config = evaluation_config(EnvConfig.build({"scenario": "random"}), policy.env_overrides)
        run = rollout(policy, config, 12, 3)
        armse, accuracy = scores[("tracker (env)", stay, share)]
        np.testing.assert_allclose(armse, armse_from_squared(run.squared_position_error),
                                   rtol=1e-6)
        np.testing.assert_allclose(accuracy, mode_accuracy(run.mode_probs, run.true_model),
                                   atol=0.005)

    def best(detector: str) -> float:
        return min(scores[(detector, s, v)][0] for s in example.STAYS for v in example.SHARES)

    assert best("true, 0 late") < best("true, 8 late") < best("tracker (env)")


def test_varied_conditions_take_each_runs_sampling_period_and_leave_out_the_ekf() -> None:
    example = load_example("detector_headroom")
    overrides = read_env_config(EXAMPLES / "broad.yaml")
    scores = example.detector_runs(overrides, (0,), 6, 2)
    assert {d for d, _, _ in scores} == {"true, 0 late", "tracker (env)", "learned (env)"}
    policy = TurnRatePrior(3, 0.6, 0.5)
    config = evaluation_config(EnvConfig.build(overrides), policy.env_overrides)
    run = rollout(policy, config, 6, 2)
    np.testing.assert_allclose(scores[("tracker (env)", 0.6, 0.5)][0],
                               armse_from_squared(run.squared_position_error), rtol=1e-6)
    policy = TurnRatePrior(3, 0.6, 0.5, detector="learned")
    config = evaluation_config(EnvConfig.build(overrides), policy.env_overrides)
    run = rollout(policy, config, 6, 2)
    np.testing.assert_allclose(scores[("learned (env)", 0.6, 0.5)][0],
                               armse_from_squared(run.squared_position_error), rtol=1e-6)


def test_the_learned_rows_are_the_learned_prior_baseline_s() -> None:
    example = load_example("detector_headroom")
    scores = example.detector_runs({"scenario": "random"}, (8,), 10, 5)
    for stay, share in ((1 / 3, 1.0), (0.9, 0.5)):
        policy = TurnRatePrior(3, stay, share, detector="learned")
        config = evaluation_config(EnvConfig.build({"scenario": "random"}), policy.env_overrides)
        run = rollout(policy, config, 10, 5)
        np.testing.assert_allclose(scores[("learned (env)", stay, share)][0],
                                   armse_from_squared(run.squared_position_error), rtol=1e-6)
    assert scores[("learned (env)", 1 / 3, 1.0)] != scores[("tracker (env)", 1 / 3, 1.0)]


def by_horizon(overrides: dict[str, Any], delays: Any, runs: int, seed: int, *rest: Any
               ) -> dict[tuple[str, float, float], tuple[float, float]]:
    """A stand-in for :func:`detector_runs` whose scores tell the configurations apart."""
    horizon = overrides.get("family", {}).get("horizon", 0)
    return {("tracker (env)", 0.5, 1.0): (float(horizon), 0.5)}


def test_files_of_one_name_in_other_folders_are_two_columns(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The columns were keyed by the file's name: the second ``t.yaml`` replaced the first."""
    example = load_example("detector_headroom")
    monkeypatch.setattr(example, "detector_runs", by_horizon)
    monkeypatch.setattr(example, "STAYS", (0.5,))
    monkeypatch.setattr(example, "SHARES", (1.0,))
    for folder, source in (("a", "my_tracker.yaml"), ("b", "broad.yaml")):  # horizons 75, 150
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "t.yaml").write_text((EXAMPLES / source).read_text())
    a, b = str(tmp_path / "a" / "t.yaml"), str(tmp_path / "b" / "t.yaml")
    example.main(["--runs", "1", "--env-config", a, "--env-config", b])
    out = capsys.readouterr().out
    assert f"| detector | {a} | {b} |" in out
    assert "| tracker (env) | 75.00 / 50 % (0.5, 1) | 150.00 / 50 % (0.5, 1) |" in out
    with pytest.raises(SystemExit) as exit_:
        example.main(["--env-config", a, "--env-config", a])
    assert exit_.value.code == 2
    assert "--env-config given a file twice" in capsys.readouterr().err


@pytest.mark.parametrize(("option", "message"), [
    (["--delay", "3", "--delay", "-1"], "--delay must be >= 0 (steps late; below 0 the detector "
     "sees the future), got -1"),
    (["--runs", "0"], "--runs must be >= 1, got 0"),
    (["--seed", "-1"], "--seed must be >= 0, got -1"),
    (["--yaw-noise", "-1"], "--yaw-noise must be a finite number >= 0 (rad/s²), got -1.0"),
    (["--yaw-noise", "nan"], "--yaw-noise must be a finite number >= 0"),
    (["--suite", "nowhere"], "--suite must be one of"),
    (["--env-config", "no/such.yaml"], "--env-config: no/such.yaml: cannot read"),
    (["--detector-weights", "no/such.safetensors"], "--detector-weights: "),
    (["--env-config", str(EXAMPLES / "probes" / "hetero.yaml")],
     "hetero.yaml: the turn-rate prior (turn-rate-prior, the 'tracker (env)' row) cannot run on "
     "this configuration: detector 'turn_rate' needs a linear bank"),
    # banks the learned detector cannot read (its ConfigError after the earlier columns' runs)
    (["--env-config", str(EXAMPLES / "probes" / "two_cv.yaml")],
     "two_cv.yaml: the turn-rate prior (learned-prior, the 'learned (env)' row) cannot run on "
     "this configuration: detector 'learned' needs models of distinct turn rates"),
    (["--env-config", str(EXAMPLES / "probes" / "cv_ct.yaml")],
     "cv_ct.yaml: the turn-rate prior (learned-prior, the 'learned (env)' row) cannot run on "
     "this configuration: detector_weights: the network places beliefs on 3 models, the bank "
     "has 2"),
])
def test_bad_options_are_refused_before_any_work(
    option: list[str], message: str, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    example = load_example("detector_headroom")
    monkeypatch.setattr(example, "detector_runs", lambda *a, **k: pytest.fail("ran"))
    with pytest.raises(SystemExit) as exit_:
        example.main(["--scenario", "paper", *option])
    assert exit_.value.code == 2 and message in capsys.readouterr().err


def test_the_ekf_starts_from_the_position_and_velocity_of_a_ca_banks_state() -> None:
    """A bank with a CA model (6-dimensional state) and distinct turn rates passes the checks;
    its CT-omega EKF starts from ``[x, y, vx, vy]`` (the whole state was a ConfigError)."""
    example = load_example("detector_headroom")
    overrides = {"scenario": {"segments": [{"duration": 10}, {"duration": 10,
                                                              "turn_rate_deg": 3.0}]},
                 "bank": [{"kind": "ca", "noise": "continuous", "intensity": 0.05},
                          {"kind": "ct", "turn_rate_deg": 3.0, "noise": "continuous",
                           "intensity": 0.1},
                          {"kind": "ct", "turn_rate_deg": -3.0, "noise": "continuous",
                           "intensity": 0.1}]}
    scores = example.detector_runs(overrides, [0], 1, 0)
    assert {d for d, _, _ in scores} == {"true, 0 late", "tracker (env)", "CT-omega EKF",
                                         "learned (env)"}
    assert all(np.isfinite(armse) for armse, _ in scores.values())
