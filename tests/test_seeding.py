"""The seed ranges of :mod:`imm_gym.seeding` as the README and the command line state them, with
literal numbers: RLlib's sub-env seeds, the evaluation's and the tuners' ranges, the agents'
validation and training seeds, and the refusal of a negative seed; a clone of a generator of
any of numpy's bit generators."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym.cli.arguments import seed_problem
from imm_gym.seeding import clone, rllib_seed, streams


@pytest.mark.parametrize(
    ("seed", "runner", "sub_env", "generation"),
    [(0, 0, 0, 0), (3, 1, 2, 1), (7, 65_535, 65_535, 65_535)],
)
def test_rllib_seeds_follow_the_readme_s_formula(seed, runner, sub_env, generation) -> None:
    """README: ``rllib_seed(seed, w, i, g) = 2⁶² + ((seed·2¹⁶ + g)·2¹⁶ + w)·2¹⁶ + i``."""
    expected = 2**62 + ((seed * 65_536 + generation) * 65_536 + runner) * 65_536 + sub_env
    assert rllib_seed(seed, runner, sub_env, generation) == expected


@pytest.mark.parametrize("field", ["runner", "sub_env", "generation"])
def test_an_rllib_seed_field_of_two_to_the_sixteen_is_refused(field: str) -> None:
    fields = {"runner": 0, "sub_env": 0, "generation": 0, field: 65_536}
    with pytest.raises(ValueError, match=rf"^{field} must be below 65536, got 65536"):
        rllib_seed(0, **fields)


def test_the_evaluation_s_runs_and_seeds_end_where_the_cli_says() -> None:
    """Runs up to the tuners' offset of 1 000 000 (their training seeds start at ``--seed +
    1 000 000``) and ``--seed`` up to 48 999 900 (50 000 000 − 1 000 000 − 100 training runs,
    below the agents' validation seeds)."""
    assert seed_problem(0, 1_000_000) is None
    assert "--runs must be in [1, 1000000]" in seed_problem(0, 1_000_001)
    assert seed_problem(48_999_900, 1) is None
    assert "--seed must be in [0, 48999900]" in seed_problem(48_999_901, 1)


def test_a_negative_seed_is_refused_naming_seed() -> None:
    with pytest.raises(ValueError, match=r"^seed must be a non-negative integer, got -1$"):
        streams(-1)


@pytest.mark.parametrize(
    "bit_generator",
    [np.random.PCG64, np.random.Philox, np.random.MT19937, np.random.SFC64, np.random.PCG64DXSM],
)
def test_a_clone_of_any_bit_generator_draws_the_same_numbers_independently(bit_generator) -> None:
    original = np.random.Generator(bit_generator(11))
    original.random(3)
    twin = clone(original)
    assert type(twin.bit_generator) is bit_generator
    expected = np.random.Generator(bit_generator(11)).random(8)[3:]
    np.testing.assert_array_equal(twin.random(5), expected)
    np.testing.assert_array_equal(original.random(5), expected)  # not moved by the twin


def test_the_agents_validation_and_training_seeds_start_where_the_cli_says() -> None:
    """The agents' validation seeds start at 50 000 000 and their training slots at
    100 000 000 (``TRAIN_SEED_BASE + 10 000 s + i``): an evaluation seed past its most is
    refused naming both."""
    message = seed_problem(48_999_901, 1)
    assert "validation seeds (50000000+) and training slots (100000000+)" in message
