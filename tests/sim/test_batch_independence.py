"""A slot's episode does not depend on how many slots share the batch: slot 2 of five equals a
core of one slot reset with the same seed, bit for bit, under the settings whose per-slot
numbers go through a matrix product (the stay bank's evidence-weighted stay, the learned
detector's network), and the shadow detector beside them."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig

VARIANTS = {
    "stay bank": {"action_mode": "stay", "stay_base": "evidence",
                  "obs_features": ("stay_bank_evidence",), "reward": "bank_advantage"},
    "learned detector": {"action_mode": "stay", "detector_share": 0.3, "detector": "learned",
                         "obs_features": ("detector_belief",)},
    "shadow detector": {"action_mode": "stay", "detector_share": 0.3,
                        "obs_features": ("detector_belief",)},
}


@pytest.mark.parametrize("name", list(VARIANTS))
def test_a_slot_of_a_batch_is_the_slot_alone(name) -> None:
    config = EnvConfig.build(VARIANTS[name])
    batch, alone = TrackingCore(config, 5), TrackingCore(config, 1)
    batch.reset(np.arange(5), [11, 12, 13, 14, 15])
    alone.reset(np.array([0]), [13])
    rng = np.random.default_rng(0)
    for _ in range(60):
        actions = rng.uniform(-1.0, 1.0, size=(5, batch.action_dim))
        b, a = batch.step(actions), alone.step(actions[2:3])
        np.testing.assert_array_equal(b.obs[2], a.obs[0])
        np.testing.assert_array_equal(b.reward[2], a.reward[0])
        for key in ("estimate", "mode_probs", "tpm"):
            np.testing.assert_array_equal(b.info[key][2], a.info[key][0], key)


@pytest.mark.parametrize(
    "active", [np.array([0, 2]), np.array([1, 0, 1, 0]), np.ones(3, dtype=bool)]
)
def test_active_must_be_a_boolean_mask_of_the_slots(active: np.ndarray) -> None:
    """An index array (or 0/1 integers, or a mask of another length) would be read as a mask
    of other slots than meant: refused before anything moves."""
    core = TrackingCore(EnvConfig(), 4)
    core.reset(np.arange(4), [0, 1, 2, 3])
    with pytest.raises(ValueError, match=r"active must be a boolean mask of shape \(4,\)"):
        core.step(np.zeros((4, 9)), active=active)
    assert core.k.tolist() == [0, 0, 0, 0]
