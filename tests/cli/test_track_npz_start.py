"""A single-sequence NPZ (``z (K+1, m)``, ``x0 (4,)``, ``P0 (4, 4)``) whose start is refused:
the message names the file and the array, not a 'sequence 0' the file does not have."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imm_gym import Sonar
from imm_gym.cli.recordings import read_npz
from imm_gym.validation import ConfigError

_Z = np.array([[1000.0, 0.1], [1010.0, 0.1], [1020.0, 0.1]])


def test_a_single_sequences_bad_start_is_refused_without_a_sequence_number(
    tmp_path: Path,
) -> None:
    np.savez(tmp_path / "one.npz", z=_Z, x0=np.zeros(4), P0=-np.eye(4))
    with pytest.raises(ConfigError, match=r"one\.npz: P0 must be positive definite") as refused:
        read_npz(tmp_path / "one.npz", Sonar())
    assert "sequence 0" not in str(refused.value)
    np.savez(tmp_path / "two.npz", z=np.stack([_Z, _Z]), x0=np.zeros((2, 4)),
             P0=np.stack([np.eye(4), -np.eye(4)]))
    with pytest.raises(ConfigError, match=r"two\.npz: sequence 1: P0 must be positive definite"):
        read_npz(tmp_path / "two.npz", Sonar())
