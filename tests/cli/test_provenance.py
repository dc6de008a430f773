"""The versions a run records: one recorder for training and evaluation."""

from __future__ import annotations

import platform
import re
from importlib import metadata
from pathlib import Path

import numpy as np

import imm_gym
from imm_gym.cli.provenance import git_commit, versions


def test_the_record_names_the_package_python_and_the_core_libraries() -> None:
    record = versions()
    assert record["imm_gym"] == imm_gym.__version__
    assert record["python"] == platform.python_version()
    assert record["numpy"] == np.__version__
    assert record["gymnasium"] == metadata.version("gymnasium")


def test_an_optional_library_is_recorded_where_installed_and_left_out_where_not() -> None:
    record = versions("stable-baselines3", "no-such-distribution-imm-gym")
    assert record["stable-baselines3"] == metadata.version("stable-baselines3")
    assert "no-such-distribution-imm-gym" not in record


def test_the_commit_is_recorded_in_a_work_tree_only(tmp_path: Path) -> None:
    assert git_commit(tmp_path) is None
    package = Path(imm_gym.__file__).resolve().parent
    if any((d / ".git").exists() for d in (package, *package.parents)):
        assert re.fullmatch(r"[0-9a-f]{40}", versions()["git_commit"])
