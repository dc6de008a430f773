"""The versions a run records: one recorder for training and evaluation."""

from __future__ import annotations

import json
import math
import platform
import re
import subprocess
from importlib import metadata
from pathlib import Path

import numpy as np

import imm_gym
from imm_gym.cli.provenance import git_state, record_json, versions


def test_the_record_names_the_package_python_and_the_core_libraries() -> None:
    record = versions()
    assert record["imm_gym"] == imm_gym.__version__
    assert record["python"] == platform.python_version()
    assert record["numpy"] == np.__version__
    assert record["scipy"] == metadata.version("scipy")
    assert record["gymnasium"] == metadata.version("gymnasium")


def test_an_optional_library_is_recorded_where_installed_and_left_out_where_not() -> None:
    record = versions("stable-baselines3", "no-such-distribution-imm-gym")
    assert record["stable-baselines3"] == metadata.version("stable-baselines3")
    assert "no-such-distribution-imm-gym" not in record


def test_the_commit_is_recorded_in_a_work_tree_only(tmp_path: Path) -> None:
    assert git_state(tmp_path) is None
    package = Path(imm_gym.__file__).resolve().parent
    if any((d / ".git").exists() for d in (package, *package.parents)):
        record = versions()
        assert re.fullmatch(r"[0-9a-f]{40}", record["git_commit"])
        assert record["git_commit"] == _git(package, "rev-parse", "HEAD")
        assert isinstance(record["git_dirty"], bool)


def _git(directory: Path, *args: str) -> str:
    """``git ARGS`` in ``directory`` (an identity of its own for commits), its output stripped."""
    config = ["-c", "user.name=t", "-c", "user.email=t@example.org", "-c", "commit.gpgsign=false"]
    done = subprocess.run(
        ["git", *config, *args], cwd=directory, capture_output=True, text=True, check=True
    )
    return done.stdout.strip()


def _repo(root: Path, *tracked: str) -> Path:
    """A git repository at ``root`` with the files ``tracked`` committed (each holding a line)."""
    root.mkdir(parents=True, exist_ok=True)
    _git(root, "init", "-q")
    for name in tracked:
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text("x = 1\n")
    _git(root, "add", *tracked)
    _git(root, "commit", "-q", "-m", "one")
    return root


def test_a_repository_that_does_not_track_the_package_gives_no_commit(tmp_path, monkeypatch):
    """A package inside another project's work tree (a virtual environment in its checkout,
    ignored there) records no commit: that project's HEAD says nothing of the package."""
    outer = _repo(tmp_path / "outer", "unrelated.txt", ".gitignore")
    (outer / ".gitignore").write_text("venv/\n")
    package = outer / "venv" / "site" / "pkg"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("__version__ = '0'\n")
    assert git_state(package) is None
    monkeypatch.setattr(imm_gym, "__file__", str(package / "__init__.py"))
    assert "git_commit" not in versions()
    _git(outer, "add", "-f", "venv/site/pkg/__init__.py")
    _git(outer, "commit", "-q", "-m", "the package tracked")
    commit = _git(outer, "rev-parse", "HEAD")
    assert versions()["git_commit"] == commit and git_state(package) == (commit, True)  # .gitignore


def test_a_work_tree_whose_tracked_files_differ_from_the_commit_is_recorded_dirty(
    tmp_path, monkeypatch
) -> None:
    """``git_dirty`` beside ``git_commit``: a tracked file modified (anywhere in the tree) makes
    the commit alone not the code run; an untracked file does not."""
    root = _repo(tmp_path / "project", "pkg/__init__.py", "train.py")
    package = root / "pkg"
    head = _git(root, "rev-parse", "HEAD")
    monkeypatch.setattr(imm_gym, "__file__", str(package / "__init__.py"))
    assert git_state(package) == (head, False)
    (root / "notes.txt").write_text("untracked\n")
    record = versions()
    assert (record["git_commit"], record["git_dirty"]) == (head, False)
    (root / "train.py").write_text("x = 2\n")
    assert git_state(package) == (head, True)
    record = versions()
    assert (record["git_commit"], record["git_dirty"]) == (head, True)
    _git(root, "commit", "-q", "-am", "two")
    assert git_state(package) == (_git(root, "rev-parse", "HEAD"), False) != (head, False)


