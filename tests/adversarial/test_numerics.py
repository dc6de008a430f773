"""Extreme but valid inputs: the numerics hold (finite estimates, positive definite covariances,
bit-for-bit determinism). These kinds passed the adversarial audit of issue 16; the tests keep it
so."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import EnvConfig, Scenario, Segment, Sonar, draw_batch, paper_bank, stay_tpm
from imm_gym.envs.tpm_adapt import TPMAdaptEnv


def _assert_sound(x: np.ndarray, P: np.ndarray) -> None:
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(P))
    np.linalg.cholesky(P)  # positive definite at every step


def test_a_target_ten_thousand_km_away(make_imm) -> None:
    scenario = Scenario(
        segments=(Segment(60), Segment(40, 2.0)), position=(1e7, -3e6), velocity=(-20.0, 5.0)
    )
    batch = draw_batch(scenario, Sonar(), 3, seed=2)
    imm = make_imm(paper_bank(), Sonar())
    result = imm.run(batch.measurements.z[:, 1:], stay_tpm(3, 0.95), batch.x0, batch.P0)
    _assert_sound(result.x, result.P)
    # the range is measured to 50 m: the estimate stays within a few sigma of the true range
    true_range = np.hypot(*np.moveaxis(batch.truth.states[:, 1:, :2], -1, 0))
    est_range = np.hypot(*np.moveaxis(result.x[..., :2], -1, 0))
    assert np.max(np.abs(est_range - true_range)) < 500.0


def test_a_target_crossing_the_bearing_branch_cut(make_imm) -> None:
    """Bearing ±π at the negative x axis: the residual is wrapped, the estimate does not jump."""
    scenario = Scenario(segments=(Segment(100),), position=(-4000.0, 600.0), velocity=(0.0, -12.0))
    batch = draw_batch(scenario, Sonar(), 4, seed=7)
    bearings = batch.measurements.z[:, 1:, 1]
    assert bearings.max() > 3.0 and bearings.min() < -3.0  # it does cross
    imm = make_imm(paper_bank(), Sonar())
    result = imm.run(batch.measurements.z[:, 1:], stay_tpm(3, 0.95), batch.x0, batch.P0)
    _assert_sound(result.x, result.P)
    error = np.linalg.norm(result.x[..., :2] - batch.truth.states[:, 1:, :2], axis=-1)
    assert error.max() < 150.0


def test_ten_thousand_steps(make_imm) -> None:
    scenario = Scenario(
        segments=(Segment(5000), Segment(5000, 0.5)), position=(3000.0, 2000.0), velocity=(1.0, 0.5)
    )
    batch = draw_batch(scenario, Sonar(), 1, seed=1)
    imm = make_imm(paper_bank(), Sonar())
    result = imm.run(batch.measurements.z[0, 1:], stay_tpm(3, 0.99), batch.x0[0], batch.P0[0])
    assert result.x.shape == (10_000, 4)
    _assert_sound(result.x, result.P)
    assert np.allclose(result.mode_probs.sum(-1), 1.0)


def test_the_same_seed_gives_the_same_episode_bit_for_bit() -> None:
    def episode() -> list[np.ndarray]:
        env = TPMAdaptEnv(EnvConfig(parallel=True, obs_features=("tpm", "prob_ema")))
        obs, _ = env.reset(seed=123)
        out = [obs]
        rng = np.random.default_rng(0)
        for _ in range(150):
            obs, reward, *_ = env.step(rng.uniform(-1, 1, 9).astype(np.float32))
            out += [obs, np.array(reward)]
        return out

    for a, b in zip(episode(), episode(), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("magnitude", [1e3, 1e30, np.finfo(np.float32).max])
def test_huge_actions_are_clipped(magnitude: float) -> None:
    env = TPMAdaptEnv(EnvConfig(scenario="paper", obs_features=("tpm",)))
    env.reset(seed=0)
    signs = np.tile([1.0, -1.0, 1.0], 3).astype(np.float32)
    for _ in range(30):
        obs, reward, *_ = env.step(signs * np.float32(magnitude))
        assert np.all(np.isfinite(obs)) and np.isfinite(reward)
    tpm = env.core.tpm[0]
    np.testing.assert_allclose(tpm.sum(-1), 1.0)
    assert tpm.min() >= env.config.p_min - 1e-15


def test_a_lost_track_at_the_largest_distance_keeps_its_held_error() -> None:
    """A diverged run is held at the truth plus the cap (``divergence_error``); at the largest
    distance a configuration may give (MAX_DISTANCE: positions resolve 1e-7 m there) the error
    taken back from the two positions is still the cap, so a lost track scores
    ``divergence_error``, not the 0 m a cap rounded away would give."""
    from imm_gym.cli.comparison import evaluate
    from imm_gym.validation import MAX_DISTANCE

    scenario = {"segments": [{"duration": 5}], "position": [MAX_DISTANCE, -MAX_DISTANCE],
                "velocity": [-20.0, 5.0]}
    results, _ = evaluate(["fixed"], scenario, 3, 0, clairvoyant=False,
                          env_config={"divergence_error": 1.0})
    fixed = results["policies"]["fixed"]
    assert fixed["diverged"] == 3
    assert fixed["armse_pos"] == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ({"family": {"speed": [1.0, 1e200]}}, r"family\.speed\[1\] must be in \[1\.0, 100000\.0\]"),
        ({"family": {"range_m": [3e3, 1e308]}},
         r"family\.range_m\[1\] must be in \[3000\.0, 1000000000\.0\]"),
        ({"family": {"range_m": [2e9, 3e9]}},
         r"family\.range_m\[0\] must be in \[0\.0, 1000000000\.0\]"),
        ({"sensor": {"position": [0.0, -1e10]}},
         r"sensor\.position must be in \[-1000000000\.0, 1000000000\.0\]"),
        ({"sensor": {"sigma_r": 1e12}}, r"sensor\.sigma_r must be in \(0\.0, 1000000000\.0\]"),
        ({"scenario": {"segments": [{"duration": 5}], "position": [1e154, 0.0]}},
         r"scenario\.position must be in \[-1000000000\.0, 1000000000\.0\]"),
        ({"scenario": {"segments": [{"duration": 5}], "velocity": [8e4, 8e4]}},
         r"scenario\.velocity: the speed \|v\| must be in \[0, 100000\.0\] m/s, got 113137"),
        ({"scenario": {"segments": [{"duration": 10, "accel": 1e4}], "velocity": [300.0, 0.0]}},
         r"scenario\.segments\[0\]\.accel: 10000\.0 m/s² for 10 steps of 1\.0 s drives the speed "
         r"from 300 m/s above 100000\.0 m/s \(100300 m/s; accel <= 9970\)"),
        ({"scenario": "random", "vary": {"speed": [5.0, 1e6]}},
         r"vary\.speed\[1\] must be in \[5\.0, 100000\.0\]"),
    ],
)
def test_a_place_or_speed_beyond_any_target_is_refused_by_name(config, message) -> None:
    """Distances beyond MAX_DISTANCE (1e9 m) and speeds beyond MAX_SPEED (1e5 m/s) are refused
    as the configuration is built, naming the field and the range: a target at 1e154 m used to
    stop an evaluation seconds in with 'z0 and velocity must be finite', and one at 1e200 m/s to
    score every lost run 0 m."""
    from imm_gym.validation import ConfigError

    with pytest.raises(ConfigError, match=message):
        EnvConfig.build(config)
