"""The ``turn-rate-prior`` baseline: its search on a fake scorer, its TPM on the environment
against the detector's rows computed by hand, and its search's scores on real runs against
roll-outs of each candidate alone."""

from __future__ import annotations

import numpy as np
import pytest

from baselines import REGISTRY, STAY_GRID, BuildContext, TurnRatePrior
from baselines.turn_rate_prior import SHARE_GRID
from imm_gym import EnvConfig, TrackingCore
from imm_gym.evaluation.metrics import tracking_errors
from imm_gym.evaluation.rollout import evaluation_config, rollout
from imm_gym.sim.detectors import turn_rate_belief
from imm_gym.sim.stay_bank import detector_tpm_rows
from imm_gym.validation import ConfigError

PAPER = EnvConfig(scenario="paper")
RATES = np.radians([0.0, 4.0, -4.0])


def test_the_search_scores_every_stay_per_share_and_holds_the_best() -> None:
    scored: list[tuple[float, float]] = []

    def train_armse_from(policy: TurnRatePrior, tpms: np.ndarray) -> np.ndarray:
        assert policy.stay is None and policy.env_overrides["detector"] == "turn_rate"
        stays = np.diagonal(tpms, axis1=1, axis2=2)[:, 0]
        scored.extend((float(s), policy.share) for s in stays)
        return np.abs(stays - 0.6) + np.abs(policy.share - 0.75)

    def no_single_runs(policy: TurnRatePrior) -> float:
        raise AssertionError("the search scores each share's stays in one roll-out")

    context = BuildContext(PAPER, 1_000_000, 40, no_single_runs, train_armse_from)
    policy, notes = REGISTRY["turn-rate-prior"].build(context)
    assert scored == [(s, v) for v in SHARE_GRID for s in STAY_GRID]  # all >= 1/3 for M = 3
    assert (policy.stay, policy.share) == (0.6, 0.75)
    assert policy.env_overrides == {
        "action_mode": "stay", "stay_base": "tracker", "detector": "turn_rate",
        "detector_share": 0.75, "p_min": 1e-4, "initial_stay": 0.6, "sojourn": None,
    }
    assert (notes["stay"], notes["share"]) == (0.6, 0.75)
    assert notes["search"]["0.6000/0.75"] == pytest.approx(0.0)
    assert len(notes["search"]) == len(STAY_GRID) * len(SHARE_GRID)


def test_its_tpm_is_the_stay_leaned_toward_the_estimated_turn_rate() -> None:
    policy = TurnRatePrior(3, 0.9, 0.5)
    core = TrackingCore(evaluation_config(EnvConfig(scenario="random"), policy.env_overrides), 2)
    core.reset(np.arange(2), [3, 4])
    assert core.stay_bank is None and core.config.shadow == "none"
    obs = core.observe()
    leaned = 0
    for _ in range(100):
        belief = turn_rate_belief(core.turn_rate_estimate, RATES)
        expected = detector_tpm_rows(np.full(2, 0.9), belief, 0.5)
        action, _ = policy.predict(obs)
        result = core.step(action)
        np.testing.assert_allclose(result.info["tpm"], expected, rtol=0, atol=1e-15)
        obs = result.obs
        leaned += int(np.sum(belief[:, 0] < 0.9))
    assert leaned > 10  # the targets turned and the prior followed


def test_the_search_on_real_runs_scores_what_each_candidate_scores_alone() -> None:
    from imm_gym.cli.policies import make_policy

    base = EnvConfig(scenario="random")
    policy, _, notes = make_policy("turn-rate-prior", base, seed=5, train_runs=3)
    assert isinstance(policy, TurnRatePrior) and policy.share == notes["share"]
    first = int(notes["train_seeds"].split("..")[0])
    for stay, share in ((notes["stay"], notes["share"]), (0.95, 1.0)):
        alone = TurnRatePrior(3, stay, share)
        run = rollout(alone, evaluation_config(base, alone.env_overrides), 3, first)
        armse = tracking_errors(run.estimate, run.truth)["armse_pos"]
        assert notes["search"][f"{stay:.4f}/{share:.2f}"] == pytest.approx(armse, rel=1e-9)
    assert notes["search"][f"{notes['stay']:.4f}/{notes['share']:.2f}"] == min(
        notes["search"].values()
    )


def test_the_tables_label_the_stay_and_share_found() -> None:
    from imm_gym.cli.tables import policy_label

    assert policy_label("turn-rate-prior", {"stay": 1 / 3, "share": 0.25}) == (
        "turn-rate-prior (stay 0.333, share 0.25)"
    )
    assert policy_label("best-fixed", {"stay": 0.6}) == "best-fixed (stay 0.6)"
    assert policy_label("best-fixed-rows", {"stays": [0.995, 0.5, 0.5]}) == (
        "best-fixed-rows (stays 0.995/0.5/0.5)"
    )


def test_on_the_random_family_it_is_below_a_stay_per_model(tmp_path) -> None:
    """The README's claim: on the suite's `random` file (100 runs, seed 0) below
    `best-fixed-rows`, the 95 % CI excluding zero, at a mode accuracy above TIP-IMM's."""
    import json
    from pathlib import Path

    from imm_gym.cli.evaluate import main as evaluate_main

    suite = Path(__file__).resolve().parents[2] / "imm_gym" / "scenarios" / "suite"
    result = tmp_path / "res.json"
    argv = ["--policy", "turn-rate-prior", "--policy", "best-fixed-rows", "--policy", "tip-imm"]
    argv += ["--env-config", str(suite / "random.yaml"), "--runs", "100", "--seed", "0"]
    argv += ["--reference", "best-fixed-rows", "--json", str(result), "--quiet"]
    assert evaluate_main([*argv, "--no-clairvoyant"]) == 0
    results = json.loads(result.read_text())
    assert results["paired"]["differences"]["turn-rate-prior"]["high"] < 0.0
    rows = results["policies"]
    assert rows["turn-rate-prior"]["mode_accuracy"] > rows["tip-imm"]["mode_accuracy"]


@pytest.mark.parametrize("stay", [0.1, 1.5, [0.9, 0.2, 0.9], [0.9, 0.9]])
def test_a_stay_outside_one_over_m_to_one_is_refused(stay) -> None:
    """The detector's rows take stays of at least 1/M: a lower stay ran as 1/M."""
    with pytest.raises(ConfigError, match=r"stay(\[1\])? must (be in \[0\.333\d*, 1\.0\]|have 3)"):
        TurnRatePrior(3, stay=stay, share=0.5)
    assert TurnRatePrior(3, stay=1 / 3, share=0.5).stay == 1 / 3
    assert TurnRatePrior(3, stay=[1.0, 0.5, 1 / 3], share=0.5).stay == [1.0, 0.5, 1 / 3]
