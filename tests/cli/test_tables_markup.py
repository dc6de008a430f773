"""The printed tables show names, scenarios and notes as given, never as rich markup."""

from __future__ import annotations

import json

import pytest

import imm_gym.cli.evaluate as cli
from imm_gym.cli.comparison import evaluate
from imm_gym.cli.tables import render_suite_table, render_tables


@pytest.fixture(scope="module")
def results() -> dict:
    out, _ = evaluate(["fixed", "tip-imm"], "paper", 2, 0, clairvoyant=False)
    return out


def _renamed(results: dict, name: str) -> dict:
    """``results`` with policy ``fixed`` (the reference) renamed ``name``."""
    res = json.loads(json.dumps(results))
    p = res["policies"]
    res["policies"] = {name: p["fixed"], "tip-imm": p["tip-imm"]}
    res["paired"]["reference"] = name
    return res


@pytest.mark.parametrize("name", ["runs/ppo[lr=3e-4]/agent", "runs/a[/b]/agent", "a[bold]b"])
def test_policy_names_with_brackets_print_as_given(results, name, capsys) -> None:
    res = _renamed(results, name)
    res["meta"]["scenario"] = "cases/[lr=1]/paper.yaml"
    render_tables(res)
    printed = capsys.readouterr().out
    assert printed.count(name) >= 3  # the ARMSE and behaviour rows, the differences' title
    assert "cases/[lr=1]/paper.yaml" in printed


def test_suite_names_with_brackets_print_as_given(results, capsys) -> None:
    name = "runs/a[/b]/agent"
    case = _renamed(results, name)
    suite = {
        "meta": {**case["meta"], "suite": "s[/x]", "reference": name},
        "scenarios": {"case[lr=2]": case},
        "tally": {"tip-imm": {"below": ["case[lr=2]"], "level": [], "above": [], "skipped": []}},
    }
    render_suite_table(suite)
    printed = capsys.readouterr().out
    assert name in printed and "case[lr=2]" in printed and "s[/x]" in printed


def test_the_json_is_written_before_the_tables(tmp_path, monkeypatch) -> None:
    """A table that fails to print loses no result: ``--json`` is written first."""

    def fail(results: dict) -> None:
        raise RuntimeError("the terminal went away")

    monkeypatch.setattr(cli, "render_tables", fail)
    out = tmp_path / "out.json"
    argv = ["--policy", "fixed", "--runs", "2", "--no-clairvoyant", "--quiet", "--json", str(out)]
    with pytest.raises(RuntimeError, match="terminal"):
        cli.main(argv)
    assert set(json.loads(out.read_text())["policies"]) == {"fixed"}
