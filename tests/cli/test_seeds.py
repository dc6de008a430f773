"""Training seeds of one agent aggregated by ``python -m imm_gym.evaluate --agent-seeds``:
interquartile means with stratified bootstrap CIs, per scenario and over a suite."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from helpers import printed_row, shipped_agent

from imm_gym.cli.evaluate import main
from imm_gym.cli.seeds import across_seeds, render_seeds, suite_across_seeds


def _result(armse: dict[str, float], accuracy: float = 0.6, ref: str = "best-fixed") -> dict:
    """One scenario's result: rows and paired differences against ``ref``."""
    return {
        "policies": {n: {"armse_pos": a, "mode_accuracy": accuracy} for n, a in armse.items()},
        "paired": {
            "reference": ref,
            "differences": {
                name: {"diff": a - armse[ref], "relative": (a - armse[ref]) / armse[ref]}
                for name, a in armse.items()
                if name != ref
            },
        },
    }


def _expected_cells(s: dict) -> list[str]:
    """The cells of a scenario's row from its JSON: IQM [low, high] of each quantity."""
    a, m, r = s["armse_pos"], s["mode_accuracy"], s["relative_vs_reference"]
    return [
        f"{a['iqm']:.2f} [{a['low']:.2f}, {a['high']:.2f}]",
        f"{100 * m['iqm']:.1f}% [{100 * m['low']:.1f}, {100 * m['high']:.1f}]",
        f"{100 * r['iqm']:+.2f}% [{100 * r['low']:+.2f}, {100 * r['high']:+.2f}] "
        f"({s['reference']})",
    ]


def test_per_scenario_the_seeds_values_and_their_iqm() -> None:
    armse = {"best-fixed": 20.0, "s0": 18.0, "s1": 19.0, "s2": 30.0, "s3": 19.5, "s4": 18.5}
    seeds = ["s0", "s1", "s2", "s3", "s4"]
    out = across_seeds(_result(armse), seeds)
    assert out["armse_pos"]["per_seed"] == [18.0, 19.0, 30.0, 19.5, 18.5]
    # the middle three of 18, 18.5, 19, 19.5, 30 (floor(5 / 4) = 1 cut from each end)
    assert out["armse_pos"]["iqm"] == pytest.approx(19.0)
    assert out["armse_pos"]["low"] <= 19.0 <= out["armse_pos"]["high"] < 30.0
    np.testing.assert_allclose(
        out["relative_vs_reference"]["per_seed"], [-0.1, -0.05, 0.5, -0.025, -0.075]
    )
    assert out["relative_vs_reference"]["iqm"] == pytest.approx(-0.05)
    assert out["reference"] == "best-fixed" and out["seeds"] == seeds


def test_a_seed_without_a_paired_difference_is_an_error() -> None:
    """A seed missing from the paired differences (the reference itself) has no relative
    difference: an error, not a zero in the seeds' IQM."""
    armse = {"best-fixed": 20.0, "s0": 18.0, "s1": 19.0}
    with pytest.raises(ValueError, match="seed best-fixed has no paired difference"):
        across_seeds(_result(armse), ["s0", "s1", "best-fixed"])


