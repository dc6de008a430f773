"""``agents.report``: what a user reads of a training run — each seed's ``report.md`` table and
paired differences, how the agent was selected, and the run's statistics across seeds — checked
against numbers worked by hand, not through a training run."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from agents.report import (
    across_seeds,
    describe_selection,
    evaluated_scenarios,
    paired,
    write_report,
    write_summary_report,
)


def _row(pos: float, x: float, y: float, vx: float, vy: float) -> dict[str, float]:
    return {"armse_pos": pos, "armse_pos_x": x, "armse_pos_y": y, "armse_vel_x": vx,
            "armse_vel_y": vy}


def _difference(diff: float, low: float | None, high: float | None, relative: float) -> dict:
    return {"diff": diff, "low": low, "high": high, "relative": relative}


def _scenario(runs: int) -> dict:
    """One scenario of ``train.evaluate_agent``'s results, every number distinct."""
    one = runs == 1
    return {
        "meta": {"runs": runs, "seeds": "1000-1001"},
        "policies": {"learned": _row(11.0, 7.25, 8.5, 3.125, 4.75),
                     "best-fixed": _row(12.0, 9.0, 7.0, 5.5, 6.5)},
        "clairvoyant": {"role": "bound", **_row(9.5, 6.0, 7.125, 2.25, 1.5)},
        "paired": {"differences": {"learned": _difference(
            -1.0, None if one else -1.5, None if one else -0.25, -1.0 / 12.0)}},
        "vs_tip_imm": _difference(0.5, None if one else 0.125, None if one else 0.875, 0.05),
        "vs_turn_rate_prior": _difference(2.0, None if one else 1.0, None if one else 3.0, 0.25),
    }


def _cells(report: str, policy: str) -> list[str]:
    (line,) = [line for line in report.splitlines() if line.startswith(f"| {policy} |")]
    return [cell.strip() for cell in line.strip("|").split("|")][1:]


def test_a_seeds_report_puts_each_number_in_its_column(tmp_path: Path) -> None:
    """The policies' and the clairvoyant filter's position, X, Y, velocity X and Y ARMSE each
    under its heading, the heading giving the runs and their seeds."""
    path = tmp_path / "report.md"
    write_report(path, {"paper": _scenario(2)}, ["# Seed 0"])
    report = path.read_text()
    assert report.startswith("# Seed 0\n\n## paper scenario — 2 runs, seeds 1000-1001\n")
    assert _cells(report, "learned") == ["11.000", "7.250", "8.500", "3.125", "4.750"]
    assert _cells(report, "best-fixed") == ["12.000", "9.000", "7.000", "5.500", "6.500"]
    assert _cells(report, "clairvoyant (bound)") == ["9.500", "6.000", "7.125", "2.250", "1.500"]
    assert "## random" not in report


def test_a_seeds_report_gives_each_paired_difference_with_its_interval_and_percentage(
    tmp_path: Path,
) -> None:
    """Difference, CI low before high and the relative difference in per cent (relative 0.05
    is +5.00 %), for best-fixed, TIP-IMM and each detector rule the results hold."""
    path = tmp_path / "report.md"
    write_report(path, {"random": _scenario(2)}, [])
    lines = [line for line in path.read_text().splitlines() if line.startswith("- ")]
    assert lines == [
        "- learned − best-fixed: -1.000 m [-1.500, -0.250] (-8.33 %)",
        "- learned − tip-imm: +0.500 m [+0.125, +0.875] (+5.00 %)",
        "- learned − turn-rate-prior: +2.000 m [+1.000, +3.000] (+25.00 %)",
    ]


def test_one_run_gives_no_interval_in_a_seeds_report(tmp_path: Path) -> None:
    path = tmp_path / "report.md"
    write_report(path, {"paper": _scenario(1), "random": _scenario(1)}, [])
    report = path.read_text()
    lines = [line for line in report.splitlines() if line.startswith("- ")]
    assert len(lines) == 6 and "## random scenario — 1 runs" in report
    assert lines[1] == "- learned − tip-imm: +0.500 m undefined (1 run) (+5.00 %)"


