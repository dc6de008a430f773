"""The cases :func:`imm_gym.cli.suite.suite_configs` reads, checked by hand: the scenario a file
that gives none runs, and a named suite's file that names another scenario than its case."""

from __future__ import annotations

import shutil

import pytest

import imm_gym.cli.suite as suite
from imm_gym.cli.suite import suite_configs
from imm_gym.scenarios.catalog import SUITE_CONFIGS
from imm_gym.validation import ConfigError


def test_a_directory_file_without_a_scenario_runs_the_paper_scenario(tmp_path) -> None:
    """A file of your own suite that gives no scenario runs ``paper``, as ``--env-config``
    does (not the randomized family); one that gives its scenario keeps it."""
    (tmp_path / "plain.yaml").write_text("sensor: {sigma_r: 10.0}\n")
    (tmp_path / "own.yaml").write_text("scenario: atc\n")
    configs = suite_configs(str(tmp_path))
    assert configs["plain"]["scenario"] == "paper"
    assert configs["plain"]["sensor"]["sigma_r"] == 10.0
    assert configs["own"]["scenario"] == "atc"


def test_a_named_suites_file_gives_its_own_scenario_or_none(tmp_path, monkeypatch) -> None:
    """The benchmark's files (copied here): ``random.yaml`` giving no scenario (only the default
    filter) runs the randomized family, its case's; ``paper.yaml`` naming ``atc`` is refused,
    not run as the ``paper`` case."""
    folder = tmp_path / "suite"
    shutil.copytree(SUITE_CONFIGS, folder)
    monkeypatch.setattr(suite, "SUITE_CONFIGS", folder)
    random = folder / "random.yaml"
    random.write_text("filter: ukf\n")
    assert suite_configs("benchmark")["random"]["scenario"] == "random"
    paper = folder / "paper.yaml"
    paper.write_text(paper.read_text().replace("scenario: paper\n", "scenario: atc\n"))
    with pytest.raises(ConfigError, match=r"paper\.yaml: scenario must be 'paper'"):
        suite_configs("benchmark")


def test_a_suites_meta_names_the_seeds_its_runs_used(tmp_path) -> None:
    """Two runs from ``seed 7`` are seeds 7 and 8: ``meta.seeds`` says ``7..8``, the suite's
    and each case's, beside the reference (``fixed``) and no bar; ``clairvoyant=False`` leaves
    each case's clairvoyant row out."""
    (tmp_path / "one.yaml").write_text("scenario: paper\n")
    out = suite.evaluate_suite(["fixed", "window"], str(tmp_path), 2, 7, clairvoyant=False)
    meta = out["meta"]
    assert (meta["runs"], meta["seed"], meta["seeds"]) == (2, 7, "7..8")
    assert (meta["reference"], meta["bar"]) == ("fixed", [])
    assert out["scenarios"]["one"]["meta"]["seeds"] == "7..8"
    assert "clairvoyant" not in out["scenarios"]["one"]