def test_over_a_suite_scenarios_are_the_strata(capsys) -> None:
    """The relative differences are against the reference (``--reference``, also with
    ``--bar``), which the JSON and the table name."""
    seeds = ["a", "b", "c"]
    results = {
        "scenarios": {
            "easy": _result({"best-fixed": 10.0, "a": 9.0, "b": 9.5, "c": 10.5}),
            "hard": _result({"best-fixed": 50.0, "a": 55.0, "b": 60.0, "c": 50.0}),
        }
    }
    for scenario, accuracies in (("easy", (0.5, 0.7, 0.9)), ("hard", (0.2, 0.3, 0.6))):
        for seed, accuracy in zip(seeds, accuracies, strict=True):
            results["scenarios"][scenario]["policies"][seed]["mode_accuracy"] = accuracy
    out = suite_across_seeds(results, seeds)
    relative = np.array([[-0.1, -0.05, 0.05], [0.1, 0.2, 0.0]])
    # by hand: 10000 resamples (seed 0), each scenario's three seeds drawn with replacement from
    # its own; the IQM of 6 values is the mean of the middle 4 (floor(6 / 4) = 1 cut at each end)
    picks = np.random.default_rng(0).integers(0, 3, size=(10_000, 2, 3))
    resampled = np.concatenate([relative[0][picks[:, 0]], relative[1][picks[:, 1]]], axis=1)
    boot = np.sort(resampled, axis=1)[:, 1:-1].mean(axis=1)
    expected = {
        "iqm": np.mean([-0.05, 0.0, 0.05, 0.1]),
        "low": np.quantile(boot, 0.025),
        "high": np.quantile(boot, 0.975),
    }
    assert out["relative_vs_reference"] == pytest.approx(expected, rel=1e-9, abs=1e-12)
    assert set(out["scenarios"]) == {"easy", "hard"} and out["not_run"] == []
    assert out["reference"] == "best-fixed"
    render_seeds(out)
    table = capsys.readouterr().out
    # the printed cells are the JSON's IQM [low, high] (10.5 - 9 m wide: low < IQM < high)
    for name in ("easy", "hard"):
        assert printed_row(table, name)[1:] == _expected_cells(out["scenarios"][name])
    assert printed_row(table, "easy")[1:3] == ["9.67 [9.00, 10.50]", "70.0% [50.0, 90.0]"]
    printed = " ".join(table.split())
    pooled = out["relative_vs_reference"]
    assert (
        "all scenarios, relative Δ vs the reference, best-fixed: "
        f"{100 * pooled['iqm']:+.2f}% [{100 * pooled['low']:+.2f}, {100 * pooled['high']:+.2f}]"
    ) in printed
    assert "+2.50% [" in printed


def test_over_a_suite_the_cases_the_seeds_did_not_run_on_are_left_out() -> None:
    """A case whose tracker the seeds cannot read (a bank of another size: ``--suite DIR``) has
    no rows of theirs; the aggregate is over the others and names it."""
    seeds = ["a", "b", "c"]
    easy = _result({"best-fixed": 10.0, "a": 9.0, "b": 9.5, "c": 10.5})
    hard = _result({"best-fixed": 50.0, "a": 55.0, "b": 60.0, "c": 50.0})
    # 'part': a seed ran there, not every one (an aggregate needs them all)
    part = _result({"best-fixed": 30.0, "a": 29.0})
    five = _result({"best-fixed": 30.0})
    results = {"scenarios": {"easy": easy, "five": five, "part": part, "hard": hard}}
    out = suite_across_seeds(results, seeds)
    assert out["not_run"] == ["five", "part"] and list(out["scenarios"]) == ["easy", "hard"]
    without = suite_across_seeds({"scenarios": {"easy": easy, "hard": hard}}, seeds)
    assert out["relative_vs_reference"] == without["relative_vs_reference"]


def test_a_suite_where_no_case_ran_every_seed_has_no_iqm_and_no_nan(capsys) -> None:
    """Each seed ran on some case, none on all: no suite-wide IQM (None and a note, strict JSON:
    it was NaN) and the table says so (it raised a KeyError, losing the evaluation's JSON)."""
    results = {
        "scenarios": {
            "three": _result({"best-fixed": 10.0, "a": 9.0}),
            "four": _result({"best-fixed": 10.0, "b": 9.5}),
        }
    }
    out = suite_across_seeds(results, ["a", "b"])
    assert out["relative_vs_reference"] is None and out["scenarios"] == {}
    assert out["not_run"] == ["three", "four"] and "no scenario ran every seed" in out["note"]
    json.dumps(out, allow_nan=False)
    render_seeds(out)
    printed = " ".join(capsys.readouterr().out.split())
    assert "no scenario ran every seed" in printed and "not run on three, four" in printed


