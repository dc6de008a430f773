"""The cases :func:`imm_gym.cli.suite.suite_configs` reads, checked by hand: the scenario a file
that gives none runs, and a named suite's file that names another scenario than its case."""

from __future__ import annotations

from imm_gym.cli.suite import suite_configs


def test_a_directory_file_without_a_scenario_runs_the_paper_scenario(tmp_path) -> None:
    """A file of your own suite that gives no scenario runs ``paper``, as ``--env-config``
    does (not the randomized family); one that gives its scenario keeps it."""
    (tmp_path / "plain.yaml").write_text("sensor: {sigma_r: 10.0}\n")
    (tmp_path / "own.yaml").write_text("scenario: atc\n")
    configs = suite_configs(str(tmp_path))
    assert configs["plain"]["scenario"] == "paper"
    assert configs["plain"]["sensor"]["sigma_r"] == 10.0
    assert configs["own"]["scenario"] == "atc"
