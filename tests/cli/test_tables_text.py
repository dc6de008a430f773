"""The tables' titles say what is computed."""

from __future__ import annotations

import numpy as np

from imm_gym.cli.evaluate import evaluate
from imm_gym.cli.tables import render_tables
from imm_gym.evaluation.metrics import maneuver_starts


def test_the_maneuver_response_title_counts_turn_ends_too(capsys) -> None:
    """The maneuver response's windows start at every change of the true model, a turn's end as
    its start (:func:`maneuver_starts`): the title says so, not "after each maneuver starts"."""
    true_model = np.array([[0, 0, 1, 1, 0, 0]])
    assert np.flatnonzero(maneuver_starts(true_model)[0]).tolist() == [2, 4]  # start and end
    results, _ = evaluate(["fixed"], "paper", 2, 0, clairvoyant=False)
    render_tables(results)
    printed = " ".join(capsys.readouterr().out.split())
    assert "from each change of the true model (a maneuver's start or end)" in printed
    assert "after each maneuver starts" not in printed
