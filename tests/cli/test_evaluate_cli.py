"""The evaluation tool: command line, JSON layout, common random numbers, figures, errors."""

from __future__ import annotations

import json
import shlex
import sys

import numpy as np
import pytest
from helpers import printed_row

from baselines import REGISTRY, BuildContext, FixedTPM, register
from imm_gym.cli.comparison import evaluate
from imm_gym.cli.evaluate import main
from imm_gym.evaluation.rollout import evaluation_config, rollout, score
from imm_gym.sim.env_config import EnvConfig
from imm_gym.validation import ConfigError


def test_cli_json_layout_and_figures(tmp_path, capsys) -> None:
    out = tmp_path / "res.json"
    figs = tmp_path / "figs"
    code = main(
        [
            "--policy",
            "fixed",
            "--policy",
            "tip-imm",
            "--scenario",
            "paper",
            "--runs",
            "6",
            "--seed",
            "3",
            "--json",
            str(out),
            "--plots",
            str(figs),
            "--quiet",
        ]
    )
    assert code == 0
    data = json.loads(out.read_text())
    for name in ("fixed", "tip-imm"):
        row = data["policies"][name]
        for key in ("armse_pos", "armse_pos_x", "armse_pos_y", "armse_vel_x", "armse_vel_y"):
            assert np.isfinite(row[key]) and row[key] > 0
        assert 0.0 <= row["nis"]["inside"] <= 1.0 and 0.0 <= row["mode_accuracy"] <= 1.0
        assert 0.0 < row["mode_prob_tv"] < 1.0
        assert row["peak_error"] > row["maneuver_response"] > row["armse_pos"] / 2
    assert data["paired"]["reference"] == "fixed"
    d = data["paired"]["differences"]["tip-imm"]
    assert d["low"] <= d["diff"] <= d["high"]
    assert data["clairvoyant"]["armse_pos"] < data["policies"]["fixed"]["armse_pos"]
    assert data["clairvoyant"]["role"] == "bound" and data["clairvoyant"]["beaten_by"] == {}
    assert data["clairvoyant"]["maneuver_response"] < data["policies"]["fixed"]["maneuver_response"]
    assert data["meta"]["runs"] == 6 and data["meta"]["seeds"] == "3..8"
    for png in ("trajectory.png", "mode_probs.png", "rmse.png"):
        assert (figs / png).stat().st_size > 1000
    printed = capsys.readouterr().out
    assert "paper: TIP-IMM" in printed and "17.0247" in printed
    # every policy's printed ARMSE cells are its JSON values, in the columns' order, and the
    # paired difference's CI is printed [low, high]
    keys = ("armse_pos", "armse_pos_x", "armse_pos_y", "armse_vel_x", "armse_vel_y")
    for name in ("fixed", "tip-imm"):
        row = data["policies"][name]
        cells = printed_row(printed, name)
        assert cells[1:6] == [f"{row[k]:.4f}" for k in keys]
        assert cells[8] == f"{100 * row['mode_accuracy']:.1f}%"
    assert printed_row(printed, "tip-imm", after="Position ARMSE minus")[1:] == [
        f"{d['diff']:+.3f}", f"[{d['low']:+.3f}, {d['high']:+.3f}]", f"{100 * d['relative']:+.2f}%"
    ]
    assert "clairvoyant (bound)" in printed and "maneuver response (m)" in printed


def test_common_random_numbers_across_policies() -> None:
    """Every policy meets the same targets through the same measurements: the same noise, the
    same missed detections (a sensor that misses some, so that their flags can differ)."""
    _, rollouts = evaluate(["fixed", "window", "amp-imm"], "random", 4, 11, clairvoyant=False,
                           env_config={"sensor": {"detection_prob": 0.8}})
    first, *others = rollouts.values()
    assert np.isnan(first.measurements).any() and not np.isnan(first.measurements).all()
    for other in others:
        np.testing.assert_array_equal(other.truth, first.truth)
        np.testing.assert_array_equal(other.measurements, first.measurements)  # NaN: missed


