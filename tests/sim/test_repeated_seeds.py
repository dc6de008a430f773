"""Slots reset with the same seed in one call (the best fixed TPM's search: every run from each of
several TPMs) draw their episode once and share it; each keeps streams of its own, in the state
they would be in had it drawn alone. Held bit for bit against the slots reset one at a time."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym.seeding import clone, streams
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.presets import CONTINUOUS_BANK
from imm_gym.tracking.tpm import stay_tpm

CONFIGS = {
    "default": EnvConfig(),
    "paper": EnvConfig(scenario="paper"),
    "varied": EnvConfig(
        bank=CONTINUOUS_BANK,
        vary={"T": (0.5, 5.0), "sigma_r": (10.0, 100.0), "detection_prob": (0.8, 1.0),
              "speed": (5.0, 300.0), "q_scale": (0.3, 30.0), "share": 0.5},
    ),
}
SEEDS = [3, 7, 3, 11, np.int64(7), 3]


def _episode(core: TrackingCore) -> list[np.ndarray]:
    return [core.truth, core.z, core.detected, core.outlier, core.true_model, core.fixed_tpms,
            core.state_a.x, core.state_a.P, core.state_s.P, *core.kernel_args[:3], core.observe()]


@pytest.mark.parametrize("name", list(CONFIGS))
def test_repeated_seeds_draw_what_each_slot_draws_alone(name: str) -> None:
    config = CONFIGS[name]
    n = len(SEEDS)
    together, alone = TrackingCore(config, n), TrackingCore(config, n)
    tpms = np.stack([stay_tpm(3, s) for s in np.linspace(0.5, 0.99, n)])
    together.reset(np.arange(n), SEEDS, tpms)
    for i, seed in enumerate(SEEDS):
        alone.reset(np.array([i]), [seed], tpms[i:i + 1])
    for a, b in zip(_episode(together), _episode(alone), strict=True):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()
    action = np.zeros((n, together.action_dim))
    for _ in range(3):
        together.step(action)
        alone.step(action)
    for a, b in zip(_episode(together), _episode(alone), strict=True):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()
    # the next episodes continue each slot's own streams: twins draw the same again
    together.reset(np.arange(n), [None] * n)
    alone.reset(np.arange(n), [None] * n)
    for a, b in zip(_episode(together), _episode(alone), strict=True):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()
    assert not np.array_equal(together.z[0], together.z[1])
    assert np.array_equal(together.z[0], together.z[2])


def test_seeds_are_still_checked_and_counted() -> None:
    core = TrackingCore(EnvConfig(), 3)
    with pytest.raises(ValueError, match="non-negative integer"):
        core.reset(np.arange(3), [1, True, 1])
    with pytest.raises(ValueError, match="non-negative integer"):
        core.reset(np.arange(3), [1, 1.0, 1])
    with pytest.raises(ValueError, match="2 seeds for 3 slots"):
        core.reset(np.arange(3), [1, 1])


def test_a_rejected_seed_replaces_no_slot_s_streams() -> None:
    # a bad seed after good ones: the earlier slots' streams are kept (their next episodes
    # continue the seed-0 sequence), not replaced by the good seeds' before the refusal
    core, untouched = TrackingCore(EnvConfig(), 2), TrackingCore(EnvConfig(), 2)
    core.reset(np.arange(2), [0, 1])
    untouched.reset(np.arange(2), [0, 1])
    for bad in ([5, -1], [5, 1.5]):
        with pytest.raises(ValueError, match="non-negative integer"):
            core.reset(np.arange(2), bad)
    core.reset(np.arange(2), [None, None])
    untouched.reset(np.arange(2), [None, None])
    np.testing.assert_array_equal(core.truth, untouched.truth)
    np.testing.assert_array_equal(core.z, untouched.z)


def test_a_clone_draws_the_same_numbers_independently() -> None:
    scenario, _ = streams(5)
    scenario.random(3)
    twin = clone(scenario)
    assert twin is not scenario and twin.bit_generator is not scenario.bit_generator
    assert np.array_equal(twin.random(4), scenario.random(4))
    ahead = scenario.random(2)  # the twin does not move with it
    assert np.array_equal(twin.random(2), ahead)


def test_a_slot_listed_twice_in_one_reset_is_refused() -> None:
    """One seed per slot: a slot listed twice would draw from one listing's streams for both
    (the second episode of its last seed), so the reset is refused and no slot changes."""
    core = TrackingCore(EnvConfig(), 2)
    core.reset(np.array([0, 1]), [3, 4])
    before = core.z.copy()
    with pytest.raises(ValueError, match=r"slots \[0\] listed more than once"):
        core.reset(np.array([0, 1, 0]), [5, 5, 9])
    np.testing.assert_array_equal(core.z, before)


def test_a_slot_outside_the_core_is_refused() -> None:
    """A negative slot wrapped round to the last one, a slot past the end raised a bare
    IndexError from list assignment: both are refused by name before any slot changes."""
    core = TrackingCore(EnvConfig(), 2)
    core.reset(np.array([0, 1]), [3, 4])
    before = core.z.copy()
    for bad in ([0, -1], [2]):
        with pytest.raises(IndexError, match=r"slots must be in \[0, 1\], got \[(-1|2)\]"):
            core.reset(np.array(bad), [5] * len(bad))
    np.testing.assert_array_equal(core.z, before)
