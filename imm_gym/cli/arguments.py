"""Checks of the arguments that ``python -m imm_gym.evaluate`` and ``python -m imm_gym.track``
share, made before any work: the seeds (:func:`seed_problem`) and the outputs
(:func:`output_problem`).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from imm_gym.cli.policies import TRAIN_RUNS
from imm_gym.seeding import TRAIN_SEED_BASE, TRAIN_SEED_OFFSET, VALIDATION_SEED_BASE

#: The most runs: the evaluation seeds ``seed .. seed + runs - 1`` stay below the tuners' training
#: seeds ``seed + TRAIN_SEED_OFFSET + r``.
MAX_RUNS = TRAIN_SEED_OFFSET
#: The largest ``--seed``: the tuners' last training seed ``seed + TRAIN_SEED_OFFSET + TRAIN_RUNS
#: - 1`` (and so every evaluation seed) stays below the agents' validation seeds.
MAX_SEED = VALIDATION_SEED_BASE - TRAIN_SEED_OFFSET - TRAIN_RUNS


def output_problem(path: Path, kind: str) -> str | None:
    """Why ``path`` cannot receive the output ``kind`` (``"file"`` or ``"directory"``), or None.

    Checked before any evaluation runs, so an unwritable output costs nothing: ``path`` must not
    be an existing entry of the other kind, and a file must be created (a temporary one, removed
    at once) in it (a directory), next to it (a file) or in the nearest existing ancestor (where
    the missing directories will go).
    """
    if path.exists():
        if kind == "file" and path.is_dir():
            return "is a directory; give a file name"
        if kind == "directory" and not path.is_dir():
            return "exists and is not a directory"
    target = path if path.is_dir() else path.absolute().parent
    while not target.exists():
        target = target.parent
    if not target.is_dir():
        return f"{target} is not a directory"
    try:
        with tempfile.TemporaryFile(dir=target):
            pass
    except OSError as err:
        return f"cannot write in {target} ({err.strerror or err})"
    if path.is_file() and not os.access(path, os.W_OK):
        return "is not writable"
    return None


def seed_problem(seed: int, runs: int) -> str | None:
    """Why ``--seed seed --runs runs`` cannot be evaluated, or None: the runs' seeds
    ``seed .. seed + runs - 1`` and the tuners' training seeds ``seed + TRAIN_SEED_OFFSET + r``
    must not meet each other nor reach the agents' validation seeds or training slots."""
    if runs < 1:
        return f"--runs must be >= 1, got {runs}"
    if seed < 0:
        return f"--seed must be >= 0, got {seed}"
    if runs > MAX_RUNS:
        return (
            f"--runs must be in [1, {MAX_RUNS}], got {runs}: the run seeds --seed .. --seed + "
            f"--runs - 1 stay below the tuners' training seeds --seed + {TRAIN_SEED_OFFSET}+"
        )
    if seed > MAX_SEED:
        return (
            f"--seed must be in [0, {MAX_SEED}], got {seed}: the run seeds and the tuners' "
            f"training seeds (--seed + {TRAIN_SEED_OFFSET} + r, r < {TRAIN_RUNS}) stay below the "
            f"agents' validation seeds ({VALIDATION_SEED_BASE}+) and training slots "
            f"({TRAIN_SEED_BASE}+)"
        )
    return None

