"""``examples/stay_selection.py``: its classical IMMs are the evaluation's, run for run, and its
per-episode choices follow the evidence."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import load_example

from baselines.best_fixed import STAY_GRID, stay_grid
from baselines.fixed import FixedTPM
from imm_gym import EnvConfig
from imm_gym.evaluation.rollout import evaluation_config, rollout
from imm_gym.sim.config_file import read_env_config

ROOT = Path(__file__).resolve().parents[2]


def test_each_stays_errors_are_the_evaluations_classical_imm_at_that_stay() -> None:
    example = load_example("stay_selection")
    grid, err2, _, _, evidence = example.stay_runs({"scenario": "paper"}, 3, 5)
    assert grid == STAY_GRID
    assert evidence.shape == err2.shape and np.isfinite(evidence).all()
    for i in (0, STAY_GRID.index(0.95), len(STAY_GRID) - 1):
        policy = FixedTPM(3, STAY_GRID[i])
        config = evaluation_config(EnvConfig.build({"scenario": "paper"}), policy.env_overrides)
        run = rollout(policy, config, 3, 5)
        np.testing.assert_allclose(err2[i], run.squared_position_error, rtol=1e-12, atol=1e-9)


def test_a_two_model_bank_is_swept_from_its_uniform_tpm() -> None:
    """The sweep is the best-fixed search's for the bank: from 1/M, never an anti-sticky stay."""
    example = load_example("stay_selection")
    overrides = read_env_config(ROOT / "examples" / "probes" / "cv_ct.yaml")
    grid, err2, _, _, _ = example.stay_runs(overrides, 2, 5)
    assert grid == stay_grid(2) and grid[0] == 0.5 and len(err2) == len(grid)


def test_select_follows_the_evidence_and_average_weighs_by_it() -> None:
    example = load_example("stay_selection")
    rng = np.random.default_rng(0)
    S, R, K = 4, 5, 6
    pos = rng.normal(size=(S, R, K, 2))
    truth = rng.normal(size=(R, K, 2))
    evidence = np.full((S, R, K), -1.0)
    evidence[2] = 0.0  # stay 2 predicts every measurement best
    select, average = example.choose(pos, truth, evidence, 1.0)
    np.testing.assert_array_equal(select, np.sum((pos[2] - truth) ** 2, axis=-1))
    w = np.exp(np.where(np.arange(S) == 2, 0.0, -1.0)[:, None] * np.arange(1, K + 1))
    mean = np.einsum("sk,srkd->rkd", w / w.sum(axis=0), pos)
    np.testing.assert_allclose(average, np.sum((mean - truth) ** 2, axis=-1), rtol=1e-12)
    # equal evidence: the average is the plain mean of the estimates
    _, flat = example.choose(pos, truth, np.zeros((S, R, K)), 1.0)
    np.testing.assert_allclose(flat, np.sum((pos.mean(axis=0) - truth) ** 2, axis=-1))


@pytest.mark.parametrize(("option", "message"), [
    (["--runs", "0"], "--runs must be >= 1, got 0"),
    (["--seed", "-1"], "--seed must be >= 0, got -1"),
    (["--suite", "nowhere"], "--suite must be one of"),
])
def test_bad_options_are_refused_before_any_work(
    option: list[str], message: str, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    example = load_example("stay_selection")
    monkeypatch.setattr(example, "stay_runs", lambda *a, **k: pytest.fail("ran"))
    with pytest.raises(SystemExit) as exit_:
        example.main(option)
    assert exit_.value.code == 2 and message in capsys.readouterr().err
