"""A score with nothing to count (None in the JSON) prints as "—", never as 0."""

from __future__ import annotations

import json

from helpers import printed_row

from imm_gym.cli.comparison import evaluate
from imm_gym.cli.tables import render_suite_table, render_system_tables, render_tables


def test_scores_without_values_print_as_a_dash(capsys) -> None:
    results, _ = evaluate(["fixed", "tip-imm"], "paper", 2, 0, clairvoyant=False)
    results = json.loads(json.dumps(results))
    row = results["policies"]["fixed"]
    for test in ("nis", "nees"):
        row[test]["inside"] = row[test]["mean"] = None
    row["mode_accuracy"] = row["mode_prob_tv"] = None
    render_tables(results)
    cells = printed_row(capsys.readouterr().out, "fixed")
    assert cells[6:9] == ["—", "—", "—"]
    suite = {
        "meta": {**results["meta"], "suite": "s", "reference": "fixed"},
        "scenarios": {"paper": results},
    }
    render_suite_table(suite)
    assert printed_row(capsys.readouterr().out, "paper (150 steps)")[3:5] == ["—", "—"]


def test_the_system_table_prints_a_missing_consistency_as_a_dash(capsys) -> None:
    row = {"pos_rmse": 1.0, "pos_mae": 1.0, "pos_max": 2.0, "fde": 1.0, "vel_rmse": 1.0,
           "yaw_rmse_deg": 1.0, "nis_inside": None, "nis_mean": None, "nees_inside": None,
           "nees_mean": None, "innovation_mse": 1.0}
    meta = {"scenario": "seed002", "runs": 1, "seeds": "0..0", "steps": 10}
    render_system_tables({"meta": meta, "policies": {"fixed": row}})
    assert printed_row(capsys.readouterr().out, "fixed")[7:11] == ["—"] * 4
