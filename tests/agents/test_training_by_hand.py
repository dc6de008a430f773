"""The training helpers of :mod:`agents.training` called directly, each against a value worked
by hand: the weight average, the seeding of the training slots, the thread limits and the
checks of the hyperparameters."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch
from threadpoolctl import threadpool_info, threadpool_limits

from agents.training import (
    check_batches,
    check_hyperparams,
    check_input_size,
    set_threads,
)
from imm_gym.validation import ConfigError


def test_set_threads_limits_torch_and_the_blas_to_one_thread(monkeypatch) -> None:
    """Torch and every BLAS pool set to two threads are back to one after ``set_threads()``;
    the thread variables are set to 1 where unset and kept where set."""
    threads = torch.get_num_threads()
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    try:
        torch.set_num_threads(2)
        threadpool_limits(2)
        set_threads()
        assert torch.get_num_threads() == 1
        assert [pool["num_threads"] for pool in threadpool_info()] == [1] * len(threadpool_info())
    finally:
        torch.set_num_threads(threads)
        threadpool_limits(1)
    import os

    assert os.environ["OMP_NUM_THREADS"] == os.environ["MKL_NUM_THREADS"] == "1"
    assert os.environ["OPENBLAS_NUM_THREADS"] == "3"



@pytest.mark.parametrize(
    "given",
    [{"n_envs": 10_000}, {"gamma": 1.0, "gae_lambda": 1.0}, {"swa_start": 0},
     {"learning_rate": "lin_1e-9"}, {"n_timesteps": 1}],
)
def test_the_hyperparameters_take_the_ends_of_their_ranges(given) -> None:
    """The closed ends: 10 000 slots (a run seed's own seeds), gamma and gae_lambda 1 (no
    discount), averaging from step 0, the smallest positive schedule, a budget of one step."""
    assert check_hyperparams("f", given, "ppo", complete=False) == given



@pytest.mark.parametrize(
    ("given", "message"),
    [({"n_envs": 10_001}, r"n_envs must be in \[1, 10000\]"),
     ({"gamma": 1.0 + 1e-12}, r"gamma must be in \(0, 1\]"),
     ({"learning_rate": "lin_0"}, "learning_rate must be .*, the number finite and > 0"),
     ({"clip_range": "lin_0.0"}, "clip_range must be .*, the number finite and > 0"),
     ({"swa_start": -1e-9}, r"swa_start must be a fraction of the budget in \[0, 1\)"),
     ({"swa_start": 1}, r"swa_start must be a fraction of the budget in \[0, 1\)"),
     ({"n_timesteps": 0}, "n_timesteps must be a whole number >= 1")],
)
def test_the_hyperparameters_just_outside_their_ranges_are_refused(given, message) -> None:
    """One past each end: a slot beyond a run seed's 10 000 seeds, a discount above 1, a
    linear schedule from 0 (no learning at all), averaging before the start or from the end,
    a budget of no step."""
    with pytest.raises(ConfigError, match=f"f: {message}"):
        check_hyperparams("f", given, "ppo", complete=False)



def test_an_entry_without_n_steps_has_sb3_s_rollout_of_2048_steps() -> None:
    """One slot and SB3's default n_steps (2048) is a rollout of 2048 samples, enough to
    normalize the advantages; one slot of one step is not."""
    check_batches({"n_envs": 1})
    with pytest.raises(ConfigError, match=r"n_envs \* n_steps must be >= 2"):
        check_batches({"n_envs": 1, "n_steps": 1})



def test_the_critic_s_entries_count_in_the_input_only_with_critic_state() -> None:
    """A frame of loglik, innovation and speed for 3 models and a 2-d measurement is 16
    entries (mu(t) 3, mu(t-1) 3, loglik 3, innovation 6, speed 1), 27 with the critic's 11
    (two 4-d errors and the coming model one-hot): the deepest stack is MAX_INPUT // 16 frames
    without the critic's entries and MAX_INPUT // 27 with them."""
    from agents.schema import MAX_INPUT

    config = SimpleNamespace(bank=[None] * 3, obs_features=["loglik", "innovation", "speed"],
                             sensor=SimpleNamespace(dim_z=2))
    check_input_size({"frame_stack": MAX_INPUT // 16}, config)
    with pytest.raises(ConfigError, match=rf"frame_stack must be in \[1, {MAX_INPUT // 16}\]"):
        check_input_size({"frame_stack": MAX_INPUT // 16 + 1}, config)
    check_input_size({"frame_stack": MAX_INPUT // 27, "critic_state": True}, config)
    with pytest.raises(ConfigError, match=rf"frame_stack must be in \[1, {MAX_INPUT // 27}\]"):
        check_input_size({"frame_stack": MAX_INPUT // 27 + 1, "critic_state": True}, config)
