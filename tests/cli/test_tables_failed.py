"""A seed-scenario run whose filter failed is counted in the table, not only in the JSON, and
written there as strict JSON."""

from __future__ import annotations

import json
import math

from helpers import printed_row

from imm_gym.cli import evaluate
from imm_gym.cli.provenance import record_json
from imm_gym.cli.tables import SYSTEM_COLUMNS, render_system_tables

META = {"scenario": "seed003", "runs": 2, "seeds": "0..1", "steps": 10}


def _row(failed: int, value: float) -> dict[str, object]:
    return {**{key: value for key, _, _ in SYSTEM_COLUMNS}, "failed": failed}


def test_failed_runs_get_a_column_and_a_note(capsys) -> None:
    """Two failed runs gave only 'nan' cells (and a NIS share counting NaN as outside): the
    table gives each policy's failed runs out of the runs and says what they do to the rest."""
    policies = {"fixed": _row(0, 0.5), "bbsca": _row(2, math.nan)}
    render_system_tables({"meta": META, "policies": policies})
    printed = capsys.readouterr().out
    assert printed_row(printed, "fixed")[-1] == "0/2"
    assert printed_row(printed, "bbsca")[-1] == "2/2"
    text = " ".join(printed.split())
    assert "failed: runs whose filter failed" in text
    assert "NIS/NEES ≤ χ²95 count their NaN steps as outside the bound" in text


def test_no_failed_run_no_column(capsys) -> None:
    render_system_tables({"meta": META, "policies": {"fixed": _row(0, 0.5)}})
    printed = capsys.readouterr().out
    assert "failed" not in printed and len(printed_row(printed, "fixed")) == 1 + len(SYSTEM_COLUMNS)


def test_failed_runs_are_written_as_strict_json(tmp_path, capsys) -> None:
    """Their NaN errors were written ``NaN`` (Python's json), which strict JSON readers refuse:
    a number that is not finite is ``null`` in the evaluation's JSON."""
    tuned = tmp_path / "tuned.json"  # noise scales so small that every run's filter fails
    tuned.write_text(json.dumps({"bank": "seed003", "q_scale": [1e-300] * 3, "r_scale": 1e-300}))
    out = tmp_path / "out.json"
    argv = ["--scenario", "seed003", "--policy", "bbsca", "--tuned", f"bbsca={tuned}",
            "--runs", "2", "--json", str(out)]
    assert evaluate.main(argv) == 0
    capsys.readouterr()

    def refuse(constant: str) -> None:
        raise ValueError(f"{constant} is not JSON")

    row = json.loads(out.read_text(), parse_constant=refuse)["policies"]["bbsca"]
    assert row["failed"] == 2 and row["pos_rmse"] is None and row["innovation_mse"] is None


def test_record_json_writes_a_number_that_is_not_finite_as_null() -> None:
    results = {"a": math.nan, "b": [1.5, math.inf, -math.inf], "c": {"d": (2, "x", None)}}
    assert json.loads(record_json(results)) == {"a": None, "b": [1.5, None, None],
                                                "c": {"d": [2, "x", None]}}
