"""Tests of imm_gym.evaluation.clairvoyant: where the clairvoyant filter runs, and when its errors
are a bound or only a reference."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import MotionModel, Scenario, Segment, Sonar, generate_truth, paper_bank
from imm_gym.evaluation.clairvoyant import (
    BOUNDED_KEYS,
    clairvoyant_filter,
    clairvoyant_role,
    unsupported,
)
from imm_gym.tracking.hetero import SONAR_HETERO_BANK, HeteroBank
from imm_gym.validation import ConfigError


def _errors(value: float) -> dict[str, float]:
    return dict.fromkeys(BOUNDED_KEYS, value)


def test_a_bound_while_no_policy_beats_it() -> None:
    policies = {"fixed": {**_errors(18.0), "mode_accuracy": 0.6}, "tip-imm": _errors(15.0)}
    role = clairvoyant_role(_errors(15.0), policies)  # a tie does not beat it
    assert role["role"] == "bound" and role["beaten_by"] == {}
    assert role["note"].startswith("bound: ")


def test_a_reference_once_a_policy_beats_it_on_any_error() -> None:
    lucky = {**_errors(16.0), "armse_vel_y": 0.5}
    policies = {"fixed": _errors(18.0), "lucky": lucky, "window": _errors(14.0)}
    role = clairvoyant_role(_errors(15.0), policies)
    assert role["role"] == "reference"
    assert role["note"] == "reference: beaten by lucky, window"
    assert role["beaten_by"] == {"lucky": ["armse_vel_y"], "window": list(BOUNDED_KEYS)}


def _scenario(*segments: Segment) -> Scenario:
    return Scenario(segments, position=(3000.0, 4000.0), velocity=(10.0, 5.0))


def test_unsupported_names_acceleration_and_missing_models() -> None:
    straight_turn = generate_truth([_scenario(Segment(5), Segment(5, 2.0), Segment(5, -1.0))])
    assert unsupported(straight_turn, paper_bank()) is None
    accel = _scenario(Segment(5), Segment(5, accel=0.5))
    truth = generate_truth([_scenario(Segment(10)), accel, accel])
    reason = unsupported(truth, paper_bank())
    assert reason is not None and "2 of 3 runs have acceleration segments" in reason
    z = np.zeros((3, 10, 2))
    x0, P0 = truth.states[:, 0], np.broadcast_to(np.eye(4), (3, 4, 4))
    with pytest.raises(ConfigError, match="2 of 3 runs have acceleration"):
        clairvoyant_filter(truth, z, Sonar(), paper_bank(), x0, P0)
    no_right = (MotionModel("cv"), MotionModel("ct", 4.0))
    assert "right-turn CT" in str(unsupported(straight_turn, no_right))
    hetero = HeteroBank(**SONAR_HETERO_BANK)
    assert "NCV/CT/CTRA" in str(unsupported(straight_turn, hetero))
