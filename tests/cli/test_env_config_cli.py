"""``python -m imm_gym.evaluate --env-config FILE``: one configuration for every policy, checked
before any work; trained agents evaluated on another tracker are reported, unreadable ones refused.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

import imm_gym.cli.evaluate as cli
from imm_gym.cli.comparison import evaluate
from imm_gym.cli.evaluate import main
from imm_gym.cli.suite import evaluate_suite
from imm_gym.sim.config_file import read_env_config
from imm_gym.sim.env_config import EnvConfig

SENSOR_FILE = "scenario: paper\nsensor: {sigma_r: 10.0, sigma_theta_deg: 0.02}\n"


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if any roll-out starts."""

    def refuse(*args, **kwargs):
        raise AssertionError("a roll-out ran before the error")

    monkeypatch.setattr(cli, "rollout", refuse)


def test_the_file_applies_to_every_policy(tmp_path) -> None:
    file = tmp_path / "sensor.yaml"
    file.write_text(SENSOR_FILE)
    out = tmp_path / "out.json"
    argv = ["--env-config", str(file), "--policy", "fixed", "--policy", "best-fixed"]
    assert main([*argv, "--runs", "3", "--quiet", "--json", str(out), "--no-clairvoyant"]) == 0
    got = json.loads(out.read_text())
    overrides = {"sensor": {"sigma_r": 10.0, "sigma_theta_deg": 0.02}}
    direct, _ = evaluate(["fixed", "best-fixed"], "paper", 3, 0, env_config=overrides)
    plain, _ = evaluate(["fixed", "best-fixed"], "paper", 3, 0)
    for name in ("fixed", "best-fixed"):
        assert got["policies"][name]["armse_pos"] == direct["policies"][name]["armse_pos"]
        assert got["policies"][name]["armse_pos"] < plain["policies"][name]["armse_pos"]
    assert got["meta"]["env_config"] == {"file": str(file), "overrides": {"scenario": "paper",
                                                                          **overrides}}
    assert got["meta"]["scenario"] == "paper"


def test_the_record_holds_what_the_file_said(tmp_path) -> None:
    """meta.env_config keeps the file's overrides beside its path: the run is redone from the
    record after the file is edited (it held the path alone)."""
    file = tmp_path / "sensor.yaml"
    file.write_text(SENSOR_FILE)
    out = tmp_path / "out.json"
    argv = ["--env-config", str(file), "--policy", "fixed", "--scenario", "random", "--runs", "2"]
    assert main([*argv, "--quiet", "--json", str(out), "--no-clairvoyant"]) == 0
    file.write_text("scenario: paper\nsensor: {sigma_r: 50.0}\n")
    meta = json.loads(out.read_text())["meta"]
    recorded = meta["env_config"]
    assert recorded["file"] == str(file) and recorded["overrides"]["sensor"]["sigma_r"] == 10.0
    again, _ = evaluate(["fixed"], meta["scenario"], 2, 0, clairvoyant=False,
                        env_config={k: v for k, v in recorded["overrides"].items()
                                    if k != "scenario"})
    got = json.loads(out.read_text())["policies"]["fixed"]["armse_pos"]
    assert again["policies"]["fixed"]["armse_pos"] == got


def test_scenario_flag_replaces_the_files_scenario(tmp_path) -> None:
    file = tmp_path / "random.yaml"
    file.write_text("scenario: random\nfamily: {horizon: 40, min_duration: 5}\n")
    out = tmp_path / "out.json"
    common = ["--env-config", str(file), "--policy", "fixed", "--runs", "2", "--quiet"]
    main([*common, "--json", str(out), "--no-clairvoyant"])
    assert json.loads(out.read_text())["meta"]["steps"] == 40
    main([*common, "--scenario", "paper", "--json", str(out), "--no-clairvoyant"])
    meta = json.loads(out.read_text())["meta"]
    assert meta["steps"] == 150 and meta["scenario"] == "paper"


