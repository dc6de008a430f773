"""The evaluate command line's checks made before any work: what they let through as well as
what they refuse (each admitted case reaches the evaluation, here a stub that stops it)."""

from __future__ import annotations

import pytest

from imm_gym.cli.evaluate import main


class _Reached(Exception):
    """The stub evaluation was called: every check before it passed."""


@pytest.fixture
def stub_evaluation(monkeypatch: pytest.MonkeyPatch) -> list[tuple]:
    calls: list[tuple] = []

    def evaluate(policies, scenario, runs, seed, **kw):
        calls.append((list(policies), runs, seed))
        raise _Reached

    monkeypatch.setattr("imm_gym.cli.evaluate.evaluate", evaluate)
    return calls


@pytest.mark.parametrize("name", ["r.PNG", "r.Png", "r.png"])
def test_a_tradeoff_png_suffix_in_any_case_is_admitted(tmp_path, stub_evaluation, name) -> None:
    """matplotlib reads the format from the suffix case-blind: 'R.PNG' is a PNG, not refused."""
    with pytest.raises(_Reached):
        main(["--policy", "fixed", "--runs", "2", "--quiet", "--tradeoff", str(tmp_path / name)])
    assert stub_evaluation == [(["fixed"], 2, 0)]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        # Ray runs the tracking of one scenario's roll-outs; the seed systems run their own
        (["--ray", "auto"], "--ray does not apply to --scenario seed003"),
        (["--ray"], "--ray does not apply to --scenario seed003"),
        # the seed systems compare the tuned banks with the classical IMM-EKF, no paired reference
        (["--reference", "fixed"], "--reference does not apply to --scenario seed003"),
        (
            ["--tuned", "bbsca="],
            "--tuned must be POLICY=FILE (e.g. bbsca=tuned.json), got 'bbsca='",
        ),
        (
            ["--tuned", "=t.json"],
            "--tuned must be POLICY=FILE (e.g. bbsca=tuned.json), got '=t.json'",
        ),
    ],
)
def test_a_seed_system_refuses_what_it_does_not_take(
    argv, message, capsys, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Refused as usage errors (exit 2) before the seed system is evaluated."""
    monkeypatch.setattr(
        "imm_gym.papers.tuned_comparison.evaluate_system",
        lambda *a, **kw: pytest.fail("the seed system was evaluated"),
    )
    with pytest.raises(SystemExit) as exc:
        main(["--scenario", "seed003", "--policy", "bbsca", "--runs", "1", "--quiet", *argv])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def _meta(tmp_path, monkeypatch: pytest.MonkeyPatch, argv: list[str]) -> dict:
    """The JSON's meta the command line writes around an evaluation (a stub that names the
    scenario 'file' when it came from the --env-config file, as the evaluation does)."""
    import json

    def evaluate(policies, scenario, runs, seed, **kw):
        named = scenario if isinstance(scenario, str) else "file"
        return {"policies": {}, "meta": {"scenario": named}}, {}

    monkeypatch.setattr("imm_gym.cli.evaluate.evaluate", evaluate)
    monkeypatch.setattr("imm_gym.cli.evaluate.render_tables", lambda results: None)
    out = tmp_path / "r.json"
    assert main(["--policy", "fixed", "--runs", "1", "--quiet", "--json", str(out), *argv]) == 0
    return json.loads(out.read_text())["meta"]


def test_meta_names_the_bank_and_scenario_the_command_line_chose(
    tmp_path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """meta.bank: the preset the run's bank is (--bank's, or the file's by name or written out
    in full), else 'env-config' for a bank of the file's own, and 'paper' without one;
    meta.scenario: --scenario, else the file's scenario name, else the file's path where the
    file gives the scenario itself."""
    bank = tmp_path / "bank.yaml"
    bank.write_text("bank: hetero\nscenario: atc\n")
    meta = _meta(tmp_path, monkeypatch, ["--env-config", str(bank)])
    assert (meta["bank"], meta["scenario"]) == ("hetero", "atc")
    meta = _meta(tmp_path, monkeypatch, ["--env-config", str(bank), "--bank", "paper"])
    assert meta["bank"] == "paper"
    assert _meta(tmp_path, monkeypatch, [])["bank"] == "paper"
    paper = tmp_path / "paper.yaml"
    paper.write_text("bank: paper\n")
    assert _meta(tmp_path, monkeypatch, ["--env-config", str(paper)])["bank"] == "paper"
    ct = "{kind: ct, turn_rate_deg: %s, noise: continuous, intensity: 0.06}"
    for rates, name in ((("4.0", "-4.0"), "cv-ct-continuous"), (("4.0", "-3.0"), "env-config")):
        written = tmp_path / "written.yaml"
        models = ", ".join(ct % rate for rate in rates)
        written.write_text(f"bank: [{{kind: cv, noise: continuous, intensity: 0.12}}, {models}]\n")
        assert _meta(tmp_path, monkeypatch, ["--env-config", str(written)])["bank"] == name
    own = tmp_path / "own.yaml"
    own.write_text("scenario: {segments: [{duration: 10}]}\n")
    meta = _meta(tmp_path, monkeypatch, ["--env-config", str(own)])
    assert meta["scenario"] == str(own)


def _evaluated_on(monkeypatch: pytest.MonkeyPatch, argv: list[str]):
    """The EnvConfig the command line hands the evaluation (stopped there)."""
    from imm_gym.sim.env_config import EnvConfig

    seen = []

    def evaluate(policies, scenario, runs, seed, env_config=None, **kw):
        seen.append(EnvConfig.build({**(env_config or {}), "scenario": scenario}))
        raise _Reached

    monkeypatch.setattr("imm_gym.cli.evaluate.evaluate", evaluate)
    with pytest.raises(_Reached):
        main(["--policy", "fixed", "--runs", "1", "--quiet", *argv])
    (config,) = seen
    return config


def test_bank_replaces_the_env_config_files_filter_too(
    tmp_path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """--bank paper is the paper's CV/CT bank with its SVD-UKF (help), whatever filter the
    file named; without --bank the file's filter runs."""
    path = tmp_path / "c.yaml"
    path.write_text("filter: ekf\n")
    assert _evaluated_on(monkeypatch, ["--env-config", str(path)]).filter == "ekf"
    assert (
        _evaluated_on(monkeypatch, ["--env-config", str(path), "--bank", "paper"]).filter == "ukf"
    )
