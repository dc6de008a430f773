"""How a heterogeneous bank starts (:class:`imm_gym.tracking.hetero.HeteroBank`,
:meth:`HeteroIMM.init`): given start probabilities, the uniform default of a bare model list,
the models' display names."""

from __future__ import annotations

import numpy as np

from imm_gym import PositionSensor
from imm_gym.tracking.hetero import HeteroBank, HeteroIMM

SENSOR = PositionSensor(sigma_pos=0.5, sigma_vel=0.5)
X0, P0 = np.array([[1.0, 2.0, 3.0, 4.0]]), np.diag([0.5, 0.6, 1.0, 1.0])


def test_given_start_probabilities_replace_seed_002s() -> None:
    """``initial_probs`` of the bank ``ncv, ct, ctra`` are its start, not seed 002's
    (0.90, 0.08, 0.02); in another order they follow the models."""
    for models, probs in (
        (("ncv", "ct", "ctra"), (0.2, 0.3, 0.5)),
        (("ctra", "ncv", "ct"), (1 / 3, 1 / 3, 1 / 3)),
        (("ct", "ncv"), (0.9, 0.1)),
    ):
        bank = HeteroBank(models=models, initial_probs=probs)
        assert bank.probs == probs
        state = HeteroIMM(bank, SENSOR, T=0.1).init(X0, P0)
        np.testing.assert_array_equal(state.mu, [probs])
