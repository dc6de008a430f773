"""Random streams. Every draw of imm_gym goes through a seeded ``numpy.random.Generator``.

A seed gives two independent streams — one for the scenario (target trajectory), one for the
sensor noise — so that policies are compared on identical targets *and* identical noise (common
random numbers). Monte-Carlo run ``r`` of an evaluation seeded ``s`` uses seed ``s + r``: the same
streams as a scalar environment reset with ``seed = s + r``.
"""

from __future__ import annotations

import numpy as np

#: Training runs of the tuners use seeds ``seed + TRAIN_SEED_OFFSET + r`` (never evaluation seeds).
TRAIN_SEED_OFFSET = 1_000_000

#: The validation runs that pick an agent's checkpoint (``agents.training``): seeds
#: ``VALIDATION_SEED_BASE + r``. Evaluation and tuning seeds stay below it.
VALIDATION_SEED_BASE = 50_000_000

#: An agent's training slots (``agents.training.seed_training_env``): slot ``i`` of run seed ``s``
#: is seeded with ``TRAIN_SEED_BASE + 10_000 s + i``.
TRAIN_SEED_BASE = 100_000_000

#: The learned detector's episodes (``python -m agents.detector``): seeds from ``2**61`` on,
#: above every evaluation, validation and SB3 training seed and below RLlib's.
DETECTOR_SEED_BASE = 1 << 61

#: RLlib training (``train.py --engine rllib``): sub-env seeds from ``2**62`` on, above every
#: evaluation (``0..``), validation (``50,000,000..``) and SB3 training (``100,000,000 +
#: 10,000 s + i``) seed of training seeds ``s < 4 * 10**14``.
RLLIB_SEED_BASE = 1 << 62
#: Each field of an RLlib sub-env seed (environment built, runner, sub-env) is below this.
RLLIB_SEED_FIELD = 1 << 16


def rllib_seed(seed: int, runner: int, sub_env: int, generation: int = 0) -> int:
    """The seed of sub-env ``sub_env`` of RLlib env runner ``runner`` in the ``generation``-th
    environment that runner built (0, then 1, ... after a restart), for training seed ``seed``:

    ``RLLIB_SEED_BASE + ((seed F + generation) F + runner) F + sub_env``, ``F = RLLIB_SEED_FIELD``

    Distinct tuples give distinct seeds (mixed radix), all in the RLlib range.

    Raises:
        ValueError: a negative argument, or a field other than ``seed`` not below ``F``.
    """
    F = RLLIB_SEED_FIELD
    fields = {"generation": generation, "runner": runner, "sub_env": sub_env}
    for name, value in {"seed": seed, **fields}.items():
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    for name, value in fields.items():
        if value >= F:
            raise ValueError(f"{name} must be below {F}, got {value}")
    return (
        RLLIB_SEED_BASE + ((int(seed) * F + int(generation)) * F + int(runner)) * F + int(sub_env)
    )


def streams(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """``(scenario_rng, noise_rng)`` spawned from ``SeedSequence(seed)``."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    scenario, noise = np.random.SeedSequence(int(seed)).spawn(2)
    return np.random.default_rng(scenario), np.random.default_rng(noise)


def clone(generator: np.random.Generator) -> np.random.Generator:
    """An independent generator in ``generator``'s state: the same numbers from here on, and
    drawing from one does not move the other (its ``bit_generator.seed_seq`` is not the
    original's: ``spawn`` on the clone gives other children)."""
    bit_generator = type(generator.bit_generator)(0)
    bit_generator.state = generator.bit_generator.state
    return np.random.Generator(bit_generator)