def test_the_command_adds_the_seeds_rows_and_their_aggregate(tmp_path, capsys) -> None:
    dirs = [str(shutil.copytree(shipped_agent(), tmp_path / f"seed_{s}")) for s in range(2)]
    out = tmp_path / "res.json"
    argv = ["--policy", "fixed", "--agent-seeds", *dirs, "--reference", "fixed",
            "--scenario", "paper", "--runs", "3", "--no-clairvoyant", "--quiet"]
    assert main([*argv, "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert list(data["policies"]) == ["fixed", *dirs]
    summary = data["across_seeds"]
    rows = [data["policies"][d]["armse_pos"] for d in dirs]
    assert summary["armse_pos"]["per_seed"] == rows
    assert summary["relative_vs_reference"]["per_seed"] == [
        data["paired"]["differences"][d]["relative"] for d in dirs
    ]
    assert summary["reference"] == "fixed"
    printed = " ".join(capsys.readouterr().out.split())
    assert "Over 2 training seeds" in printed
    assert "Stratified bootstrap: 10000 resamples of the seeds within each scenario" in printed
    assert data["meta"]["bootstrap"]["seeds_iqm"]["resamples"] == 10_000


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--agent-seeds", "a"], "two or more directories"),
        (["--agent-seeds", "a", "a"], "a directory twice"),
        # one directory however spelled: three copies of one seed would give zero-width CIs
        (["--agent-seeds", "d/seed_0", "d/seed_0/", "./d/seed_0"], "a directory twice"),
        (["--agent-seeds", "d/seed_0", "d/x/../seed_0"], "a directory twice"),
        # a file of the directory names the directory the loader reads
        (["--agent-seeds", "d/seed_0", "d/seed_0/agent.json", "d/seed_1"], "a directory twice"),
        (["--agent-seeds", "d/seed_0/policy.safetensors", "./d/seed_0"], "a directory twice"),
        (["--runs", "2"], "at least one --policy"),
        (["--agent-seeds", "a", "b", "--scenario", "seed002"], "--agent-seeds does not apply"),
    ],
)
def test_bad_seed_lists_are_refused(argv, message, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--quiet"])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ([], "needs a reference outside the seeds"),
        (["--policy", "tip-imm", "--reference", "SEED0"], "is one of --agent-seeds"),
        (["--policy", "tip-imm", "--reference", "SEED0/"], "is one of --agent-seeds"),
        (["--policy", "tip-imm", "--reference", "SEED0/../seed_0"], "is one of --agent-seeds"),
        (["--policy", "tip-imm", "--reference", "SEED0/agent.json"], "is one of --agent-seeds"),
        (["--policy", "SEED0/"], "needs a reference outside the seeds"),
    ],
)
def test_the_seeds_are_not_their_own_reference(tmp_path, capsys, extra, message) -> None:
    """A seed as the reference would add its zero difference to the seeds' IQM, whatever the
    spelling of its directory; a --policy naming a seed's directory is that seed."""
    dirs = [str(tmp_path / f"seed_{s}") for s in range(2)]
    argv = ["--agent-seeds", *dirs, *[a.replace("SEED0", dirs[0]) for a in extra]]
    with pytest.raises(SystemExit):
        main([*argv, "--scenario", "paper", "--runs", "2"])
    assert message in capsys.readouterr().err


def test_the_table_prints_its_bracketed_text(capsys) -> None:
    """Square brackets are rich markup: the title's '[stratified bootstrap 95% CI]' and a
    scenario or reference name in brackets are printed, not read as tags and dropped."""
    results = {
        "scenarios": {
            "[odd]": _result({"[ref]": 10.0, "a": 9.0, "b": 9.5}, ref="[ref]"),
            "hard": _result({"[ref]": 50.0, "a": 55.0, "b": 60.0}, ref="[ref]"),
        }
    }
    render_seeds(suite_across_seeds(results, ["a", "b"]))
    printed = " ".join(capsys.readouterr().out.split())
    assert "Over 2 training seeds: interquartile mean [stratified bootstrap 95% CI]" in printed
    assert "[odd]" in printed and "([ref])" in printed
    assert "relative Δ vs the reference, [ref]:" in printed


