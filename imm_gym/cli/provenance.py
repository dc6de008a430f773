"""What a run's results depend on: the package's version and commit, Python's and the libraries'.

Every command that writes results (``train.py``, ``python -m imm_gym.evaluate``) records
:func:`versions` beside them, so that anyone can redo the run with the same code, and writes them
as strict JSON (:func:`record_json`), which any JSON reader takes.
"""

from __future__ import annotations

import json
import math
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

#: Distributions recorded wherever a run is made (read from their metadata: nothing is imported).
CORE_PACKAGES = ("numpy", "scipy", "gymnasium")
#: The packages beside imm_gym whose modules its command lines run: an untracked module in one
#: (``baselines/__init__.py`` imports every module of its folder) is code the commit does not hold.
PLUGIN_PACKAGES = ("baselines", "agents")


def versions(*optional: str) -> dict[str, str | bool]:
    """``{"imm_gym": ..., "git_commit": ..., "git_dirty": ..., "python": ..., "numpy": ..., ...}``.

    ``git_commit`` is the commit checked out where a git work tree tracks the package, and
    ``git_dirty`` whether tracked files of that tree differ from it or an untracked module lies
    in the package or beside it (:func:`git_state`: the commit alone does not give the code run
    then); both absent otherwise. Each distribution of ``optional`` (by its
    distribution name, e.g. ``"stable-baselines3"``) is recorded where it is installed and left
    out where it is not.
    """
    import imm_gym

    record: dict[str, str | bool] = {"imm_gym": imm_gym.__version__}
    state = git_state(Path(imm_gym.__file__).resolve().parent)
    if state is not None:
        record["git_commit"], record["git_dirty"] = state
    record["python"] = platform.python_version()
    for name in (*CORE_PACKAGES, *optional):
        try:
            record[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return record


def git_state(directory: Path) -> tuple[str, bool] | None:
    """``(commit, dirty)`` of the git work tree that tracks the package ``directory`` (its
    ``__init__.py``): ``git rev-parse HEAD``, and whether ``git status --porcelain
    --untracked-files=no`` lists a tracked file that differs from it (anywhere in the tree) or
    an untracked, non-ignored ``.py`` file lies in the package or in a plug-in package beside it
    (:data:`PLUGIN_PACKAGES`; other untracked files do not count). None where no work tree
    tracks the package — outside one, or inside one that does not track it (a virtual
    environment within another project's checkout) — and where git is missing or fails (the
    versions are a record, never a reason to stop)."""
    if not any((d / ".git").exists() for d in (directory, *directory.parents)):
        return None
    try:
        _git(directory, "ls-files", "--error-unmatch", "__init__.py")
        commit = _git(directory, "rev-parse", "HEAD")
        changed = _git(directory, "status", "--porcelain", "--untracked-files=no")
        untracked = _untracked_modules(directory)
    except (OSError, subprocess.SubprocessError):
        return None
    return (commit, bool(changed or untracked)) if commit else None


def _untracked_modules(directory: Path) -> str:
    """The untracked, non-ignored ``.py`` files (``git ls-files --others --exclude-standard``),
    one a line, of the package ``directory`` and, where the work tree holds its parent, of the
    :data:`PLUGIN_PACKAGES` folders beside it."""
    if (directory / ".git").exists():  # the package is the work tree's root
        return _git(directory, "ls-files", "--others", "--exclude-standard", "--", "*.py")
    folders = (directory.name, *PLUGIN_PACKAGES)
    return _git(
        directory.parent,
        "ls-files", "--others", "--exclude-standard", "--", *(f"{f}/*.py" for f in folders),
    )


def _git(directory: Path, *args: str) -> str:
    """The output of ``git ARGS`` run in ``directory``, stripped (taking no optional lock: the
    work tree may be in use).

    Raises:
        OSError, subprocess.SubprocessError: git is missing, fails or takes over 10 s.
    """
    done = subprocess.run(
        ["git", "--no-optional-locks", *args],
        cwd=directory,
        capture_output=True,
        text=True,
        timeout=10,
        check=True,
    )
    return done.stdout.strip()


def record_json(results: Any) -> str:
    """``results`` as indented JSON (RFC 8259), a number that is not finite written ``null``:
    Python's ``json`` would write ``NaN`` and ``Infinity`` (a failed run's errors), which strict
    readers (``jq``, a browser's ``JSON.parse``) refuse."""

    def finite(value: Any) -> Any:
        if isinstance(value, float):
            return value if math.isfinite(value) else None
        if isinstance(value, dict):
            return {k: finite(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [finite(v) for v in value]
        return value

    return json.dumps(finite(results), indent=2, allow_nan=False)
