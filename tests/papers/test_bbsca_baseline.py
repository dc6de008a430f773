"""The ``bbsca`` baseline around its tuner: which training runs it tunes on, what it reports, the
bank it hands the environment (the optimizer itself is replaced by a fake, so these are fast)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import baselines.bbsca as bbsca
from baselines import REGISTRY, BuildContext
from baselines.bbsca import BBSCATunedIMM, scaled_bank
from imm_gym import ConfigError, EnvConfig, paper_bank
from imm_gym.papers.tuning import OptimResult, TunedBank, TunerConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.tracking.hetero import HeteroBank, HeteroIMM, linear_models
from imm_gym.tracking.imm import run

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


def test_the_untuned_objective_is_the_innovations_of_the_untuned_bank(calls) -> None:
    """``untuned_train_objective``: the mean squared innovation, in units of the sensor's
    standard deviations, of the untuned bank over the training runs' detected steps."""
    _, notes = bbsca.tune_classical(PAPER, 2, 7, TunerConfig(particles=3, generations=1))
    ((batch, tpm, config, _),) = calls
    assert (config.particles, config.generations) == (3, 1)
    plain = HeteroIMM(linear_models(paper_bank()), PAPER.sensor, T=PAPER.source.T)
    z = batch.measurements.z[:, 1:]
    detected = batch.measurements.detected[:, 1:]
    result = run(plain, z, tpm, batch.x0, batch.P0, detected=detected, allow_failure=True)
    e = PAPER.sensor.residual(z, result.z_pred) / np.asarray(PAPER.sensor.sigma)
    assert notes["untuned_train_objective"] == pytest.approx(np.mean((e * e)[detected]), rel=1e-9)
    assert notes["train_seeds"] == "7..8"


def test_the_factors_multiply_a_heterogeneous_banks_own() -> None:
    """A heterogeneous bank's ``q_scale`` (0.5, 1, 2) times the factors (2, 3, 4) is
    (1, 3, 8); a factor of zero or below, or one too few, is refused naming it."""
    bank = dataclasses.replace(HeteroBank(), q_scale=(0.5, 1.0, 2.0))
    assert scaled_bank(bank, (2.0, 3.0, 4.0)).q_scale == pytest.approx((1.0, 3.0, 8.0))
    with pytest.raises(ConfigError, match=r"q_scale\[1\] must be in \(0\.0, inf\), got 0\.0"):
        scaled_bank(paper_bank(), (1.0, 0.0, 1.0))
    with pytest.raises(ConfigError, match=r"q_scale must have 3 entries \(one per model\)"):
        scaled_bank(paper_bank(), (1.0, 1.0))


def test_a_tuned_imm_with_a_stay_of_its_own_runs_that_stay() -> None:
    policy = BBSCATunedIMM(paper_bank(), FACTORS, stay=0.8)
    assert policy.stay == 0.8 and policy.env_overrides["initial_stay"] == 0.8
    assert policy.env_overrides["bank"] == scaled_bank(paper_bank(), FACTORS)
