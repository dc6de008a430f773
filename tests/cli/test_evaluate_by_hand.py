"""The evaluation's flow checked by hand: which policy the paired differences are taken against,
on which runs the clairvoyant filter runs, and which seeds the tuners train on."""

from __future__ import annotations

import numpy as np

from imm_gym.cli.evaluate import evaluate


def _armse(err2: np.ndarray) -> float:
    """Position ARMSE by hand: the RMSE over the runs at each step, averaged over the steps."""
    return float(np.mean([np.sqrt(np.mean(err2[:, k])) for k in range(err2.shape[1])]))


def test_the_reference_is_fixed_wherever_it_is_listed() -> None:
    """Without ``--reference`` the differences are against ``fixed`` when it is evaluated, even
    listed second (not the first policy): ``window`` minus ``fixed``, the ARMSEs by hand from
    the roll-outs' squared errors."""
    results, rollouts = evaluate(["window", "fixed"], "paper", 3, 4, clairvoyant=False)
    paired = results["paired"]
    assert paired["reference"] == "fixed" and set(paired["differences"]) == {"window"}
    window = _armse(rollouts["window"].squared_position_error)
    fixed = _armse(rollouts["fixed"].squared_position_error)
    d = paired["differences"]["window"]
    assert abs(d["diff"] - (window - fixed)) < 1e-9
    assert abs(d["relative"] - (window - fixed) / fixed) < 1e-12
