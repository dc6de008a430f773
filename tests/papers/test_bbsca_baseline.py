"""The ``bbsca`` baseline around its tuner: which training runs it tunes on, what it reports, the
bank it hands the environment (the optimizer itself is replaced by a fake, so these are fast)."""

from __future__ import annotations

import numpy as np
import pytest

import baselines.bbsca as bbsca
from baselines import REGISTRY, BuildContext
from imm_gym import EnvConfig, paper_bank
from imm_gym.papers.tuning import OptimResult, TunedBank, TunerConfig
from imm_gym.sim.episodes import draw_batch

PAPER = EnvConfig(scenario="paper")
FACTORS = (2.0, 0.5, 1.5)


@pytest.fixture
def calls(monkeypatch) -> list[tuple]:
    """Replace the optimizer: record what it was given, return the factors :data:`FACTORS`."""
    seen: list[tuple] = []

    def fake_tune(imm, batch, tpm, sigma, config, bank="custom", tune_r=True):  # type: ignore
        seen.append((batch, tpm, config, tune_r))
        result = OptimResult(np.log10(FACTORS), 0.75, [0.9, 0.75], 20)
        return TunedBank(bank, FACTORS, method=config.method, objective=0.75), result

    monkeypatch.setattr(bbsca, "tune", fake_tune)
    return seen


def test_bbsca_tunes_on_the_first_fifth_of_the_training_runs(calls) -> None:
    """Ten training runs from seed 1000: the tuner gets the runs seeded 1000 and 1001 (the
    environment's draws), the configured TPM, the ``Q`` factors only; the notes and the policy
    carry the factors it returned."""
    context = BuildContext(PAPER, 1000, 10, train_armse=lambda policy: pytest.fail("a run"))
    policy, notes = REGISTRY["bbsca"].build(context)
    ((batch, tpm, config, tune_r),) = calls
    expected = draw_batch(PAPER.source, PAPER.sensor, 2, 1000, PAPER.velocity_std)
    assert batch.n_runs == 2 and tune_r is False and config == TunerConfig()
    np.testing.assert_array_equal(batch.measurements.z, expected.measurements.z)
    np.testing.assert_array_equal(batch.truth.states, expected.truth.states)
    stay = np.full((3, 3), 0.0025) + np.eye(3) * (0.995 - 0.0025)
    np.testing.assert_allclose(tpm, stay, rtol=1e-12)
    assert notes["train_seeds"] == "1000..1001"
    assert notes["q_scale"] == list(FACTORS) and policy.q_scale == FACTORS
    assert (notes["train_objective"], notes["evaluations"]) == (0.75, 20)
    bank = paper_bank()
    assert policy.env_overrides["bank"] == tuple(
        m.scaled(s) for m, s in zip(bank, FACTORS, strict=True)
    )
