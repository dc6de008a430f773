"""imm_gym.run_policy at its edges, each against a value worked by hand or another input that
means the same."""

from __future__ import annotations

import math

import numpy as np
import pytest

from baselines import make_baseline
from imm_gym import ConfigError, EnvConfig
from imm_gym.sim.replay import run_policy

#: A target straight ahead on the x axis, 1000 m out (bearing 0), closing at 10 m/s.
Z = np.array([[1000.0 - 10.0 * k, 0.0] for k in range(6)])


def test_the_start_without_a_velocity_by_hand() -> None:
    """From z0 = (1000 m, 0 rad): x0 = (1000, 0, 0, 0); P0's position block diag(σ_r²,
    (r σ_θ)²) = diag(50², (1000 · 0.05° in rad)²), its velocity block 30² I (a velocity
    unknown: 30 m/s, as the command line's help says); given a velocity, its block is
    velocity_std² = 5² I."""
    out = run_policy(Z, make_baseline("fixed"))
    np.testing.assert_array_equal(out.x0, [[1000.0, 0.0, 0.0, 0.0]])
    across = 1000.0 * math.radians(0.05)
    expected = np.diag([50.0**2, across**2, 30.0**2, 30.0**2])
    np.testing.assert_allclose(out.P0[0], expected, rtol=1e-12, atol=1e-12)
    given = run_policy(Z, make_baseline("fixed"), velocity=[-10.0, 0.0])
    np.testing.assert_array_equal(given.x0, [[1000.0, 0.0, -10.0, 0.0]])
    np.testing.assert_allclose(given.P0[0], np.diag([50.0**2, across**2, 25.0, 25.0]),
                               rtol=1e-12, atol=1e-12)


def test_a_track_diverges_above_the_cap_not_at_it() -> None:
    """Ten missed detections after the start: the position variance P_xx + P_yy grows each
    step. A cap equal to step 4's is not exceeded there (diverged from step 5); a cap a hair
    below it is (diverged from step 4) though P_xx alone stays below it; the estimates do not
    depend on the cap."""
    z = np.concatenate([Z[:1], np.full((10, 2), np.nan)])
    free = run_policy(z, make_baseline("fixed"))
    P = free.covariance[0]
    var = P[:, 0, 0] + P[:, 1, 1]
    assert np.all(np.diff(var) > 0) and not free.diverged[0]
    assert P[4, 0, 0] < 0.99 * var[4] and var[3] < 0.99 * var[4]
    for cap, at in ((var[4], 5), (var[4] * (1 - 1e-9), 4)):
        out = run_policy(z, make_baseline("fixed"), EnvConfig(divergence_cov=float(cap)))
        assert out.diverged_at.tolist() == [at], cap
        assert out.diverged[0]
        np.testing.assert_array_equal(out.estimate, free.estimate)


def test_one_row_is_no_track() -> None:
    """A sequence of one row is the track's start without a step: refused (K >= 1)."""
    with pytest.raises(ConfigError, match=r"z must be \(N, K\+1, 2\) with K >= 1"):
        run_policy(Z[:1], make_baseline("fixed"))
    with pytest.raises(ConfigError, match=r"with K >= 1"):
        run_policy(np.stack([Z[:1], Z[:1]]), make_baseline("fixed"))


def test_every_sequence_starts_with_a_detection() -> None:
    """Two sequences, the second's first row a missed detection: refused, though the first's
    is a detection."""
    z = np.stack([Z, Z])
    z[1, 0] = np.nan
    with pytest.raises(ConfigError, match=r"z\[:, 0\] initiates the track"):
        run_policy(z, make_baseline("fixed"))


def test_flags_as_floats_zero_and_one_are_taken() -> None:
    """detected as 1.0/0.0 floats is the same missed detection as booleans."""
    flags = np.array([1.0, 1.0, 0.0, 1.0, 1.0, 1.0])
    as_floats = run_policy(Z, make_baseline("fixed"), detected=flags)
    as_bools = run_policy(Z, make_baseline("fixed"), detected=flags.astype(bool))
    np.testing.assert_array_equal(as_floats.estimate, as_bools.estimate)
    missed = Z.copy()
    missed[2] = np.nan
    np.testing.assert_array_equal(run_policy(missed, make_baseline("fixed")).estimate,
                                  as_floats.estimate)


class _TimeWatcher:
    """The fixed TPM observing the time feature k / K: it keeps each observation it is given."""

    def __init__(self) -> None:
        self.fixed = make_baseline("fixed")
        self.env_overrides = {**self.fixed.env_overrides, "obs_features": ("time",)}
        self.seen: list[np.ndarray] = []

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        self.seen.append(obs.copy())
        return self.fixed.predict(obs, state, episode_start, deterministic)


def test_the_time_feature_counts_the_steps() -> None:
    """A policy observing the time feature (the observation's last entry) of an 80-step
    horizon sees 0, 1/80, ..., 4/80 before the five steps of six measurements."""
    policy = _TimeWatcher()
    run_policy(Z, policy, EnvConfig(family={"horizon": 80}))
    seen = np.array([obs[0, -1] for obs in policy.seen])
    np.testing.assert_allclose(seen, np.arange(5) / 80.0, rtol=1e-6, atol=0.0)
