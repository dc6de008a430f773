"""The critic's ground truth (``TrackingCore.critic_state``): the combined estimates' errors in
position and velocity and the coming model, for a bank of any state size."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import EnvConfig, TrackingCore
from imm_gym.sim.core import critic_state_size

CV_CA_CT = [
    {"kind": "cv", "noise": "continuous", "intensity": 0.1},
    {"kind": "ca", "noise": "continuous", "intensity": 0.05},
    {"kind": "ct", "turn_rate_deg": 4.0, "noise": "continuous", "intensity": 0.05},
]
SCALE = np.array([50.0, 50.0, 5.0, 5.0])


@pytest.mark.parametrize("bank", [None, CV_CA_CT])
def test_the_critic_sees_the_errors_of_the_tracker_and_the_shadow(bank) -> None:
    # x̂ = Σ_j μ_j x̂_j over each model's state, position and velocity only (a CA model's
    # common state is 6-d: x, y, vx, vy, ax, ay); random actions, so that the tracker's mode
    # probabilities are not the shadow's and each block is told from the other
    changes = {"family": {"horizon": 60}, "action_mode": "stay", "shadow": "fixed"}
    config = EnvConfig.build(changes if bank is None else {**changes, "bank": bank})
    core = TrackingCore(config, 3)
    core.reset(np.arange(3), [5, 6, 7])
    rng = np.random.default_rng(0)
    for _ in range(12):
        core.step(rng.uniform(-1, 1, (3, len(config.bank))))
    assert np.abs(core.mu - core.mu_s).max() > 0.01
    state = core.critic_state()
    assert state.shape == (3, critic_state_size(len(config.bank)))
    rows = np.arange(3)
    truth = core.truth[rows, core.k]
    for block, (mu, x) in enumerate([(core.mu, core.state_a.x), (core.mu_s, core.state_s.x)]):
        estimate = np.einsum("nj,nji->ni", mu, x)[:, :4]
        np.testing.assert_allclose(
            state[:, 4 * block:4 * block + 4], (estimate - truth) / SCALE, rtol=1e-4, atol=1e-5
        )
    np.testing.assert_array_equal(
        state[:, 8:], _one_hot(core.true_model[rows, core.k], len(config.bank))
    )


def _one_hot(models: np.ndarray, n_models: int) -> np.ndarray:
    """A row per slot, a 1 at its model, zeros where none matches (-1)."""
    out = np.zeros((models.size, n_models))
    for i, j in enumerate(models.tolist()):
        if j >= 0:
            out[i, j] = 1.0
    return out


def test_the_critic_sees_no_model_where_none_of_the_bank_matches() -> None:
    # a CT(+4°/s) bank without CT(-4°/s): a right turn is no model's (true model -1); its
    # one-hot is all zeros, not the last model's
    config = EnvConfig.build({"bank": CV_CA_CT, "action_mode": "stay"})
    core = TrackingCore(config, 8)
    core.reset(np.arange(8), list(range(8)))
    rows = np.arange(8)
    seen = False
    while not core.done.any():
        coming = core.true_model[rows, core.k]
        state = core.critic_state()
        np.testing.assert_array_equal(state[:, 8:], _one_hot(coming, 3))
        seen |= bool((coming == -1).any())
        if seen:
            break
        core.step(np.zeros((8, 3)))
    assert seen, "no right turn in these episodes: choose others"


def test_a_step_reports_the_model_the_critic_saw_coming() -> None:
    # info["true_model"] of the step from k to k + 1 is the episode's true_model[k], the model
    # of the interval the step ends, the one-hot the critic saw before it
    core = TrackingCore(EnvConfig.build({"family": {"horizon": 60}}), 3)
    core.reset(np.arange(3), [3, 4, 5])
    rows = np.arange(3)
    reported = []
    while not core.done.any():
        coming = core.true_model[rows, core.k]
        np.testing.assert_array_equal(core.critic_state()[:, 8:], _one_hot(coming, 3))
        reported.append(core.step(np.zeros((3, 9))).info["true_model"])
        np.testing.assert_array_equal(reported[-1], coming)
    np.testing.assert_array_equal(np.array(reported).T, core.true_model)
    assert np.count_nonzero(np.diff(core.true_model, axis=1)) >= 3  # the models switch