def test_an_untracked_module_in_the_packages_is_recorded_dirty(tmp_path, monkeypatch) -> None:
    """``baselines/__init__.py`` imports every module of its folder: an untracked, non-ignored
    ``.py`` file in the package or in baselines/ or agents/ beside it is code the commit does not
    hold (it was recorded clean); one elsewhere, or ignored, is not."""
    root = _repo(tmp_path / "project", "pkg/__init__.py", "baselines/__init__.py", ".gitignore")
    (root / ".gitignore").write_text("baselines/ignored_*.py\n")
    _git(root, "commit", "-q", "-am", "ignore")
    package = root / "pkg"
    head = _git(root, "rev-parse", "HEAD")
    monkeypatch.setattr(imm_gym, "__file__", str(package / "__init__.py"))
    (root / "scripts").mkdir()
    (root / "scripts" / "mine.py").write_text("x = 1\n")
    (root / "baselines" / "ignored_rule.py").write_text("x = 1\n")
    (root / "agents").mkdir()
    (root / "agents" / "notes.txt").write_text("not a module\n")
    assert git_state(package) == (head, False)
    for module in ("baselines/zz_mine.py", "agents/sub/policy.py", "pkg/extra.py"):
        (root / module).parent.mkdir(parents=True, exist_ok=True)
        (root / module).write_text("x = 1\n")
        assert git_state(package) == (head, True), module
        assert versions()["git_dirty"] is True
        (root / module).unlink()
    assert git_state(package) == (head, False)


def test_a_package_at_the_root_of_its_work_tree_records_its_commit_and_modules(
    tmp_path, monkeypatch
) -> None:
    """The package directory is the work tree itself (its own ``.git``): its commit is recorded,
    an untracked ``.py`` file in it makes the record dirty, an untracked text file does not."""
    package = _repo(tmp_path / "pkg", "__init__.py")
    head = _git(package, "rev-parse", "HEAD")
    monkeypatch.setattr(imm_gym, "__file__", str(package / "__init__.py"))
    (package / "notes.txt").write_text("untracked\n")
    assert git_state(package) == (head, False)
    (package / "extra.py").write_text("x = 1\n")
    assert git_state(package) == (head, True)
    record = versions()
    assert (record["git_commit"], record["git_dirty"]) == (head, True)


def test_without_git_the_record_has_no_commit_and_the_run_goes_on(tmp_path, monkeypatch) -> None:
    """git not installed (not on ``PATH``) in a work tree: no ``git_commit`` and no error (the
    versions are a record, never a reason to stop)."""
    root = _repo(tmp_path / "project", "pkg/__init__.py")
    monkeypatch.setattr(imm_gym, "__file__", str(root / "pkg" / "__init__.py"))
    empty = tmp_path / "no-git"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    assert git_state(root / "pkg") is None
    record = versions()
    assert "git_commit" not in record and "git_dirty" not in record
    assert record["numpy"] == np.__version__


def test_record_json_writes_a_number_that_is_not_finite_in_a_tuple_as_null() -> None:
    """A tuple (an interval, a shape) holding NaN or an infinity, at any depth: null, as in a
    list (json.dumps refused it, allow_nan=False, and no results were written)."""
    results = {"ci": (math.nan, 1.5), "deep": [{"range": (-math.inf, (math.inf, 2))}]}
    assert json.loads(record_json(results)) == {
        "ci": [None, 1.5],
        "deep": [{"range": [None, [None, 2]]}],
    }


def test_record_json_is_indented_two_spaces_a_value_a_line() -> None:
    """The results file reads line by line (RFC 8259 JSON, indented by two spaces), written out
    here by hand."""
    assert record_json({"a": 1, "b": [2.5, math.nan]}) == (
        '{\n  "a": 1,\n  "b": [\n    2.5,\n    null\n  ]\n}'
    )
