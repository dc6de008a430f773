"""``examples/detector_headroom.py``: its ``tracker (env)`` rows are the ``turn-rate-prior``
baseline's roll-outs, run for run; its true turn rates are the truth's heading changes; the
turn rate known sooner leads the prior better."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from helpers import load_example

from baselines.turn_rate_prior import TurnRatePrior
from imm_gym import EnvConfig
from imm_gym.evaluation.metrics import mode_accuracy
from imm_gym.evaluation.rollout import armse_from_squared, evaluation_config, rollout
from imm_gym.sim.config_file import read_env_config


def test_the_trackers_rows_are_the_baselines_and_a_sooner_rate_leads_better() -> None:
    example = load_example("detector_headroom")
    scores = example.detector_runs({"scenario": "random"}, (0, 8), 12, 3)
    for stay, share in ((1 / 3, 0.5), (0.9, 0.25), (0.995, 0.75)):
        policy = TurnRatePrior(3, stay, share)
        config = evaluation_config(EnvConfig.build({"scenario": "random"}), policy.env_overrides)
        run = rollout(policy, config, 12, 3)
        armse, accuracy = scores[("tracker (env)", stay, share)]
        np.testing.assert_allclose(armse, armse_from_squared(run.squared_position_error),
                                   rtol=1e-6)
        np.testing.assert_allclose(accuracy, mode_accuracy(run.mode_probs, run.true_model),
                                   atol=0.005)

    def best(detector: str) -> float:
        return min(scores[(detector, s, v)][0] for s in example.STAYS for v in example.SHARES)

    assert best("true, 0 late") < best("true, 8 late") < best("tracker (env)")


def test_true_turn_rates_are_the_heading_changes() -> None:
    example = load_example("detector_headroom")
    T, omega = 2.0, np.array([0.0, 0.01, -0.03])
    heading = np.concatenate([[3.1], 3.1 + np.cumsum(omega * T)])  # crosses +-pi
    truth = np.zeros((1, 4, 4))
    truth[0, :, 2], truth[0, :, 3] = 20.0 * np.cos(heading), 20.0 * np.sin(heading)
    np.testing.assert_allclose(example.true_turn_rates(truth, T)[0], omega, atol=1e-12)


def test_varied_conditions_take_each_runs_sampling_period_and_leave_out_the_ekf() -> None:
    example = load_example("detector_headroom")
    overrides = read_env_config(Path(__file__).parents[2] / "examples" / "broad.yaml")
    scores = example.detector_runs(overrides, (0,), 6, 2)
    assert {d for d, _, _ in scores} == {"true, 0 late", "tracker (env)"}
    policy = TurnRatePrior(3, 0.6, 0.5)
    config = evaluation_config(EnvConfig.build(overrides), policy.env_overrides)
    run = rollout(policy, config, 6, 2)
    np.testing.assert_allclose(scores[("tracker (env)", 0.6, 0.5)][0],
                               armse_from_squared(run.squared_position_error), rtol=1e-6)


def test_given_beliefs_lead_rows_of_their_own() -> None:
    """The true turn rate's belief three steps late, handed over as a detector's, gives the rows
    of the true rate known three steps late, prior for prior (not those of its own slots'
    default, the rate known at once)."""
    example = load_example("detector_headroom")
    overrides = {"scenario": "random"}
    truth = example.true_beliefs(overrides, 8, 3)
    straight = np.broadcast_to([1.0, 0.0, 0.0], (8, 3, 3))  # CV's before the first turn rate
    late = np.concatenate([straight, truth[:, :-3]], axis=1)
    scores = example.detector_runs(overrides, (0, 3), 8, 3, beliefs={"given": late})
    for s in example.STAYS[::4]:
        for v in example.SHARES:
            assert scores[("given", s, v)] == scores[("true, 3 late", s, v)]
    assert scores[("given", 1 / 3, 1.0)] != scores[("true, 0 late", 1 / 3, 1.0)]


def test_the_learned_detector_is_repeatable_and_beats_a_constant_belief() -> None:
    example = load_example("detector_headroom")
    overrides = {"scenario": "random"}
    net = example.train_detector(overrides, 200, 100, epochs=4)
    again = example.train_detector(overrides, 200, 100, epochs=4)
    belief = example.learned_beliefs(net, overrides, 40, 0)
    np.testing.assert_array_equal(belief, example.learned_beliefs(again, overrides, 40, 0))
    assert belief.shape == (40, 150, 3)
    np.testing.assert_allclose(belief.sum(axis=-1), 1.0, atol=1e-6)
    # on held-out runs its cross-entropy to the true rate's belief is below that of the
    # training targets' mean belief, the best constant
    target = example.true_beliefs(overrides, 40, 0)
    constant = example.true_beliefs(overrides, 200, 100).reshape(-1, 3).mean(axis=0)
    learned = -np.mean(np.sum(target * np.log(belief), axis=-1))
    mean = -np.mean(np.sum(target * np.log(constant), axis=-1))
    assert learned < 0.9 * mean
