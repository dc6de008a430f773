"""``examples/error_by_mode.py``: the error split by true model adds up to the evaluation's mean
squared error, a fixed TPM's stays are its stay, and an agent's zero action is its base TPM."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import load_example

from imm_gym.cli.comparison import evaluate
from imm_gym.cli.suite import suite_configs
from imm_gym.evaluation.rollout import armse_from_squared


def test_the_split_adds_up_and_the_stays_are_the_tpms() -> None:
    example = load_example("error_by_mode")
    config = suite_configs("benchmark")["paper"]
    _, rollouts = evaluate(["fixed"], "paper", 6, 3, clairvoyant=False, env_config=config)
    run = rollouts["fixed"]
    split = example.by_mode(run)
    assert split["armse"] == armse_from_squared(run.squared_position_error)
    counts = np.bincount(run.true_model.ravel(), minlength=3)
    assert np.all(counts > 0)
    # sum over models of (steps x mean square) = the total squared error
    np.testing.assert_allclose(
        np.sum(counts * split["rms"] ** 2), run.squared_position_error.sum(), rtol=1e-12
    )
    np.testing.assert_allclose(split["stays"], 0.995, rtol=1e-12)  # the classical IMM's TPM


def test_an_agents_zero_action_is_its_base_tpm() -> None:
    example = load_example("error_by_mode")
    results = example.score(["pretrained"], ["agents/pretrained"], ["vsmm-s1"], 4, 0)
    zero = results["vsmm-s1"]["zero of agents/pretrained"]
    agent = results["vsmm-s1"]["pretrained"]
    # the stay base gives every row one stay (the stay bank's evidence-weighted centre)
    seen = ~np.isnan(zero["stays"][:, 0])
    assert seen.sum() == 2  # S1 turns one way only
    rows = zero["stays"][seen]
    np.testing.assert_allclose(rows, rows[:, :1] * np.ones((1, 3)), rtol=1e-12)
    assert np.all((rows > 1 / 3) & (rows < 0.999))
    assert not np.allclose(agent["stays"][seen], rows)
    assert np.isnan(zero["rms"][2]) and np.all(np.isfinite(zero["rms"][:2]))


def test_the_windows_average_back_to_the_armse_and_count_every_step() -> None:
    example = load_example("error_by_mode")
    config = suite_configs("benchmark")["paper"]
    _, rollouts = evaluate(["fixed"], "paper", 5, 11, clairvoyant=False, env_config=config)
    run = rollouts["fixed"]
    R, K = run.true_model.shape
    window = 40  # 150 steps: three windows of 40 and one of 30
    time = example.by_time(run, window)
    lengths = np.diff(np.append(time["start"], K))
    assert lengths.tolist() == [40, 40, 40, 30]
    np.testing.assert_allclose(
        np.sum(lengths * time["armse"]) / K, armse_from_squared(run.squared_position_error),
        rtol=1e-12,
    )
    assert time["steps"].sum(axis=1).tolist() == (R * lengths).tolist()
    np.testing.assert_array_equal(
        time["steps"][-1], np.bincount(run.true_model[:, 120:].ravel(), minlength=3)
    )
    np.testing.assert_allclose(time["stay"], 0.995, rtol=1e-12)  # the classical IMM's TPM


def test_a_window_below_one_step_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    example = load_example("error_by_mode")
    with pytest.raises(SystemExit):
        example.main(["--window", "-1"])
    assert "--window must be" in capsys.readouterr().err


@pytest.mark.parametrize(("option", "message"), [
    (["--runs", "0"], "--runs must be >= 1, got 0"),
    (["--seed", "-1"], "--seed must be >= 0, got -1"),
    (["--policy", "nosuch"], "--policy: unknown policy 'nosuch'"),
    (["--policy", "fixed", "--policy", "fixed"], "--policy given twice"),
    (["--zero", "examples"], "--zero: no trained agent at 'examples'"),
])
def test_bad_options_are_refused_before_any_work(
    option: list[str], message: str, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    example = load_example("error_by_mode")
    monkeypatch.setattr(example, "evaluate", lambda *a, **k: pytest.fail("ran"))
    with pytest.raises(SystemExit) as exit_:
        example.main(["--scenario", "paper", *option])
    assert exit_.value.code == 2 and message in capsys.readouterr().err


def test_the_time_table_labels_each_window_by_its_filter_steps(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The rows name the steps k of each window (k = 0 is the track's start, the roll-out's
    first step k = 1), the last one to its last step: windows of 40 over 150 steps are 1–40,
    41–80, 81–120 and 121–150."""
    example = load_example("error_by_mode")
    config = suite_configs("benchmark")["paper"]
    _, rollouts = evaluate(["fixed"], "paper", 2, 11, clairvoyant=False, env_config=config)
    time = example.by_time(rollouts["fixed"], 40)
    assert time["end"].tolist() == [40, 80, 120, 150]
    example.print_time_table("paper", {"fixed": {"time": time}})
    rows = [line.split(" | ")[0] for line in capsys.readouterr().out.splitlines()[5:]]
    assert rows == ["| 1–40", "| 41–80", "| 81–120", "| 121–150"]
