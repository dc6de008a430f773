"""The training helpers of :mod:`agents.training` called directly, each against a value worked
by hand: the weight average, the seeding of the training slots, the thread limits and the
checks of the hyperparameters."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from threadpoolctl import threadpool_info, threadpool_limits
from torch import nn

from agents.training import (
    SLOTS_PER_SEED,
    TRAIN_SEED_BASE,
    WeightAverage,
    build_algorithm,
    check_batches,
    check_hyperparams,
    check_input_size,
    seed_training_env,
    set_threads,
)
from imm_gym.validation import ConfigError


class _Policy(nn.Module):
    """Two float tensors and an integer buffer, as the asymmetric actor's input index."""

    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(2, 1)
        self.register_buffer("index", torch.tensor([0, 1]))

    def set(self, value: float, index: int) -> None:
        with torch.no_grad():
            self.linear.weight.fill_(value)
            self.linear.bias.fill_(-2 * value)
        self.index.fill_(index)


def test_the_weight_average_is_the_mean_of_the_weights_after_each_update_from_start() -> None:
    """Updates (n, step, weight): (0, 0, 9) is the initial weights, (1, 100, 7) before start
    200, then (2, 200, 1), (3, 300, 2), (3, 300, 50) (the same update again, ignored) and
    (4, 400, 6): the mean of 1, 2 and 6 by hand is 3, the bias's -6; the integer buffer is the
    last update's, not a mean."""
    policy = _Policy()
    model = SimpleNamespace(policy=policy, _n_updates=0, num_timesteps=0)
    swa = WeightAverage(200)
    for n, step, value in ((0, 0, 9.0), (1, 100, 7.0), (2, 200, 1.0), (3, 300, 2.0),
                           (3, 300, 50.0), (4, 400, 6.0)):
        model._n_updates, model.num_timesteps = n, step
        policy.set(value, index=n)
        swa.update(model)
    assert swa.snapshots == 3 and swa.last_update == 4
    assert swa.average["linear.weight"].numpy() == pytest.approx(np.full((1, 2), 3.0))
    assert swa.average["linear.bias"].numpy() == pytest.approx([-6.0])
    assert swa.average["index"].tolist() == [4, 4]
    policy.set(0.0, index=0)
    swa.apply(model)
    assert policy.linear.weight.detach().numpy() == pytest.approx(np.full((1, 2), 3.0))
    assert policy.index.tolist() == [4, 4]


def test_a_weight_average_of_no_update_cannot_be_applied() -> None:
    model = SimpleNamespace(policy=_Policy(), _n_updates=3, num_timesteps=99)
    swa = WeightAverage(100)
    swa.update(model)
    with pytest.raises(RuntimeError, match="training ended before step 100"):
        swa.apply(model)


class _Env:
    def __init__(self) -> None:
        self.seeds: list[int] = []

    def seed(self, seed: int) -> None:
        self.seeds.append(seed)


@pytest.mark.parametrize("seed", [0, 1, 3, 2**32 - 1])
def test_the_training_slots_of_a_run_seed_start_at_its_own_ten_thousand_seeds(seed) -> None:
    """Run seed s seeds slot 0 with TRAIN_SEED_BASE + 10 000 s (the VecEnv adds i for slot i),
    so that runs s and s + 1 are 10 000 seeds apart, as many as a run's slots may be."""
    env = _Env()
    seed_training_env(env, seed)
    assert SLOTS_PER_SEED == 10_000
    assert env.seeds == [TRAIN_SEED_BASE + 10_000 * seed]


def test_the_algorithm_is_built_then_its_slots_seeded_with_the_training_seeds() -> None:
    """The constructor (which seeds the environment with seed + i) is called first, with the
    run seed and the CPU, and the training seeds are set after it."""
    env = _Env()

    class Algo:
        def __init__(self, policy, env, seed, device, **kwargs) -> None:
            env.seed(seed)
            self.args = (policy, seed, device, kwargs)

    model = build_algorithm(Algo, "MlpPolicy", env, 7, gamma=0.9)
    assert model.args == ("MlpPolicy", 7, "cpu", {"gamma": 0.9})
    assert env.seeds == [7, TRAIN_SEED_BASE + 70_000]


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