@pytest.mark.parametrize(
    ("selected", "text"),
    [
        ({"swa_start": 2048, "snapshots": 6, "timesteps": 4096, "armse_pos": 10.25},
         "the mean of the weights after every update from step 2048 on (6 updates), validation "
         "ARMSE 10.250 m"),
        ({"timesteps": 3072, "armse_pos": 9.5},
         "the best validated checkpoint, at step 3072, validation ARMSE 9.500 m"),
        ({"timesteps": 4096, "armse_pos": None}, "the last iterate, at step 4096"),
    ],
)
def test_the_selection_is_described_by_how_the_policy_was_obtained(selected, text) -> None:
    assert describe_selection(selected) == text


def _seed(learned: float, vs_best: float, vs_tip: float) -> dict:
    scenario = {
        "policies": {"learned": {"armse_pos": learned}},
        "paired": {"differences": {"learned": {"relative": vs_best}}},
        "vs_tip_imm": {"relative": vs_tip},
    }
    return {"paper": scenario, "random": {**scenario, "policies": {
        "learned": {"armse_pos": 2 * learned}}}}


def test_across_seeds_gives_the_mean_and_sample_spread_of_the_learned_agent() -> None:
    """Seeds of ARMSE 10, 14 and 18 m: mean 14, sample standard deviation
    sqrt((16 + 0 + 16) / 2) = 4 m; the relative differences' means, each of its own."""
    out = across_seeds({"seed_0": _seed(10.0, -0.1, 0.02), "seed_1": _seed(14.0, -0.2, 0.04),
                        "seed_2": _seed(18.0, -0.3, 0.09)})
    paper = out["paper"]
    assert paper["armse_pos_mean"] == pytest.approx(14.0)
    assert paper["armse_pos_std"] == pytest.approx(4.0)
    assert paper["relative_vs_best_fixed_mean"] == pytest.approx(-0.2)
    assert paper["relative_vs_tip_imm_mean"] == pytest.approx(0.05)
    assert paper["per_seed_armse_pos"] == [10.0, 14.0, 18.0]
    assert out["random"]["armse_pos_std"] == pytest.approx(8.0)
    two = across_seeds({"seed_0": _seed(10.0, 0.0, 0.0), "seed_1": _seed(14.0, 0.0, 0.0)})
    assert two["paper"]["armse_pos_std"] == pytest.approx(np.sqrt(8.0))
    assert across_seeds({"seed_0": _seed(10.0, 0.0, 0.0)})["paper"]["armse_pos_std"] is None


def test_a_runs_report_gives_the_spread_and_the_percentages(tmp_path: Path) -> None:
    summary = {"command": "python train.py --seed 0 1", "across_seeds": {"paper": {
        "armse_pos_mean": 12.0, "armse_pos_std": 2.5, "per_seed_armse_pos": [10.25, 13.75],
        "relative_vs_best_fixed_mean": -0.0125, "relative_vs_tip_imm_mean": 0.031}}}
    path = tmp_path / "report.md"
    write_summary_report(path, summary)
    assert (
        "Learned position ARMSE over seeds: 12.000 m, ± 2.500 m (per seed: 10.250, 13.750); "
        "mean relative difference vs best fixed -1.25 %, vs TIP-IMM +3.10 %."
    ) in path.read_text()


def test_paired_is_the_first_policys_armse_minus_the_seconds() -> None:
    """ARMSE averages over time the root of the mean over runs: errors 3 and 4 m at the first
    step, 5 and 0 m at the second give sqrt((9 + 16) / 2) and sqrt((25 + 0) / 2), 5 / sqrt(2) m;
    against half those errors (5 / sqrt(2) / 2 m) learned minus the reference is +100 %."""
    err2 = np.array([[9.0, 25.0], [16.0, 0.0]])
    rollouts = {"learned": SimpleNamespace(squared_position_error=err2),
                "ref": SimpleNamespace(squared_position_error=err2 / 4.0)}
    d = paired(rollouts, "learned", "ref")
    assert d["diff"] == pytest.approx(5.0 / np.sqrt(2) / 2.0)
    assert d["relative"] == pytest.approx(1.0)
    assert d["low"] <= d["diff"] <= d["high"]


def test_the_paper_scenario_runs_the_files_configuration_without_its_drawn_conditions() -> None:
    overrides = {"scenario": "random", "vary": {"speed": [100.0, 300.0]},
                 "sensor": {"sigma_r": 50.0}}
    assert evaluated_scenarios(overrides) == {
        "paper": {"sensor": {"sigma_r": 50.0}},
        "random": {"vary": {"speed": [100.0, 300.0]}, "sensor": {"sigma_r": 50.0}},
    }