def test_roll_outs_of_other_targets_are_not_paired(monkeypatch) -> None:
    """The evaluation checks that every policy met the same targets before it pairs them."""
    import dataclasses

    import imm_gym.cli.comparison as comparison

    calls = []

    def moved(policy, config, runs, seed, **kwargs):
        out = rollout(policy, config, runs, seed, **kwargs)
        calls.append(out)
        if len(calls) == 2:  # the second policy's targets, one run moved by a metre
            truth = out.truth.copy()
            truth[1, :, 0] += 1.0
            out = dataclasses.replace(out, truth=truth)
        return out

    monkeypatch.setattr(comparison, "rollout", moved)
    with pytest.raises(ValueError, match=r"'window' was rolled out on other targets .*\[1\]"):
        evaluate(["fixed", "window"], "random", 3, 0, clairvoyant=False)


def test_scenario_file(tmp_path) -> None:
    path = tmp_path / "scen.json"
    path.write_text(
        json.dumps(
            {
                "segments": [{"duration": 30}, {"duration": 20, "turn_rate_deg": 2.0}],
                "position": [4000.0, 1000.0],
                "velocity": [-10.0, 12.0],
            }
        )
    )
    assert main(["--policy", "fixed", "--scenario", str(path), "--runs", "3", "--quiet"]) == 0


