"""The registered ids' presets (``imm_gym.sim.presets.ENV_PRESETS``) by the targets a user's
episodes fly: the randomized family (SPEC §6) where an id says so, the paper's Table-1 scenario
(SPEC §3) for the paper id."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import imm_gym  # noqa: F401  (registers the envs)
from imm_gym.tracking.hetero import HeteroBank

FAMILY_IDS = ("imm_gym/TPMAdapt-v0", "imm_gym/TPMAdaptParallel-v0", "imm_gym/TPMAdaptHetero-v0")


def _starts(env_id: str, seeds: range) -> np.ndarray:
    """The true state ``[x, y, vx, vy]`` at t = 0 of the episode of each seed."""
    env = gym.make(env_id)
    starts = []
    for seed in seeds:
        env.reset(seed=seed)
        starts.append(env.unwrapped.core.truth[0, 0].copy())
    env.close()
    return np.array(starts)


@pytest.mark.parametrize("env_id", FAMILY_IDS)
def test_a_family_id_draws_a_new_target_of_the_family_each_seed(env_id: str) -> None:
    """Every seed starts its target somewhere else, 3-8 km from the sensor at 5-25 m/s."""
    starts = _starts(env_id, range(8))
    ranges = np.linalg.norm(starts[:, :2], axis=-1)
    speeds = np.linalg.norm(starts[:, 2:], axis=-1)
    assert np.all((ranges >= 3000.0) & (ranges <= 8000.0))
    assert np.all((speeds >= 5.0) & (speeds <= 25.0))
    assert len({tuple(s) for s in starts.tolist()}) == 8


def test_the_hetero_id_flies_the_family_with_the_ncv_ct_ctra_ekf() -> None:
    config = gym.make("imm_gym/TPMAdaptHetero-v0").unwrapped.config
    assert isinstance(config.bank, HeteroBank) and config.bank.models == ("ncv", "ct", "ctra")
    assert config.filter == "ekf" and config.scenario == "random"


def test_the_paper_id_flies_table_1_at_every_seed() -> None:
    """SPEC §3: from (3000, 4500) m at (20, 15) m/s, whatever the seed."""
    np.testing.assert_array_equal(
        _starts("imm_gym/TPMAdaptPaper-v0", range(3)), [[3000.0, 4500.0, 20.0, 15.0]] * 3
    )