@pytest.mark.parametrize(
    ("content", "words"),
    [
        ("sensor: {sigma_r: 10.0}\nbogus_key: 1\n", ["bogus_key"]),
        ("sensor: {sigma_r: ten}\n", ["sensor.sigma_r"]),
        ('initial_stay: "0.9"\n', ["initial_stay", "'0.9'"]),
        ("bank: [{kind: cv}]\n", ["bank"]),
    ],
)
def test_a_bad_file_is_a_usage_error_before_any_work(
    tmp_path, capsys, no_work, content, words
) -> None:
    file = tmp_path / "bad.yaml"
    file.write_text(content)
    with pytest.raises(SystemExit) as exit_:
        main(["--env-config", str(file), "--policy", "best-fixed", "--runs", "2"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    for word in (str(file), *words):
        assert word in err


def test_env_config_does_not_apply_to_the_seed_systems(tmp_path, capsys) -> None:
    file = tmp_path / "c.yaml"
    file.write_text("p_min: 0.01\n")
    with pytest.raises(SystemExit):
        main(["--env-config", str(file), "--scenario", "seed002", "--policy", "fixed"])
    assert "--env-config does not apply" in capsys.readouterr().err


def test_an_agent_on_another_tracker_is_reported(tmp_path, capsys) -> None:
    file = tmp_path / "sensor.yaml"
    file.write_text(SENSOR_FILE)
    out = tmp_path / "out.json"
    argv = ["--env-config", str(file), "--policy", "pretrained", "--policy", "fixed"]
    main([*argv, "--runs", "2", "--quiet", "--json", str(out), "--no-clairvoyant"])
    assert "pretrained was trained on another tracker" in capsys.readouterr().out
    row = json.loads(out.read_text())["policies"]["pretrained"]
    assert row["tracker_differs"] == ["sensor"]
    assert row["trained_on"]["sensor"]["sigma_r"] == 50.0
    assert row["evaluated_on"]["sensor"]["sigma_r"] == 10.0
    assert row["trained_on"]["bank"] == row["evaluated_on"]["bank"]
    results, _ = evaluate(["pretrained"], "paper", 2, 0, clairvoyant=False)
    assert results["policies"]["pretrained"]["tracker_differs"] == []


def test_an_agent_reading_other_models_as_its_own_is_reported(tmp_path, capsys) -> None:
    """A bank of three models standing for others than the trained banks' (CV, CA, CT(+)): the
    agent runs, and the report says what it reads each model as; the same models listed in
    another order are not reported (the canonical order)."""
    file = tmp_path / "cvcact.yaml"
    file.write_text("bank: [{kind: cv}, {kind: ca, q: [0.1, 0.1, 0.1, 0.1, 0.1, 0.1]},\n"
                    "       {kind: ct, turn_rate_deg: 3.0}]\n")
    out = tmp_path / "out.json"
    argv = ["--env-config", str(file), "--policy", "pretrained", "--runs", "2"]
    main([*argv, "--quiet", "--json", str(out), "--no-clairvoyant"])
    assert ("pretrained reads the evaluated bank's models (CV, CA, CT(+)) as those it was "
            "trained on (CV, CT(+), CT(−))") in capsys.readouterr().out
    row = json.loads(out.read_text())["policies"]["pretrained"]
    assert row["models_differ"] == {"trained": ["CV", "CT(+)", "CT(−)"],
                                    "evaluated": ["CV", "CA", "CT(+)"]}
    file.write_text("bank: [{kind: ct, turn_rate_deg: -3.0}, {kind: ct, turn_rate_deg: 3.0},\n"
                    "       {kind: cv}]\n")
    main([*argv, "--quiet", "--json", str(out), "--no-clairvoyant"])
    assert "reads the evaluated bank's models" not in capsys.readouterr().out
    assert "models_differ" not in json.loads(out.read_text())["policies"]["pretrained"]


def test_an_agent_that_cannot_read_the_observation_is_refused_before_any_work(
    tmp_path, capsys, no_work
) -> None:
    file = tmp_path / "four.yaml"
    file.write_text(
        "bank: [{kind: cv}, {kind: ct, turn_rate_deg: 2.0}, {kind: ct, turn_rate_deg: -2.0},\n"
        "       {kind: ct, turn_rate_deg: 6.0}]\n"
    )
    with pytest.raises(SystemExit):
        main(["--env-config", str(file), "--policy", "fixed", "--policy", "pretrained"])
    err = capsys.readouterr().err
    assert "reads observations of 44 entries" in err and "4 models" in err


def test_the_benchmark_suite_runs_end_to_end(tmp_path, capsys) -> None:
    out = tmp_path / "suite.json"
    argv = ["--suite", "benchmark", "--policy", "fixed", "--policy", "pretrained", "--runs", "2"]
    assert main([*argv, "--quiet", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    results = json.loads(out.read_text())
    assert list(results["scenarios"]) == ["paper", "random", "atc", "vsmm-s1", "vsmm-s2", "vsmm-s3"]
    for name, r in results["scenarios"].items():
        assert r["meta"]["scenario"] == name
        assert r["meta"]["env_config"]["file"].endswith(f"{name}.yaml")
        assert r["paired"]["reference"] == "fixed"
        assert set(r["policies"]) == {"fixed", "pretrained"}
        assert f"{name} ({r['meta']['steps']} steps)" in printed
    assert results["scenarios"]["atc"]["meta"]["steps"] == 99
    assert results["scenarios"]["vsmm-s3"]["meta"]["steps"] == 400
    assert results["scenarios"]["atc"]["policies"]["pretrained"]["tracker_differs"] == [
        "sensor",
        "bank",
        "initial_stay",
    ]
    assert results["scenarios"]["paper"]["policies"]["pretrained"]["tracker_differs"] == []
    # the suite's configuration, not the default tracker: the atc file's sensor and bank
    alone, _ = evaluate(["fixed"], "atc", 2, 0, clairvoyant=False)
    atc = results["scenarios"]["atc"]["policies"]["fixed"]["armse_pos"]
    assert atc != alone["policies"]["fixed"]["armse_pos"]


FOUR_MODELS = (
    "scenario: random\n"
    "bank: [{kind: cv}, {kind: ct, turn_rate_deg: 2.0}, {kind: ct, turn_rate_deg: -2.0},\n"
    "       {kind: ct, turn_rate_deg: 6.0}]\n"
)


def _directory_suite(tmp_path: Path) -> Path:
    """A suite of two configuration files (the paper with a finer sonar; a bank of four models)
    and a file that is not one."""
    folder = tmp_path / "cases"
    folder.mkdir()
    (folder / "fine.yaml").write_text(SENSOR_FILE)
    (folder / "four.json").write_text(json.dumps(yaml.safe_load(FOUR_MODELS)))
    (folder / "notes.txt").write_text("not a configuration")
    return folder


def test_a_directory_is_a_suite_of_its_configuration_files(tmp_path, capsys) -> None:
    """``--suite DIR``: one case per file (named by its stem, in name order), each run as
    ``--env-config FILE``; the shipped MLP, which reads three models, is not run on the bank of
    four and the table and the JSON say why; the tally sorts the cases by the paired CI."""
    folder = _directory_suite(tmp_path)
    out = tmp_path / "suite.json"
    argv = ["--suite", str(folder), "--policy", "fixed", "--policy", "pretrained",
            "--policy", "best-fixed", "--runs", "3", "--no-clairvoyant", "--quiet"]
    assert main([*argv, "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    results = json.loads(out.read_text())
    assert list(results["scenarios"]) == ["fine", "four"]
    assert results["meta"]["suite"] == str(folder) and results["meta"]["reference"] == "fixed"
    fine, four = results["scenarios"]["fine"], results["scenarios"]["four"]
    assert fine["meta"]["env_config"] == {"file": str(folder / "fine.yaml"),
                                          "overrides": yaml.safe_load(SENSOR_FILE)}
    assert four["meta"]["env_config"]["overrides"]["bank"][3]["turn_rate_deg"] == 6.0
    assert four["meta"]["scenario"] == "random"
    assert fine["skipped"] == {} and set(fine["policies"]) == {"fixed", "pretrained", "best-fixed"}
    assert set(four["policies"]) == {"fixed", "best-fixed"}
    assert "4 models" in four["skipped"]["pretrained"]
    assert "not run: reads 44 observation entries" in printed
    # each case is what --env-config FILE gives, on the same runs
    alone, _ = evaluate(["fixed", "best-fixed"], "random", 3, 0, clairvoyant=False,
                        env_config=yaml.safe_load(FOUR_MODELS))
    for name in ("fixed", "best-fixed"):
        assert four["policies"][name]["armse_pos"] == alone["policies"][name]["armse_pos"]
    tally = results["tally"]
    assert set(tally) == {"pretrained", "best-fixed"} and tally["pretrained"]["skipped"] == ["four"]
    for name, cases in tally.items():
        assert sorted(case for group in cases.values() for case in group) == ["fine", "four"]
        for case in cases["below"]:
            assert results["scenarios"][case]["paired"]["differences"][name]["high"] < 0
    assert "pretrained against fixed (2 cases, paired 95% CIs)" in printed
    assert "not run on 1" in printed


def test_the_bar_is_the_better_of_its_policies_on_each_case(tmp_path, capsys) -> None:
    """``--bar tip-imm best-fixed``: on each case the rule with the lower ARMSE is the bar, every
    other policy's paired difference is taken against it, and the tally is against the bar."""
    folder = _directory_suite(tmp_path)
    out = tmp_path / "suite.json"
    argv = ["--suite", str(folder), "--policy", "fixed", "--policy", "pretrained", "--bar",
            "tip-imm", "best-fixed", "--runs", "3", "--no-clairvoyant", "--quiet"]
    assert main([*argv, "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    results = json.loads(out.read_text())
    assert results["meta"]["bar"] == ["tip-imm", "best-fixed"]
    for r in results["scenarios"].values():
        rows = r["policies"]
        best = min(("tip-imm", "best-fixed"), key=lambda name: rows[name]["armse_pos"])
        assert r["bar"]["policy"] == best
        assert set(r["bar"]["differences"]) == set(rows) - {"tip-imm", "best-fixed"}
        for name, d in r["bar"]["differences"].items():
            assert d["diff"] == pytest.approx(rows[name]["armse_pos"] - rows[best]["armse_pos"])
            assert d["low"] <= d["diff"] <= d["high"]
    assert set(results["tally"]) == {"fixed", "pretrained"}
    assert "against the better of tip-imm and best-fixed (2 cases" in printed
    assert "— the bar" in printed


def test_the_bar_applies_to_a_suite(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["--policy", "fixed", "--bar", "tip-imm", "best-fixed"])
    assert "--bar applies to --suite" in capsys.readouterr().err


def test_the_tally_sorts_the_cases_by_the_paired_ci() -> None:
    from imm_gym.cli.suite import suite_tally

    def case(low, high) -> dict:
        d = {"diff": 0.0 if low is None else (low + high) / 2, "low": low, "high": high}
        return {"paired": {"differences": {"agent": d}}}

    scenarios = {
        "a": case(-2.0, -0.1),
        "b": case(-1.0, 0.5),
        "c": case(0.0, 1.0),  # a bound at zero includes it
        "d": case(0.2, 0.9),
        "e": case(None, None),  # one run: no CI
        "f": {"paired": {"differences": {}}},
    }
    assert suite_tally(scenarios, ["agent"]) == {
        "agent": {"below": ["a"], "level": ["b", "c", "e"], "above": ["d"], "skipped": ["f"]}
    }


def test_a_directory_suite_is_checked_before_any_work(tmp_path, capsys, no_work) -> None:
    folder = _directory_suite(tmp_path)
    empty = tmp_path / "empty"
    empty.mkdir()
    cases = [
        (["--suite", str(tmp_path / "missing")], "or a directory of configuration files"),
        (["--suite", str(empty)], "holds no configuration file"),
        (["--suite", str(folder), "--reference", "pretrained"], "four: the reference, pretrained"),
        (["--suite", str(folder)], "fine.json and fine.yaml name one case"),
    ]
    for argv, expected in cases:
        if expected.startswith("fine.json"):
            (folder / "fine.json").write_text("{}")
        with pytest.raises(SystemExit):
            main([*argv, "--policy", "fixed", "--policy", "pretrained", "--runs", "2"])
        assert expected in capsys.readouterr().err


def test_a_suite_s_reference_is_a_rule_when_none_is_given(tmp_path) -> None:
    """Without ``--reference`` (and without ``fixed``) the first rule given is the reference, not
    an agent listed before it, which may not read every case."""
    out = tmp_path / "suite.json"
    argv = ["--suite", str(_directory_suite(tmp_path)), "--policy", "pretrained", "--policy",
            "tip-imm", "--runs", "2", "--no-clairvoyant", "--quiet", "--json", str(out)]
    assert main(argv) == 0
    results = json.loads(out.read_text())
    assert results["meta"]["reference"] == "tip-imm"
    assert results["tally"]["pretrained"]["skipped"] == ["four"]


#: A bank with two models of turn rate zero (CV and CA), which the learned detector cannot read.
CV_CA_CT = (
    "bank: [{kind: cv, noise: continuous, intensity: 0.1},\n"
    "       {kind: ca, noise: continuous, intensity: 0.05},\n"
    "       {kind: ct, turn_rate_deg: 4.0, noise: continuous, intensity: 0.05}]\n"
)


def test_a_rule_a_case_does_not_admit_is_not_run_there(tmp_path, capsys) -> None:
    """The learned detector reads banks of distinct turn rates: ``learned-prior`` is not run on
    a bank with two models of rate zero, said before any work, and runs on the others."""
    folder = tmp_path / "cases"
    folder.mkdir()
    (folder / "ca.yaml").write_text(f"scenario: random\n{CV_CA_CT}")
    (folder / "paper.yaml").write_text("scenario: random\n")
    out = tmp_path / "suite.json"
    argv = ["--suite", str(folder), "--policy", "fixed", "--policy", "learned-prior", "--runs",
            "2", "--no-clairvoyant", "--quiet", "--json", str(out)]
    assert main(argv) == 0
    results = json.loads(out.read_text())
    assert "distinct turn rates" in results["scenarios"]["ca"]["skipped"]["learned-prior"]
    assert "learned-prior" in results["scenarios"]["paper"]["policies"]
    assert results["tally"]["learned-prior"]["skipped"] == ["ca"]


def test_a_rule_the_configuration_does_not_admit_is_refused_before_any_work(
    tmp_path, capsys, no_work
) -> None:
    file = tmp_path / "ca.yaml"
    file.write_text(CV_CA_CT)
    with pytest.raises(SystemExit):
        main(["--env-config", str(file), "--policy", "best-fixed", "--policy", "learned-prior"])
    assert "learned-prior cannot run on this configuration" in capsys.readouterr().err


def test_an_agent_that_reads_no_case_of_a_suite_is_refused(tmp_path, capsys, no_work) -> None:
    folder = tmp_path / "cases"
    folder.mkdir()
    (folder / "four.yaml").write_text(FOUR_MODELS)
    with pytest.raises(SystemExit):
        main(["--suite", str(folder), "--policy", "fixed", "--policy", "pretrained"])
    assert "pretrained cannot run on any case" in capsys.readouterr().err


@pytest.mark.parametrize("flag", [["--scenario", "paper"], ["--bank", "hetero"]])
def test_the_suite_refuses_per_scenario_flags(capsys, flag) -> None:
    with pytest.raises(SystemExit):
        main(["--suite", "benchmark", "--policy", "fixed", *flag])
    assert "does not apply to --suite" in capsys.readouterr().err


def test_an_agent_trained_on_varied_conditions_runs_on_a_named_scenario() -> None:
    """The training distribution (``vary``, ``sojourn``) stays with the training: the evaluated
    configuration's tracker and conditions apply, and the difference is reported."""
    from imm_gym.cli.policies import agent_overrides
    from imm_gym.sim.presets import CONTINUOUS_BANK

    recorded = {
        "action_mode": "set",
        "bank": CONTINUOUS_BANK,
        "vary": {"T": (0.5, 5.0), "sigma_r": (10.0, 100.0)},
        "sojourn": (60.0, 20.0, 20.0),
        "velocity_std": 10.0,
    }
    kept, notes = agent_overrides(object(), recorded, EnvConfig(scenario="paper"))
    assert kept == {"action_mode": "set"}
    assert set(notes["tracker_differs"]) == {"bank", "sojourn"}


def test_an_agent_is_scored_with_the_evaluation_s_divergence_cap() -> None:
    """An agent trained with another divergence threshold (or engine) is capped as every other
    policy of the evaluation is: those settings are the evaluation's, not the agent's."""
    from imm_gym.cli.policies import agent_overrides

    recorded = {"action_mode": "stay", "divergence_error": 40.0, "divergence_cov": 1e6,
                "engine": "numpy"}
    kept, _ = agent_overrides(object(), recorded, EnvConfig(scenario="paper"))
    assert kept == {"action_mode": "stay"}


def test_an_agent_starts_its_tracks_as_the_rules_do() -> None:
    """A trained agent's recorded ``velocity_std`` (the prior standard deviation of the first
    velocity estimate) does not follow it to the evaluation: every policy's tracks start from
    the same prior and so give the same estimates (it did, and the agents trained across
    trackers started with a velocity prior twice as wide as the rules' on the suite)."""
    from imm_gym.cli.comparison import evaluate

    class Zero:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros((obs.shape[0], 9)), None

    recorded = {"action_mode": "scale", "velocity_std": 10.0}
    _, rollouts = evaluate(["fixed"], "paper", 3, 0, extra={"zero": (Zero(), recorded)},
                           clairvoyant=False)
    np.testing.assert_array_equal(rollouts["zero"].estimate, rollouts["fixed"].estimate)


def test_a_file_with_an_agent_s_settings_evaluates_every_policy_on_its_tracker() -> None:
    """``examples/across_trackers.yaml`` says what the default agent is trained as too (the
    evidence's base, its features, its reward): the rules run on its tracker and targets in
    their own modes, not in the agent's."""
    overrides = read_env_config(Path(__file__).parents[2] / "examples" / "across_trackers.yaml")
    results, rollouts = evaluate(["fixed", "best-fixed"], "random", 2, 0, clairvoyant=False,
                                 env_config=overrides)
    assert set(rollouts) == {"fixed", "best-fixed"}
    assert np.isfinite(results["policies"]["fixed"]["armse_pos"])


def test_each_case_of_a_suite_names_its_bank(tmp_path) -> None:
    """A case whose file gives a bank of its own is labelled ``env-config`` in its meta, as
    ``--env-config FILE`` is (it was always ``paper``: the benchmark's ``atc`` runs CV and
    CT(±2°/s) with continuous noise); a case without one runs the paper's bank."""
    folder = _directory_suite(tmp_path)
    results = evaluate_suite(["fixed"], str(folder), 2, 0, clairvoyant=False)
    assert results["scenarios"]["four"]["meta"]["bank"] == "env-config"
    assert results["scenarios"]["fine"]["meta"]["bank"] == "paper"
    assert results["meta"]["bootstrap"]["paired"]["resamples"] == 2000
