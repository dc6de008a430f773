"""The true model of each step (``true_model_index``) by hand: which model of a bank a segment's
motion names, for banks that hold several CT models of one sign, a CA model, or no model of
the motion at all."""

from __future__ import annotations

import math

import numpy as np

from imm_gym import MotionModel, Scenario, Segment, generate_truth
from imm_gym.scenarios.profiles import profile_truth
from imm_gym.scenarios.segments import true_model_index
from imm_gym.tracking.hetero import HeteroBank


def _index(scenario: Scenario, bank) -> list[int]:
    """The true model of every step of ``scenario``, one entry per segment (checked constant)."""
    idx = true_model_index(generate_truth([scenario]), bank)[0]
    out, k = [], 0
    for seg in scenario.segments:
        assert len(set(idx[k:k + seg.duration].tolist())) == 1
        out.append(int(idx[k]))
        k += seg.duration
    return out


def test_a_turn_names_the_ct_model_of_its_sign_nearest_its_rate() -> None:
    """Three CT models turning left (0.5, 2, 6 °/s) and one right (-2 °/s): a left turn names the
    left model whose rate is nearest, by hand |1.0 - 0.5| = 0.5 < |1.0 - 2| = 1 (model 1),
    |2.5 - 2| = 0.5 < |2.5 - 6| (model 2), |5.0 - 6| = 1 < |5.0 - 2| = 3 (model 3); a right turn
    of any rate the one right model (4); straight flight the CV model (0)."""
    bank = (
        MotionModel("cv"),
        MotionModel("ct", 0.5),
        MotionModel("ct", 2.0),
        MotionModel("ct", 6.0),
        MotionModel("ct", -2.0),
    )
    table = (Segment(3), Segment(4, 1.0), Segment(2, 2.5), Segment(5, 5.0), Segment(3, -5.0),
             Segment(2, -0.3), Segment(2))
    scenario = Scenario(table, (0.0, 0.0), (10.0, 0.0))
    assert _index(scenario, bank) == [0, 1, 2, 3, 4, 4, 0]


def test_speeding_up_or_slowing_down_names_the_ca_model() -> None:
    """A tangential acceleration of either sign is the CA model's motion (SPEC: acceleration ->
    the first CA model): +2 m/s² and then -1.5 m/s² (from 20 m/s: 20 + 2*5 - 1.5*4 = 24 m/s,
    never below 0) both name the CA model (2), the straight stretches around them the CV model
    (0), the turn the CT model (1)."""
    bank = (MotionModel("cv"), MotionModel("ct", 3.0), MotionModel("ca", q=(0.1,) * 6))
    table = (Segment(3), Segment(5, accel=2.0), Segment(2), Segment(4, accel=-1.5),
             Segment(3, 3.0), Segment(2))
    scenario = Scenario(table, (0.0, 0.0), (20.0, 0.0))
    assert _index(scenario, bank) == [0, 2, 0, 2, 1, 0]
    states = generate_truth([scenario]).states[0]
    assert math.isclose(math.hypot(*states[14, 2:]), 24.0, rel_tol=1e-12)


def test_a_heterogeneous_bank_without_a_ctra_model_has_no_model_of_an_acceleration() -> None:
    """A heterogeneous NCV/CT bank: straight -> NCV (0), turn -> CT (1), and an acceleration,
    whose model is CTRA, is no model of this bank (-1), not the NCV model of straight flight."""
    bank = HeteroBank(models=("ncv", "ct"))
    table = (Segment(3), Segment(4, accel=1.0), Segment(3, -2.0), Segment(4, accel=-0.5))
    scenario = Scenario(table, (0.0, 0.0), (15.0, 0.0))
    assert _index(scenario, bank) == [0, -1, 1, -1]
    full = HeteroBank(models=("ncv", "ct", "ctra"))
    assert _index(scenario, full) == [0, 2, 1, 2]


def test_a_step_that_turns_and_accelerates_at_once_names_the_acceleration_model() -> None:
    """A profile source (:func:`profile_truth`) turns and speeds up in one step: 3 straight steps,
    4 at +3 °/s and +1 m/s², 3 straight at +0.5 m/s², 2 at -2 °/s. By the docstring's rule
    (acceleration -> the first CA model, turning or not, else the turn's CT model; heterogeneous:
    acceleration -> CTRA) worked per segment: a CV/CT/CT/CA bank names CA (3) for both
    accelerations; without the CA model the turning acceleration is the +3 °/s CT model (1) and
    the straight one no model (-1), not CV; NCV/CT/CTRA names CTRA (2) for both, NCV/CT none."""
    durations = [3, 4, 3, 2]
    omega = np.repeat(np.radians([0.0, 3.0, 0.0, -2.0]), durations)[None]
    accel = np.repeat([0.0, 1.0, 0.5, 0.0], durations)[None]
    truth = profile_truth(omega, accel, np.zeros((1, 2)), np.array([10.0]), np.zeros(1), 1.0)
    np.testing.assert_array_equal(truth.turn_rate, omega)
    np.testing.assert_array_equal(truth.accel, accel)
    cv, ct_left, ct_right = MotionModel("cv"), MotionModel("ct", 3.0), MotionModel("ct", -2.0)
    banks = [
        ((cv, ct_left, ct_right, MotionModel("ca", q=(0.1,) * 6)), [0, 3, 3, 2]),
        ((cv, ct_left, ct_right), [0, 1, -1, 2]),
        (HeteroBank(models=("ncv", "ct", "ctra")), [0, 2, 2, 1]),
        (HeteroBank(models=("ncv", "ct")), [0, -1, -1, 1]),
    ]
    for bank, per_segment in banks:
        expected = np.repeat(per_segment, durations)[None]
        np.testing.assert_array_equal(true_model_index(truth, bank), expected)
