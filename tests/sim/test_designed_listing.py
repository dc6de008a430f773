"""A designed family (``designed_share > 0``) draws its targets for the tracker's CT models in
canonical order: every listing of one bank draws the same targets."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym.scenarios.segments import RandomFamily
from imm_gym.sim.conditions import Variation
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.tracking.models import MotionModel
from imm_gym.tracking.sensors import Sonar

CV = MotionModel("cv", noise="continuous", intensity=1.0)
LEFT = MotionModel("ct", 4.0, noise="continuous", intensity=20.0)
RIGHT = MotionModel("ct", -4.0, noise="continuous", intensity=20.0)
SLOW = MotionModel("ct", 2.0, noise="continuous", intensity=10.0)


@pytest.mark.parametrize("variation", [None, Variation(sigma_r=(10.0, 100.0), T=(0.5, 2.0))])
@pytest.mark.parametrize("listing", [(CV, RIGHT, LEFT), (LEFT, RIGHT, SLOW, CV)])
def test_every_listing_draws_the_same_targets(listing: tuple, variation: Variation | None) -> None:
    family = RandomFamily(designed_share=1.0)
    canonical = tuple(sorted(listing, key=lambda m: (m.kind != "cv", abs(m.omega), m.omega < 0)))
    a = draw_batch(family, Sonar(), 12, 0, variation=variation, bank=canonical)
    b = draw_batch(family, Sonar(), 12, 0, variation=variation, bank=listing)
    np.testing.assert_array_equal(a.truth.states, b.truth.states)
    np.testing.assert_array_equal(a.measurements.z, b.measurements.z)


def test_a_canonical_policy_sees_one_tracker_in_any_listing() -> None:
    cores = []
    for bank in ((CV, LEFT, RIGHT), (CV, RIGHT, LEFT)):
        config = EnvConfig(scenario="random", family={"designed_share": 1.0}, bank=bank,
                           model_order="canonical")
        core = TrackingCore(config, 3)
        core.reset(np.arange(3), [0, 1, 2])
        cores.append(core)
    np.testing.assert_array_equal(cores[0].observe(), cores[1].observe())
    for _ in range(20):
        steps = [core.step(np.zeros((3, core.action_dim))) for core in cores]
        np.testing.assert_allclose(
            steps[0].info["estimate"], steps[1].info["estimate"], rtol=0, atol=1e-9
        )