def test_clairvoyant_beaten_on_a_tiny_run_set_is_a_reference(tmp_path, capsys) -> None:
    # one run (seed 5) of the paper scenario: the fixed TPM's position ARMSE is below the
    # clairvoyant filter's, TIP-IMM's X ARMSE too
    out = tmp_path / "res.json"
    argv = ["--policy", "fixed", "--policy", "tip-imm", "--runs", "1", "--seed", "5"]
    assert main([*argv, "--quiet", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    c = data["clairvoyant"]
    assert c["role"] == "reference"
    assert c["note"] == "reference: beaten by fixed, tip-imm"
    assert "armse_pos" in c["beaten_by"]["fixed"] and "armse_pos_x" in c["beaten_by"]["tip-imm"]
    assert data["policies"]["fixed"]["armse_pos"] < c["armse_pos"]
    printed = capsys.readouterr().out
    assert "clairvoyant (reference)" in printed and "clairvoyant (bound)" not in printed
    assert "reference: beaten by fixed, tip-imm" in printed


def test_the_clairvoyant_filters_runs_are_held_by_the_policies_divergence_rule() -> None:
    """A target 335 m from the sonar under an EKF: some of the clairvoyant filter's runs lose
    the target (errors of km) as the policies' do; they are held at ``divergence_error`` from the
    step they diverge at and counted, not averaged in at their raw errors."""
    scenario = {
        "segments": [{"duration": 30}, {"duration": 20, "turn_rate_deg": 3.0}, {"duration": 30}],
        "position": [300.0, -150.0],
        "velocity": [-10.0, 5.0],
    }
    results, _ = evaluate(["fixed"], scenario, 20, 0, env_config={"filter": "ekf",
                                                                   "divergence_error": 500.0})
    c, fixed = results["clairvoyant"], results["policies"]["fixed"]
    assert fixed["diverged"] > 0 and c["diverged"] > 0
    assert c["armse_pos"] <= 500.0 and c["peak_error"] <= 500.0


def test_scenario_with_acceleration_has_no_clairvoyant_row(tmp_path, capsys) -> None:
    path = tmp_path / "accel.json"
    path.write_text(
        json.dumps(
            {
                "segments": [
                    {"duration": 20},
                    {"duration": 10, "accel": 1.0},
                    {"duration": 20, "turn_rate_deg": 2.0},
                ],
                "position": [4000.0, 1000.0],
                "velocity": [-10.0, 12.0],
            }
        )
    )
    out = tmp_path / "res.json"
    argv = ["--policy", "fixed", "--policy", "tip-imm", "--scenario", str(path), "--runs", "2"]
    assert main([*argv, "--quiet", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["clairvoyant"] == {
        "role": "skipped",
        "note": "skipped: the clairvoyant filter is defined for straight and turn segments only; "
        "2 of 2 runs have acceleration segments",
    }
    for row in data["policies"].values():
        assert np.isfinite(row["armse_pos"]) and row["maneuver_response"] is not None
    printed = " ".join(capsys.readouterr().out.split())
    assert "clairvoyant (" not in printed
    assert "skipped: the clairvoyant filter is defined for straight and turn" in printed


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--policy", "nope"], "unknown policy"),
        (["--policy", "fixed", "--runs", "0"], "--runs must be >= 1"),
        (["--policy", "fixed", "--seed", "-1"], "--seed must be >= 0"),
        (["--policy", "fixed", "--scenario", "missing.json"], "--scenario must be"),
        (["--policy", "fixed", "--policy", "fixed"], "given twice"),
        (["--policy", "fixed", "--reference", "tip-imm"], "--reference"),
        (["--policy", "missing_dir/model.zip"], "no trained agent"),
    ],
)
def test_cli_rejects_bad_arguments(argv, message, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--quiet"])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--seed", "50000000"], "--seed must be in [0, 48999900], got 50000000"),
        (["--seed", "100000000"], "--seed must be in [0, 48999900], got 100000000"),
        # a tuner's last training seed, 48999901 + 1000000 + 99, would be a validation seed
        (["--seed", "48999901"], "--seed must be in [0, 48999900], got 48999901"),
        (["--runs", "1000001"], "--runs must be in [1, 1000000], got 1000001"),
        (["--runs", "100000000"], "--runs must be in [1, 1000000], got 100000000"),
    ],
)
def test_seeds_of_validation_training_or_tuning_runs_are_refused(
    argv, message, capsys, monkeypatch
) -> None:
    """Evaluation seeds stay below the agents' validation seeds (50 000 000+, those that picked
    a checkpoint) and training slots (100 000 000+), with the tuners' training seeds; and the
    runs below the tuners' offset (1 000 000), which they would overlap. Refused before any
    work; ``--seed 48999900`` (the most) and seeds 20 000 000+ are evaluated."""
    from imm_gym.seeding import TRAIN_SEED_BASE, TRAIN_SEED_OFFSET, VALIDATION_SEED_BASE

    with pytest.raises(SystemExit) as exc:
        main(["--policy", "fixed", *argv, "--quiet"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and message in err
    if argv[0] == "--seed":
        assert f"--seed + {TRAIN_SEED_OFFSET} + r" in err
        assert f"({VALIDATION_SEED_BASE}+)" in err and f"({TRAIN_SEED_BASE}+)" in err
    seeds = []
    monkeypatch.setattr(
        "imm_gym.cli.evaluate.evaluate",
        lambda policies, scenario, runs, seed, **kw: seeds.append((seed, runs)) or 1 / 0,
    )
    for seed in ("48999900", "20000000"):
        with pytest.raises(ZeroDivisionError):
            main(["--policy", "fixed", "--seed", seed, "--runs", "1000000", "--quiet"])
    assert seeds == [(48_999_900, 1_000_000), (20_000_000, 1_000_000)]


def test_a_reference_not_evaluated_is_refused_before_any_work(monkeypatch) -> None:
    """A --reference that is not among the policies is refused before a policy is tuned or
    rolled out (it was refused after every roll-out)."""

    def no_work(*args, **kwargs):
        raise AssertionError("work done before the reference was checked")

    monkeypatch.setattr("imm_gym.cli.comparison.make_policy", no_work)
    monkeypatch.setattr("imm_gym.cli.comparison.rollout", no_work)
    with pytest.raises(ConfigError, match="--reference 'tip-imm' is not among the evaluated"):
        evaluate(["fixed", "best-fixed"], "paper", 200, 0, reference="tip-imm")


@pytest.fixture
def throwaway_baseline():
    """A tuned baseline registered for one test: the fixed TPM at stay 1/2, its training ARMSE
    in the notes; unregistered afterwards (if the test did not)."""

    @register("throwaway", help="test only: the fixed TPM at stay 1/2")
    def build(context: BuildContext) -> tuple[FixedTPM, dict[str, object]]:
        policy = FixedTPM(context.n_models, 0.5)
        return policy, {"train_armse": context.train_armse(policy), "seeds": context.train_seeds()}

    yield "throwaway"
    if "throwaway" in REGISTRY:
        REGISTRY.unregister("throwaway")


def test_a_registered_baseline_is_listed_and_evaluated(throwaway_baseline, tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    listed = " ".join(capsys.readouterr().out.split())
    assert "window: the TPM estimated from the model probabilities of a sliding window;" in listed
    assert "throwaway: test only: the fixed TPM at stay 1/2" in listed
    out = tmp_path / "res.json"
    argv = ["--policy", "throwaway", "--runs", "3", "--seed", "2", "--quiet", "--json", str(out)]
    assert main(argv) == 0
    row = json.loads(out.read_text())["policies"]["throwaway"]
    policy = FixedTPM(3, 0.5)
    cfg = evaluation_config(EnvConfig(scenario="paper"), policy.env_overrides)
    assert row["armse_pos"] == score(rollout(policy, cfg, 3, 2))["armse_pos"]
    assert row["train_armse"] == score(rollout(policy, cfg, 100, 1_000_002))["armse_pos"]
    assert row["seeds"] == "1000002..1000101"
    REGISTRY.unregister("throwaway")
    with pytest.raises(SystemExit):
        main(argv)
    assert "unknown policy 'throwaway'" in capsys.readouterr().err


def test_the_hetero_bank_says_why_there_is_no_clairvoyant_row() -> None:
    results, _ = evaluate(["fixed"], "paper", 2, 0, bank="hetero")
    assert results["clairvoyant"] == {
        "role": "skipped",
        "note": "skipped: the clairvoyant filter runs linear CV/CT models; this bank is "
        "NCV/CT/CTRA",
    }
    assert results["policies"]["fixed"]["maneuver_response"] > 0.0


def test_the_tradeoff_runs_on_a_training_file(tmp_path) -> None:
    """A configuration file that also says what an agent is trained as (action mode, stay base,
    features) gives the sweep the evaluated tracker, as it gives every policy: the configured
    stay's point is the ``fixed`` row (it failed on the agent's settings before)."""
    out, figure = tmp_path / "r.json", tmp_path / "t.png"
    argv = ["--policy", "fixed", "--env-config", "examples/across_trackers_paper.yaml",
            "--runs", "2", "--quiet", "--no-clairvoyant", "--json", str(out),
            "--tradeoff", str(figure)]
    assert main(argv) == 0
    results = json.loads(out.read_text())
    fixed = results["tradeoff"]["fixed"]
    assert fixed["0.995"]["armse_pos"] == results["policies"]["fixed"]["armse_pos"]


def test_the_tradeoff_figure_sweeps_the_fixed_tpms_on_the_same_runs(tmp_path) -> None:
    """``--tradeoff``: the classical IMM at every stay of the grid, on the evaluation's runs (the
    configured stay's point is the ``fixed`` policy's row), and each policy's point."""
    from baselines.best_fixed import STAY_GRID

    out, figure = tmp_path / "r.json", tmp_path / "t.png"
    argv = ["--policy", "fixed", "--policy", "tip-imm", "--scenario", "paper", "--runs", "4",
            "--quiet", "--no-clairvoyant", "--json", str(out), "--tradeoff", str(figure)]
    assert main(argv) == 0
    assert figure.stat().st_size > 10_000
    results = json.loads(out.read_text())
    fixed = results["tradeoff"]["fixed"]
    assert [float(s) for s in fixed] == pytest.approx(list(STAY_GRID), rel=1e-6)
    assert len({row["armse_pos"] for row in fixed.values()}) == len(STAY_GRID)
    classical = results["policies"]["fixed"]
    assert fixed["0.995"]["armse_pos"] == classical["armse_pos"]
    assert fixed["0.995"]["mode_accuracy"] == classical["mode_accuracy"]
    assert set(results["tradeoff"]["policies"]) == {"fixed", "tip-imm"}
    with pytest.raises(SystemExit):
        main(["--policy", "fixed", "--suite", "benchmark", "--tradeoff", str(figure)])


@pytest.mark.parametrize("name", ["r.txt", "r"])
def test_a_tradeoff_file_that_is_not_a_png_is_refused_before_the_evaluation(
    tmp_path, capsys, name: str
) -> None:
    """matplotlib takes the format from the suffix: '.txt' failed after the whole evaluation
    (the JSON lost with it), no suffix wrote FILE.png beside the name printed."""
    with pytest.raises(SystemExit) as exc:
        main(["--policy", "fixed", "--runs", "2", "--quiet", "--tradeoff", str(tmp_path / name)])
    assert exc.value.code == 2
    assert "the figure is a PNG, end it in .png" in capsys.readouterr().err


def test_tuned_banks_apply_to_the_seed_systems_only(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["--policy", "bbsca", "--tuned", "bbsca=t.json", "--scenario", "paper"])
    assert "--tuned applies to --scenario seed002|seed003" in capsys.readouterr().err


def test_the_json_and_the_table_say_how_diverged_runs_are_scored(capsys) -> None:
    """``meta.divergence``: the cap and what it does to the scores; said under the table when a
    policy has a diverged run (a cap of 40 m: most paper runs diverge)."""
    from imm_gym.cli.tables import render_tables

    results, _ = evaluate(["fixed"], "paper", 4, 0, clairvoyant=False,
                          env_config={"divergence_error": 40.0})
    divergence = results["meta"]["divergence"]
    assert divergence["error_m"] == 40.0 and "NIS and NEES are over the steps before" in (
        divergence["scored"]
    )
    assert results["policies"]["fixed"]["diverged"] > 0
    render_tables(results)
    printed = " ".join(capsys.readouterr().out.split())
    assert "Diverged runs (error above 40 m): a diverged run's position error is held" in printed
    assert "its velocity error at the one it diverged with" in printed


def test_the_papers_rows_only_beside_the_papers_setting(capsys) -> None:
    """Table 2's rows are printed beside results on the paper scenario with the paper's bank and
    filter only: ``--bank cv-ct-continuous`` (another noise model) gets none."""
    from imm_gym.cli.tables import paper_setting

    argv = ["--policy", "fixed", "--scenario", "paper", "--runs", "2", "--no-clairvoyant",
            "--quiet"]
    assert main([*argv, "--bank", "cv-ct-continuous"]) == 0
    assert "paper: TIP-IMM" not in capsys.readouterr().out
    assert main(argv) == 0
    assert "paper: TIP-IMM" in capsys.readouterr().out
    meta = {"scenario": "paper", "env_config": None, "bank": "paper", "filter": "ukf"}
    assert paper_setting(meta)
    assert not paper_setting({**meta, "filter": "ekf"})
    assert not paper_setting({**meta, "bank": "hetero"})


def test_meta_records_the_learning_stack_and_the_bootstrap(tmp_path, capsys) -> None:
    """``meta.versions`` adds torch, stable-baselines3, sb3-contrib and numba where installed
    (their metadata: nothing imported for it), the existing keys kept; ``meta.bootstrap`` gives
    the paired bootstrap's and the seeds' IQM's settings, and a line under the paired differences
    says them."""
    from importlib import metadata

    out = tmp_path / "res.json"
    argv = ["--policy", "fixed", "--policy", "tip-imm", "--runs", "2", "--no-clairvoyant"]
    assert main([*argv, "--quiet", "--json", str(out)]) == 0
    meta = json.loads(out.read_text())["meta"]
    versions = meta["versions"]
    assert {"imm_gym", "numpy", "scipy", "gymnasium", "python"} <= set(versions)
    for name in ("torch", "stable-baselines3", "numba"):
        assert versions[name] == metadata.version(name)
    assert meta["bootstrap"]["paired"] == {
        "resamples": 2000, "seed": 0, "level": 0.95, "interval": "percentile",
        "resampled": "runs, the same for both policies (paired)",
    }
    iqm = meta["bootstrap"]["seeds_iqm"]
    assert (iqm["resamples"], iqm["seed"], iqm["level"]) == (10_000, 0, 0.95)
    printed = " ".join(capsys.readouterr().out.split())
    assert "Paired bootstrap: 2000 resamples of the runs" in printed
    assert "seed 0, 95% percentile interval" in printed


def test_meta_records_the_command_main_parsed_quoted(tmp_path, monkeypatch) -> None:
    """``meta.command`` is the argv ``main`` was given (not the process's), each argument quoted
    for a shell: a path with a space splits back into one argument."""
    out = tmp_path / "a dir" / "res.json"
    argv = ["--policy", "fixed", "--runs", "2", "--no-clairvoyant", "--quiet", "--json", str(out)]
    monkeypatch.setattr(sys, "argv", ["evaluate", "--policy", "something-else"])
    assert main(argv) == 0
    command = json.loads(out.read_text())["meta"]["command"]
    assert command.startswith("python -m imm_gym.evaluate ")
    assert shlex.split(command)[3:] == argv
    monkeypatch.setattr(sys, "argv", ["evaluate", *argv])
    assert main() == 0
    assert json.loads(out.read_text())["meta"]["command"] == command


def test_a_shard_that_died_ends_the_command_in_one_line(monkeypatch, capsys) -> None:
    """A Ray shard dying mid-run (:class:`~imm_gym.evaluation.distributed.ShardError`) stops the
    command with one error line, exit status 1, not a traceback; other errors are not caught."""
    import imm_gym.cli.evaluate as cli
    from imm_gym.evaluation.distributed import ShardError

    def died(*args, **kwargs):
        raise ShardError("evaluation shard 1 of 2 (runs 2..3 of 4) died: the node ended")

    monkeypatch.setattr(cli, "evaluate", died)
    with pytest.raises(SystemExit) as exc:
        main(["--policy", "fixed", "--runs", "4", "--quiet"])
    assert exc.value.code == 1
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "python -m imm_gym.evaluate: error: evaluation shard 1 of 2 (runs 2..3 of 4) died: the "
        "node ended"
    ]

    def failed(*args, **kwargs):
        raise RuntimeError("not a shard")

    monkeypatch.setattr(cli, "evaluate", failed)
    with pytest.raises(RuntimeError, match="not a shard"):
        main(["--policy", "fixed", "--runs", "4", "--quiet"])


def test_meta_records_the_code_state_read_as_the_run_starts(tmp_path, monkeypatch) -> None:
    """``meta.versions`` is read once, before any roll-out (it was read after them: a commit made
    while the evaluation ran was recorded as the code run), for one scenario, a suite (its meta
    and every case's) and a seed system."""
    import imm_gym.cli.comparison as comparison
    import imm_gym.cli.evaluate as cli
    import imm_gym.cli.suite as suite_module
    import imm_gym.papers.tuned_comparison as systems

    state = {"git_commit": "at start"}

    def commit_while_running(run):
        def wrapped(*args, **kwargs):
            state["git_commit"] = "committed mid-run"
            return run(*args, **kwargs)

        return wrapped

    for module in (comparison, suite_module, cli):
        monkeypatch.setattr(module, "versions", lambda *optional: dict(state))
    monkeypatch.setattr(comparison, "rollout", commit_while_running(comparison.rollout))
    monkeypatch.setattr(systems, "run_bank", commit_while_running(systems.run_bank))
    results, _ = evaluate(["fixed"], "paper", 2, 0, clairvoyant=False)
    assert results["meta"]["versions"] == {"git_commit": "at start"}
    state["git_commit"] = "at start"
    folder = tmp_path / "cases"
    folder.mkdir()
    for name in ("a", "b"):
        (folder / f"{name}.yaml").write_text("scenario: paper\n")
    suite = suite_module.evaluate_suite(["fixed"], str(folder), 2, 0, clairvoyant=False)
    assert suite["meta"]["versions"] == {"git_commit": "at start"}
    cases = [r["meta"]["versions"] for r in suite["scenarios"].values()]
    assert cases == [{"git_commit": "at start"}] * 2
    state["git_commit"] = "at start"
    out = tmp_path / "system.json"
    argv = ["--scenario", "seed003", "--policy", "fixed", "--runs", "2", "--quiet"]
    assert main([*argv, "--json", str(out)]) == 0
    assert state["git_commit"] == "committed mid-run"
    assert json.loads(out.read_text())["meta"]["versions"] == {"git_commit": "at start"}


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--policy", "fixed", "--tuned", "bbsca=/nonexistent.json"],
         "--tuned bbsca=FILE: 'bbsca' is not a tuned policy evaluated here"),
        (["--policy", "fixed", "--policy", "bbsca", "--tuned", "BBSCA=/x.json"],
         "the keys allowed are those of ['bbsca', 'sca'] given as --policy (['fixed', 'bbsca']): "
         "['bbsca']"),
        (["--policy", "sca", "--tuned", "bogus=/x.json"], "'bogus' is not a tuned policy"),
        (["--policy", "bbsca", "--tuned", "bbsca=/a.json", "--tuned", "bbsca=/b.json"],
         "--tuned bbsca given twice: '/a.json' and '/b.json'"),
    ],
)
def test_a_tuned_file_that_no_policy_loads_is_refused(argv, message, monkeypatch, capsys) -> None:
    """A ``--tuned`` key that is not a tuned policy asked for (its file was silently unused) or
    given twice is a usage error before any run."""
    import imm_gym.papers.tuned_comparison as systems

    monkeypatch.setattr(systems, "draw", lambda *a, **k: pytest.fail("a run started"))
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--scenario", "seed003", "--runs", "3", "--quiet"])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err
