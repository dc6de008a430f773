"""Each printed cell holds its own figure: hand-made results with a distinct value per column
print those values, in their own columns, formatted as said."""

from __future__ import annotations

from helpers import printed_row

from imm_gym.cli.tables import (
    SYSTEM_COLUMNS,
    paper_setting,
    policy_label,
    render_suite_table,
    render_system_tables,
    render_tables,
)

#: How diverged runs are scored, as the evaluation's meta gives it.
DIVERGENCE = {"error_m": 5000.0, "scored": "held at the cap"}


def _row(**changes: object) -> dict:
    """A policy row whose every figure differs from the others."""
    row = {
        "armse_pos": 1.25, "armse_pos_x": 0.6, "armse_pos_y": 0.8, "armse_vel_x": 0.11,
        "armse_vel_y": 0.22, "nis": {"inside": 0.95}, "nees": {"inside": 0.40},
        "mode_accuracy": 0.8, "diverged": 2, "mode_prob_tv": 0.0125, "peak_error": 3.5,
        "maneuver_response": 1.75,
    }
    return {**row, **changes}


def _results() -> dict:
    """Two policies, the second 1.5 m below the reference (95 % CI -2 to -1 m)."""
    meta = {"scenario": "random", "runs": 4, "seeds": "0..3", "steps": 10, "filter": "ukf",
            "divergence": DIVERGENCE,
            "bootstrap": {"paired": {"resamples": 2000, "seed": 7, "level": 0.95}}}
    policies = {"fixed": _row(), "tip-imm": _row(armse_pos=-0.25)}
    differences = {"tip-imm": {"diff": -1.5, "low": -2.0, "high": -1.0, "relative": -0.125}}
    return {"meta": meta, "policies": policies,
            "paired": {"reference": "fixed", "differences": differences}}


def _cells(printed: str, header: str, first: str) -> dict[str, str]:
    """The cells of row ``first`` of the table whose header row has ``header``, by column."""
    lines = printed.splitlines()
    top = next(i for i, line in enumerate(lines) if line.startswith("┃") and header in line)
    headers = [h.strip() for h in lines[top].strip("┃").split("┃")]
    cells = printed_row("\n".join(lines[top + 1:]), first)
    assert len(cells) == len(headers)
    return dict(zip(headers, cells, strict=True))


def test_the_armse_table_counts_each_policys_diverged_runs(capsys) -> None:
    """A policy with 2 diverged runs prints 2 under "diverged", its other cells beside it."""
    render_tables(_results())
    cells = _cells(capsys.readouterr().out, "NEES ≤ χ²95", "fixed")
    assert cells["diverged"] == "2"
    assert cells["pos (m)"] == "1.2500" and cells["mode acc."] == "80.0%"


def test_the_behaviour_table_formats_each_score(capsys) -> None:
    render_tables(_results())
    cells = _cells(capsys.readouterr().out, "maneuver response (m)", "fixed")
    assert cells == {"policy": "fixed", "mode acc.": "80.0%", "mode-prob. TV / step": "0.0125",
                     "peak error (m)": "3.500", "maneuver response (m)": "1.750"}


def test_the_suite_table_delta_and_tally(capsys) -> None:
    """The suite's row gives the difference and its CI low to high; the tally line counts each
    kind of case under its own name, the cases not run, and names the bar's policies."""
    case = {**_results(), "meta": {"steps": 10, "divergence": DIVERGENCE}}
    tally = {"tip-imm": {"below": ["a", "b"], "level": [], "above": ["c"], "skipped": ["d"]}}
    suite = {"meta": {"suite": "s", "runs": 4, "seeds": "0..3", "reference": "fixed"},
             "scenarios": {"paper": case}, "tally": tally}
    render_suite_table(suite)
    printed = capsys.readouterr().out
    cells = printed_row(printed, "", "paper (10 steps)")
    assert cells[1] == "tip-imm" and cells[-1] == "-1.50 [-2.00, -1.00]"
    text = " ".join(printed.split())
    assert ("tip-imm against fixed (1 cases, paired 95% CIs): below on 2, level on 0, above on 1; "
            "not run on 1") in text
    suite["meta"]["bar"] = ["tip-imm", "best-fixed"]
    render_suite_table(suite)
    text = " ".join(capsys.readouterr().out.split())
    assert "tip-imm against the better of tip-imm and best-fixed (1 cases" in text


def test_a_policy_on_another_tracker_names_every_field(capsys) -> None:
    results = _results()
    results["policies"]["tip-imm"]["tracker_differs"] = ["sensor", "filter"]
    render_tables(results)
    text = " ".join(capsys.readouterr().out.split())
    assert "tip-imm was trained on another tracker than the evaluated one (sensor, filter differ" \
        in text


def test_the_papers_rows_not_beside_a_configuration_file() -> None:
    """Table 2's rows are beside the paper's setting only: not when a configuration file set the
    tracker, though the scenario, bank and filter are the paper's."""
    meta = {"scenario": "paper", "env_config": None, "bank": "paper", "filter": "ukf"}
    assert paper_setting(meta)
    assert not paper_setting({**meta, "env_config": {"sensor": {"sigma_r": 20.0}}})


def test_the_system_table_shares_and_the_papers_row(capsys) -> None:
    """NIS inside its bound 95 % of the time prints as 95.0 %; the seed-002 paper row gives the
    paper's figures it has and "—" for the others."""
    row = {key: 0.5 for key, _, _ in SYSTEM_COLUMNS}
    row["nis_inside"], row["nees_inside"] = 0.95, 0.4
    meta = {"scenario": "seed002", "runs": 1, "seeds": "0..0", "steps": 10}
    render_system_tables({"meta": meta, "policies": {"fixed": row},
                          "paper": {"pos_rmse": 1.23456}})
    printed = capsys.readouterr().out
    cells = _cells(printed, "pos RMSE (m)", "fixed")
    assert cells["NIS ≤ χ²95"] == "95.0%" and cells["NEES ≤ χ²95"] == "40.0%"
    paper = _cells(printed, "pos RMSE (m)", "seed 002 paper (their trajectory)")
    assert paper["pos RMSE (m)"] == "1.2346"
    assert [v for k, v in paper.items() if k not in ("policy", "pos RMSE (m)")] == ["—"] * 10


def test_a_found_stay_keeps_three_significant_digits() -> None:
    """A stay of 0.995 prints as 0.995, not rounded to another stay (0.99)."""
    assert policy_label("best-fixed", {"stay": 0.995}) == "best-fixed (stay 0.995)"
    assert policy_label("best-fixed-rows", {"stays": [0.995, 0.5]}) == (
        "best-fixed-rows (stays 0.995/0.5)"
    )
