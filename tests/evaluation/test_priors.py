"""``imm_gym.evaluation.priors``: priors given step by step run the evaluation's tracker, run
for run, prior-major."""

from __future__ import annotations

from typing import Any

import numpy as np

from baselines.fixed import FixedTPM
from imm_gym import EnvConfig
from imm_gym.evaluation.metrics import mode_accuracy, mode_prob_tv
from imm_gym.evaluation.priors import prior_core, run_priors
from imm_gym.evaluation.rollout import armse_from_squared, evaluation_config, rollout
from imm_gym.tracking.tpm import stay_tpm

RUNS, SEED = 6, 11


def test_fixed_rows_are_the_evaluations_fixed_tpm_and_the_slots_prior_major() -> None:
    stays = (0.5, 0.98, 0.5)  # the first and last prior alike: same runs, same numbers
    core = prior_core({"scenario": "paper"}, len(stays), RUNS, SEED)
    tpms = np.repeat(np.stack([stay_tpm(3, s) for s in stays]), RUNS, axis=0)
    seen: list[Any] = []

    def rows(k: int, info: dict[str, Any] | None) -> np.ndarray:
        seen.append((k, None if info is None else info["step"][0]))
        return tpms

    result = run_priors(core, len(stays), rows)
    K = core.horizon
    assert seen[:2] == [(0, None), (1, 1)] and len(seen) == K  # the previous step's info
    assert result.squared_error.shape == (3, RUNS, K) and result.mode_probs.shape == (3, RUNS, K, 3)
    np.testing.assert_array_equal(result.squared_error[0], result.squared_error[2])
    for p, stay in enumerate(stays[:2]):
        policy = FixedTPM(3, stay)
        config = evaluation_config(EnvConfig.build({"scenario": "paper"}), policy.env_overrides)
        run = rollout(policy, config, RUNS, SEED)
        armse, accuracy, tv = result.scores(p)
        np.testing.assert_allclose(armse, armse_from_squared(run.squared_position_error),
                                   rtol=1e-9)
        np.testing.assert_allclose(accuracy, mode_accuracy(run.mode_probs, run.true_model),
                                   atol=0.005)
        np.testing.assert_allclose(tv, mode_prob_tv(run.mode_probs), atol=0.005)
    assert result.scores(0)[0] != result.scores(1)[0]
