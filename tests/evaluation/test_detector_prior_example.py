"""``examples/detector_prior.py``: without the detector's share its priors are the evaluation's
classical IMMs, run for run; with it, a nearly uniform prior identifies the maneuvers."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import load_example

from baselines.fixed import FixedTPM
from imm_gym import EnvConfig
from imm_gym.evaluation.metrics import mode_accuracy
from imm_gym.evaluation.rollout import armse_from_squared, evaluation_config, rollout


def test_no_share_is_the_evaluations_classical_imm_and_a_share_identifies_the_modes() -> None:
    example = load_example("detector_prior")
    scores = example.detector_runs({"scenario": "paper"}, (0.0, 0.5), 10, 5)
    for stay in (example.STAYS[0], 0.95, example.STAYS[-1]):
        policy = FixedTPM(3, stay)
        config = evaluation_config(EnvConfig.build({"scenario": "paper"}), policy.env_overrides)
        run = rollout(policy, config, 10, 5)
        armse, accuracy, _ = scores[(stay, 0.0)]
        np.testing.assert_allclose(armse, armse_from_squared(run.squared_position_error),
                                   rtol=1e-9)
        np.testing.assert_allclose(accuracy, mode_accuracy(run.mode_probs, run.true_model),
                                   atol=0.005)
    # the uniform prior's mode probabilities are one step's likelihoods: near chance; leaning
    # half of its jumps toward the shadow's belief makes them follow the maneuvers
    assert scores[(example.STAYS[0], 0.0)][1] < 0.4 < 0.6 < scores[(example.STAYS[0], 0.5)][1]


@pytest.mark.parametrize(("option", "message"), [
    (["--runs", "0"], "--runs must be >= 1, got 0"),
    (["--runs", "-3"], "--runs must be >= 1, got -3"),  # it said n_envs ... got -42
    (["--seed", "-1"], "--seed must be >= 0, got -1"),
    (["--suite", "nowhere"], "--suite must be one of"),
    (["--share", "0"], "--share must be in (0, 1]"),
])
def test_bad_options_are_refused_before_any_work(
    option: list[str], message: str, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    example = load_example("detector_prior")
    monkeypatch.setattr(example, "detector_runs", lambda *a, **k: pytest.fail("ran"))
    with pytest.raises(SystemExit) as exit_:
        example.main(option)
    assert exit_.value.code == 2 and message in capsys.readouterr().err
