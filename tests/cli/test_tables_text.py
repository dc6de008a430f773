"""The tables' titles say what is computed."""

from __future__ import annotations

import numpy as np

from imm_gym.cli.comparison import evaluate
from imm_gym.cli.tables import divergence_note, render_suite_table, render_tables
from imm_gym.evaluation.metrics import maneuver_starts


def test_the_maneuver_response_title_counts_turn_ends_too(capsys) -> None:
    """The maneuver response's windows start at every change of the true model, a turn's end as
    its start (:func:`maneuver_starts`): the title says so, not "after each maneuver starts"."""
    true_model = np.array([[0, 0, 1, 1, 0, 0]])
    assert np.flatnonzero(maneuver_starts(true_model)[0]).tolist() == [2, 4]  # start and end
    results, _ = evaluate(["fixed"], "paper", 2, 0, clairvoyant=False)
    render_tables(results)
    printed = " ".join(capsys.readouterr().out.split())
    assert "from each change of the true model (a maneuver's start or end)" in printed
    assert "after each maneuver starts" not in printed


#: How diverged runs are scored, as the evaluation's meta gives it.
DIVERGENCE = {"error_m": 5000.0, "scored": "held at the cap"}


def _row(diverged: int = 0) -> dict:
    """A hand-made policy row: NIS inside the bound 95 % of the time, NEES 40 %."""
    return {
        "armse_pos": 1.0, "armse_pos_x": 0.7, "armse_pos_y": 0.7, "armse_vel_x": 0.1,
        "armse_vel_y": 0.2, "nis": {"inside": 0.95}, "nees": {"inside": 0.40},
        "mode_accuracy": 0.8, "diverged": diverged, "mode_prob_tv": 0.1, "peak_error": 2.0,
        "maneuver_response": 1.5,
    }


def _results(*diverged: int) -> dict:
    meta = {"scenario": "random", "runs": 2, "seeds": "0..1", "steps": 10, "filter": "ukf",
            "divergence": DIVERGENCE}
    policies = {f"policy{i}": _row(d) for i, d in enumerate(diverged)}
    return {"meta": meta, "policies": policies, "paired": {"differences": {}, "reference": "x"}}


def test_the_divergence_note_only_when_a_run_diverged(capsys) -> None:
    """The line on how diverged runs are scored is printed when a policy has a diverged run, not
    when none has (nor without the meta's ``divergence``)."""
    line = "Diverged runs (error above 5000 m): held at the cap."
    meta = {"divergence": DIVERGENCE}
    assert divergence_note(meta, [{"diverged": 0}, {"diverged": 0}]) is None
    assert divergence_note(meta, []) is None
    assert divergence_note(meta, [{"diverged": 0}, {"diverged": 1}]) == line
    assert divergence_note({}, [{"diverged": 1}]) is None
    render_tables(_results(0, 0))
    assert "Diverged runs" not in capsys.readouterr().out
    render_tables(_results(0, 2))
    assert line in " ".join(capsys.readouterr().out.split())


def _cells_under_headers(printed: str, header: str, first_cell: str) -> dict[str, str]:
    """The cells of the row starting ``first_cell`` of the first table whose header row has
    ``header``, keyed by their column's header (one header line, rich's box characters)."""
    lines = printed.splitlines()
    top = next(i for i, line in enumerate(lines) if line.startswith("┃") and header in line)
    headers = [h.strip() for h in lines[top].strip("┃").split("┃")]
    for line in lines[top + 1:]:
        cells = [c.strip() for c in line.strip("│").split("│")]
        if line.startswith("│") and cells[0] == first_cell:
            assert len(cells) == len(headers)
            return dict(zip(headers, cells, strict=True))
    raise AssertionError(f"no row {first_cell!r} under {header!r}")


def test_nis_and_nees_each_under_their_own_header(capsys) -> None:
    """A policy whose NIS is inside its bound 95 % of the time and NEES 40 %: Table 2's layout
    and the suite table print 95.0 % under "NIS ≤ χ²95" and 40.0 % under "NEES ≤ χ²95" (the
    suite table only the NEES)."""
    render_tables(_results(0))
    cells = _cells_under_headers(capsys.readouterr().out, "NEES ≤ χ²95", "policy0")
    assert cells["NIS ≤ χ²95"] == "95.0%" and cells["NEES ≤ χ²95"] == "40.0%"
    assert cells["mode acc."] == "80.0%" and cells["pos (m)"] == "1.0000"
    case = {
        "meta": {"steps": 10, "divergence": DIVERGENCE},
        "policies": {"fixed": _row(), "window": _row()},
        "paired": {"differences": {"window": {"diff": 0.0, "low": -0.1, "high": 0.1}}},
    }
    suite = {"meta": {"suite": "s", "runs": 2, "seeds": "0..1", "reference": "fixed"},
             "scenarios": {"paper": case}}
    render_suite_table(suite)
    cells = _cells_under_headers(capsys.readouterr().out, "NEES ≤ χ²95", "paper (10 steps)")
    assert cells["policy"] == "fixed"
    assert cells["NEES ≤ χ²95"] == "40.0%" and cells["mode acc."] == "80.0%"
    assert "95.0%" not in cells.values()
