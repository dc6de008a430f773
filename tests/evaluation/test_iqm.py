"""The interquartile mean over training seeds and its stratified bootstrap CI."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from imm_gym.evaluation.metrics import interquartile_mean, stratified_bootstrap_iqm


def test_the_iqm_by_hand() -> None:
    assert interquartile_mean(np.array([1.0, 2.0, 3.0, 4.0, 100.0])) == 3.0  # 2, 3, 4
    assert interquartile_mean(np.array([[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0]])) == 4.5


def test_the_iqm_cuts_whole_scores() -> None:
    """floor(n / 4) whole scores cut at each end (rliable's aggregate_iqm), not the middle half
    with fractional weights: 5 scores keep the middle 3, 3 scores keep all."""
    x = np.array([0.0, 0.0, 10.0, 10.0, 10.0])
    assert interquartile_mean(x) == np.mean([0.0, 10.0, 10.0])  # fractional weights: 7.0
    assert interquartile_mean(np.array([1.0, 2.0, 30.0])) == 11.0
    assert interquartile_mean(np.array([1.0, 2.0])) == 1.5


def test_the_stratified_bootstrap() -> None:
    scores = np.array([[17.8, 17.9, 18.0, 18.1, 25.0], [16.6, 16.7, 16.7, 16.8, 16.9]])
    a = stratified_bootstrap_iqm(scores, n_boot=2000, seed=3)
    assert a == stratified_bootstrap_iqm(scores, n_boot=2000, seed=3)
    assert a["low"] <= a["iqm"] <= a["high"] and a["high"] - a["low"] < 2.0  # the outlier trimmed
    # a single task: seeds resampled within it; identical seeds give a zero-width interval
    same = stratified_bootstrap_iqm(np.full(5, 2.5), n_boot=500)
    assert same == {"iqm": 2.5, "low": 2.5, "high": 2.5}
    # resampling never mixes tasks: each resample keeps every task's own share of scores
    wide = stratified_bootstrap_iqm(np.array([[0.0] * 4, [10.0] * 4]), n_boot=500)
    assert wide["low"] == wide["high"] == 5.0


def test_the_stratified_bootstrap_against_explicit_resampling() -> None:
    """The interval is the 2.5 % and 97.5 % quantiles of the IQMs of resamples drawing each task's
    own seeds with replacement, with the generator seeded ``seed``: redrawn here a resample and a
    task at a time. A 90 % interval (alpha = 1 - level) or one set of picks for every task would
    give other bounds."""
    rng = np.random.default_rng(11)
    scores = rng.normal([[10.0], [20.0], [30.0]], [[1.0], [4.0], [0.5]], (3, 6))
    scores[1, 2] = 60.0  # an outlier the IQM trims
    out = stratified_bootstrap_iqm(scores, n_boot=1500, seed=5)
    assert out["iqm"] == stats.trim_mean(scores.ravel(), 0.25)
    draws = np.random.default_rng(5)
    picks = draws.integers(0, 6, size=(1500, 3, 6))
    boot = []
    for b in range(1500):
        resample = [scores[t, picks[b, t, s]] for t in range(3) for s in range(6)]
        boot.append(stats.trim_mean(resample, 0.25))
    assert out["low"] == pytest.approx(np.quantile(boot, 0.025), rel=0, abs=1e-12)
    assert out["high"] == pytest.approx(np.quantile(boot, 0.975), rel=0, abs=1e-12)
    assert out["high"] - out["low"] > 1.0  # wide enough for the checks above to tell
