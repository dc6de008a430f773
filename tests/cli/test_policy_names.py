"""``imm_gym.cli.policies``: what a ``--policy`` name or path becomes, the cores a tuned rule
trains on, and the notes and refusals of a trained agent evaluated on a tracker."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from gymnasium import spaces

from agents import PRETRAINED
from baselines import REGISTRY, BuildContext, register
from baselines.fixed import FixedTPM
from imm_gym import EnvConfig
from imm_gym.cli.policies import UnreadableTracker, agent_overrides, make_policy
from imm_gym.evaluation.rollout import evaluation_config, rollout, score
from imm_gym.sim.config_file import tracker_of
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.tracking.tpm import stay_tpm
from imm_gym.validation import ConfigError

PAPER = EnvConfig(scenario="paper")


def _actions(policy: Any, seed: int) -> np.ndarray:
    obs = np.random.default_rng(seed).standard_normal((3, policy.obs_size)).astype(np.float32)
    action, _ = policy.predict(obs, None, np.ones(3, dtype=bool), True)
    return np.asarray(action)


@pytest.mark.parametrize(
    ("directory", "file"), [(PRETRAINED, "ensemble.json"), (PRETRAINED / "seed_0", "agent.json")]
)
def test_a_policy_file_is_its_directory_s_policy(directory: Path, file: str) -> None:
    """``--policy DIR/agent.json`` (or ``ensemble.json``) loads the policy of ``DIR``, as the
    loader reads a policy's file; the notes name the path as given."""
    by_dir, _, dir_notes = make_policy(str(directory), PAPER, 0)
    by_file, overrides, notes = make_policy(str(directory / file), PAPER, 0)
    assert dir_notes == {"path": str(directory)} and notes == {"path": str(directory / file)}
    assert overrides == by_dir.env_overrides
    np.testing.assert_array_equal(_actions(by_file, 3), _actions(by_dir, 3))


def test_a_shipped_name_is_its_directory_named_in_the_notes() -> None:
    _, _, notes = make_policy("pretrained", PAPER, 0)
    assert notes == {"path": str(PRETRAINED)}


def test_an_unknown_name_is_refused_naming_every_policy_there_is(tmp_path: Path) -> None:
    """A name that is no rule, no shipped agent and no path is refused with the names a user
    can give instead: every registered rule, the shipped agents and a directory."""
    for name in ("nope", str(tmp_path / "no_such_run")):
        with pytest.raises(ConfigError, match=f"unknown policy {name!r}") as err:
            make_policy(name, PAPER, 0)
        message = str(err.value)
        for known in [*REGISTRY, "'pretrained'", "'pretrained-per-model'"]:
            assert known in message
        assert message.endswith("or a trained agent's directory")


def test_a_tuned_rule_scores_on_the_training_runs_and_the_cores_it_is_given() -> None:
    """A registry entry's ``train_armse`` and ``train_armse_from`` are the rollouts of the
    training runs (seeds ``seed + 1_000_000 + r``) on the cores ``make_core`` builds."""
    built: list[int] = []

    def make_core(config: EnvConfig, n_envs: int) -> TrackingCore:
        built.append(n_envs)
        return TrackingCore(config, n_envs)

    got: dict[str, Any] = {}
    stays = (0.9, 0.995)

    @register("probe", help="test only: scores two fixed TPMs on the training runs")
    def build(context: BuildContext) -> tuple[FixedTPM, dict[str, object]]:
        got["one"] = context.train_armse(FixedTPM(3, 0.8))
        tpms = np.stack([stay_tpm(3, s) for s in stays])
        got["from"] = context.train_armse_from(FixedTPM(3), tpms)
        return FixedTPM(3), {}

    try:
        make_policy("probe", PAPER, 5, train_runs=3, make_core=make_core)
    finally:
        REGISTRY.unregister("probe")
    assert built == [3, 3 * len(stays)]

    def alone(stay: float) -> float:
        policy = FixedTPM(3, stay)
        cfg = evaluation_config(PAPER, policy.env_overrides)
        return score(rollout(policy, cfg, 3, 1_000_005))["armse_pos"]

    assert got["one"] == pytest.approx(alone(0.8), rel=1e-9)
    np.testing.assert_allclose(got["from"], [alone(s) for s in stays], rtol=1e-9)


@pytest.mark.parametrize(
    ("recorded", "writes", "takes"),
    [({}, 6, 9), ({}, 12, 9), ({"action_mode": "stay"}, 9, 3), ({"action_mode": "stay"}, 2, 3)],
)
def test_an_agent_writing_actions_of_another_size_is_refused(
    recorded: dict[str, Any], writes: int, takes: int
) -> None:
    """A bank of 3 models takes 3 × 3 entries (``scale``, the default) or 3 (a stay mode):
    an agent's network writing more or fewer is refused, before any roll-out."""
    space = spaces.Box(-1.0, 1.0, (writes,), np.float32)
    agent = SimpleNamespace(model=SimpleNamespace(action_space=space))
    with pytest.raises(UnreadableTracker, match=f"writes actions of {writes} entries") as err:
        agent_overrides(agent, recorded, PAPER)
    reason = f"writes {writes} action entries, the tracker takes {takes} (3 models)"
    assert err.value.reason == reason
    right = SimpleNamespace(model=SimpleNamespace(action_space=spaces.Box(-1.0, 1.0, (takes,))))
    assert agent_overrides(right, recorded, PAPER)[0] == recorded


def test_an_agent_of_one_tracker_lists_no_trackers_trained_across() -> None:
    _, notes = agent_overrides(SimpleNamespace(trained_across=()), {}, PAPER)
    assert "trained_across" not in notes and "models_differ" not in notes
    assert notes["trained_on"] == notes["evaluated_on"] == tracker_of({})


#: Three tracker fields off the evaluated paper tracker (sensor, initial_stay, sojourn).
FAR = {"sensor": {"sigma_r": 20.0}, "initial_stay": 0.9, "sojourn": (60.0, 20.0, 20.0)}
HETERO = tracker_of(BANK_PRESETS["hetero"])  # two off (bank, filter): the closer one


def test_the_models_that_differ_are_the_closest_trained_tracker_s() -> None:
    """An agent trained across the paper bank (three other fields) and the heterogeneous one
    (two), evaluated on the paper bank in reverse: the notes compare the evaluated models with
    the closest trained tracker's (the heterogeneous bank's), not the first one's."""
    reverse = PAPER.replace(bank=PAPER.bank[::-1])
    agent = SimpleNamespace(trained_across=(HETERO,))
    _, notes = agent_overrides(agent, FAR, reverse)
    assert notes["trained_on"] == HETERO and notes["tracker_differs"] == ["bank", "filter"]
    assert notes["models_differ"] == {
        "trained": ["NCV", "CT", "CTRA"], "evaluated": ["CT(−)", "CT(+)", "CV"]
    }
    assert notes["trained_across"] == [tracker_of(FAR), HETERO]


def test_models_of_any_trained_tracker_do_not_differ() -> None:
    """The evaluated bank's models are those of one tracker trained on (the paper bank), though
    another (the heterogeneous one) is closer: nothing is said to differ."""
    _, notes = agent_overrides(SimpleNamespace(trained_across=(HETERO,)), FAR, PAPER)
    assert notes["trained_on"] == HETERO and "models_differ" not in notes
