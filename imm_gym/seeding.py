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


def streams(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """``(scenario_rng, noise_rng)`` spawned from ``SeedSequence(seed)``."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    scenario, noise = np.random.SeedSequence(int(seed)).spawn(2)
    return np.random.default_rng(scenario), np.random.default_rng(noise)