def test_one_scenarios_table_names_the_scenario(capsys) -> None:
    """The table of one scenario's seeds names it in its scenario column (it printed '—')."""
    armse = {"best-fixed": 20.0, "s0": 18.0, "s1": 19.0}
    render_seeds(across_seeds(_result(armse), ["s0", "s1"]), "vsmm-s2")
    printed = capsys.readouterr().out
    assert "vsmm-s2" in printed and "—" not in printed


def test_seeds_without_a_mode_accuracy_have_no_iqm_of_it(capsys) -> None:
    """A bank without the true model has no mode accuracy (None): its IQM is None and the
    table prints "—" (float(None) raised TypeError)."""
    armse = {"best-fixed": 20.0, "s0": 18.0, "s1": 19.0}
    out = across_seeds(_result(armse, accuracy=None), ["s0", "s1"])
    assert out["mode_accuracy"] == {"per_seed": [None, None], "iqm": None, "low": None,
                                    "high": None}
    assert out["armse_pos"]["iqm"] == pytest.approx(18.5)
    render_seeds(out, "paper")
    assert printed_row(capsys.readouterr().out, "paper")[2] == "—"


def test_a_seed_without_a_mode_accuracy_leaves_the_others_without_an_iqm_of_it() -> None:
    """One seed of three without a mode accuracy (None) and the others with one: the seeds have
    no common IQM of it, so it is None with its CI (strict JSON), never NaN; the per-seed values
    are kept as given and the position ARMSE's IQM is the plain mean of the three (n = 3: nothing
    cut, floor(3 / 4) = 0), worked by hand: (18 + 19 + 21) / 3."""
    armse = {"best-fixed": 20.0, "s0": 18.0, "s1": 19.0, "s2": 21.0}
    result = _result(armse)
    for seed, accuracy in (("s0", 0.5), ("s1", None), ("s2", 0.7)):
        result["policies"][seed]["mode_accuracy"] = accuracy
    out = across_seeds(result, ["s0", "s1", "s2"])
    assert out["mode_accuracy"] == {"per_seed": [0.5, None, 0.7], "iqm": None, "low": None,
                                    "high": None}
    assert out["armse_pos"]["iqm"] == pytest.approx(58.0 / 3.0, rel=1e-12)
    json.dumps(out, allow_nan=False)


def test_a_suite_table_with_an_iqm_names_the_cases_the_seeds_did_not_run_on(capsys) -> None:
    """With an IQM over the suite, the caption gives it and also names the cases left out (a
    bank the seeds cannot read): 'not run on five' after the pooled interval. The pooled IQM of
    the relative differences (-0.1, -0.05, 0.1, 0.2; n = 4, one cut at each end) is by hand
    (-0.05 + 0.1) / 2 = +2.50 %."""
    seeds = ["a", "b"]
    results = {
        "scenarios": {
            "easy": _result({"best-fixed": 10.0, "a": 9.0, "b": 9.5}),
            "five": _result({"best-fixed": 30.0}),
            "hard": _result({"best-fixed": 50.0, "a": 55.0, "b": 60.0}),
        }
    }
    out = suite_across_seeds(results, seeds)
    assert out["relative_vs_reference"]["iqm"] == pytest.approx(0.025, rel=1e-12)
    render_seeds(out)
    printed = " ".join(capsys.readouterr().out.split())
    assert "all scenarios, relative Δ vs the reference, best-fixed: +2.50% [" in printed
    assert "; not run on five" in printed


def test_a_suite_where_no_case_ran_every_seed_names_no_seed_as_its_reference() -> None:
    """With no case that ran every seed there is no aggregate: the reference it names is the
    one of the cases' paired differences ('best-fixed') or None, never one of the seeds."""
    results = {
        "scenarios": {
            "three": _result({"best-fixed": 10.0, "a": 9.0}),
            "four": _result({"best-fixed": 10.0, "b": 9.5}),
        }
    }
    out = suite_across_seeds(results, ["a", "b"])
    assert out["reference"] in (None, "best-fixed")
