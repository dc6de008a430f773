"""How a heterogeneous bank starts (:class:`imm_gym.tracking.hetero.HeteroBank`,
:meth:`HeteroIMM.init`): given start probabilities, the uniform default of a bare model list,
the models' display names."""

from __future__ import annotations

import numpy as np

from imm_gym import PositionSensor, paper_bank
from imm_gym.sim.render import model_labels
from imm_gym.tracking.hetero import HeteroBank, HeteroIMM, HeteroModel, linear_models

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


def test_a_bare_list_of_models_starts_uniform() -> None:
    """Without a :class:`HeteroBank` (and no ``mode_probs``) every model starts at ``1 / M``."""
    for models in (
        linear_models(paper_bank()),
        (HeteroModel("ncv", (0.6,)), HeteroModel("ct", (2.4, 0.6))),
        (
            HeteroModel("ncv", (0.6,)),
            HeteroModel("ct", (2.4, 0.6)),
            HeteroModel("ctra", (20, 3)),
            HeteroModel("ncv", (2.0,)),
        ),
    ):
        state = HeteroIMM(models, SENSOR, T=0.1).init(np.tile(X0, (2, 1)), P0)
        M = len(models)
        np.testing.assert_allclose(state.mu, np.full((2, M), 1.0 / M), rtol=1e-15)


def test_model_labels_are_the_names_the_renderer_gives_the_bank() -> None:
    """``HeteroModel.label`` names a model as the renderer's legend does (``NCV``, ``CT``,
    ``CTRA``, from the bank's kinds)."""
    bank = HeteroBank(models=("ctra", "ncv", "ct"))
    assert [m.label for m in bank.build()] == model_labels(bank) == ["CTRA", "NCV", "CT"]


def test_run_starts_from_the_given_mode_probabilities() -> None:
    """``HeteroIMM.run(..., mode_probs)`` equals ``init`` with those probabilities and ``step``
    after ``step``; starting elsewhere changes the run."""
    rng = np.random.default_rng(2)
    imm = HeteroIMM(HeteroBank(), SENSOR, T=0.1)
    z = rng.normal(size=(1, 12, 4)) * 0.5 + np.array([1.0, 2.0, 3.0, 4.0])
    tpm, mu0 = np.full((3, 3), 1 / 3) * 0.3 + 0.7 * np.eye(3), np.array([0.05, 0.15, 0.8])
    out = imm.run(z, tpm, X0, P0, mode_probs=mu0)
    state = imm.init(X0, P0, mu0)
    for k in range(12):
        state, step = imm.step(state, tpm, z[:, k])
        np.testing.assert_allclose(out.mode_probs[0, k], step.mode_probs[0], rtol=1e-13)
        np.testing.assert_allclose(out.x[0, k], step.x[0], rtol=1e-13, atol=1e-13)
    default = imm.run(z, tpm, X0, P0)
    assert np.abs(default.mode_probs[0, 0] - out.mode_probs[0, 0]).max() > 1e-3
