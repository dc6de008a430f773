"""``imm_gym.cli.policies``: what a ``--policy`` name or path becomes, the cores a tuned rule
trains on, and the notes and refusals of a trained agent evaluated on a tracker."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agents import PRETRAINED
from imm_gym import EnvConfig
from imm_gym.cli.policies import make_policy

PAPER = EnvConfig(scenario="paper")


def _actions(policy: Any, seed: int) -> np.ndarray:
    obs = np.random.default_rng(seed).standard_normal((3, policy.obs_size)).astype(np.float32)
    action, _ = policy.predict(obs, None, np.ones(3, dtype=bool), True)
    return np.asarray(action)


@pytest.mark.parametrize(
    ("directory", "file"), [(PRETRAINED, "ensemble.json"), (PRETRAINED / "seed_0", "agent.json")]
)
def test_a_policy_file_is_its_directory_s_policy(directory: Path, file: str) -> None:
    """``--policy DIR/agent.json`` (or ``ensemble.json``) loads the policy of ``DIR``, as the
    loader reads a policy's file; the notes name the path as given."""
    by_dir, _, dir_notes = make_policy(str(directory), PAPER, 0)
    by_file, overrides, notes = make_policy(str(directory / file), PAPER, 0)
    assert dir_notes == {"path": str(directory)} and notes == {"path": str(directory / file)}
    assert overrides == by_dir.env_overrides
    np.testing.assert_array_equal(_actions(by_file, 3), _actions(by_dir, 3))


def test_a_shipped_name_is_its_directory_named_in_the_notes() -> None:
    _, _, notes = make_policy("pretrained", PAPER, 0)
    assert notes == {"path": str(PRETRAINED)}
