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
