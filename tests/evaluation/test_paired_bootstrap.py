"""Tests of imm_gym.evaluation.rollout.paired_bootstrap against intervals worked by hand."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym.evaluation.rollout import paired_bootstrap


def test_the_paired_ci_is_the_2_5_and_97_5_percentiles_of_the_resampled_differences() -> None:
    """Three runs of one step, squared errors (100, 400, 900) m² for A and 100 m² each for B: a
    resample of the runs (the same for both) gives sqrt(mean of A's) - 10 m. The lowest value,
    0 m (run 0 drawn three times), and the highest, 20 m (run 2 three times), each have
    probability 1/27 = 3.7 % > 2.5 %, so the 95 % percentile interval is exactly [0, 20] m; the
    next values inward, (2 x run 0, run 1) and (run 1, 2 x run 2), are 4.14 m and 17.8 m. The
    difference itself is sqrt(1400 / 3) - 10 = 11.60 m, relative to B's ARMSE of 10 m."""
    a = np.array([[100.0], [400.0], [900.0]])
    b = np.full((3, 1), 100.0)
    d = paired_bootstrap(a, b)
    assert d["low"] == 0.0 and d["high"] == 20.0
    assert abs(d["diff"] - (np.sqrt(1400.0 / 3.0) - 10.0)) < 1e-12
    assert abs(d["relative"] - d["diff"] / 10.0) < 1e-12
    # at the 80 % level the tails (10 %) pass the extreme atoms: the interval is inside [0, 20]
    d80 = paired_bootstrap(a, b, level=0.8)
    assert 0.0 < d80["low"] < d80["high"] < 20.0


def test_errors_of_other_runs_or_steps_are_refused() -> None:
    """Paired errors are of the same runs and steps: (3, 4) against (3, 5) squared errors (whose
    resampled means would still subtract, step counts apart) is refused."""
    rng = np.random.default_rng(2)
    a, b = rng.gamma(2.0, 50.0, (3, 4)), rng.gamma(2.0, 50.0, (3, 5))
    with pytest.raises(ValueError, match=r"same shape: \(3, 4\), \(3, 5\)"):
        paired_bootstrap(a, b)
