"""Conditions drawn per episode (EnvConfig.vary): checks, draws, and each slot's tracker equal to
an independent numpy IMM built for that slot's sampling period and sensor."""

from __future__ import annotations

import math
from types import SimpleNamespace

import gymnasium
import numpy as np
import pytest

import imm_gym  # noqa: F401  (registers the envs)
from imm_gym import paper_bank
from imm_gym.scenarios.segments import RandomFamily
from imm_gym.seeding import streams
from imm_gym.sim.conditions import Variation, bank_noise, draw_conditions, maneuver_factors
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.sim.presets import CONTINUOUS_BANK
from imm_gym.tracking.imm import IMM
from imm_gym.tracking.sensors import PositionSensor, Sonar
from imm_gym.tracking.tpm import stay_tpm
from imm_gym.validation import ConfigError

BROAD = {
    "T": (0.5, 5.0),
    "sigma_r": (10.0, 100.0),
    "sigma_theta_deg": (0.02, 0.5),
    "outlier_prob": (0.0, 0.05),
    "detection_prob": (0.8, 1.0),
    "speed": (5.0, 300.0),
    "q_scale": (0.3, 30.0),
}


def broad_config(**changes: object) -> EnvConfig:
    return EnvConfig(bank=CONTINUOUS_BANK, vary=BROAD, **changes)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"vary": {"T": (0.5, 5.0)}}, "bank[0] has per-step noise"),
        ({"vary": {"T": (0.5, 5.0)}, "bank": CONTINUOUS_BANK, "scenario": "paper"},
         "vary.T needs scenario 'random'"),
        ({"vary": {"sigma_pos": (1.0, 5.0)}}, "vary.sigma_pos: the sensor Sonar has no field"),
        ({"vary": {"sigma_r": (50.0, 10.0)}}, "vary.sigma_r[1] must be in [50.0"),
        ({"vary": {"sigma_r": (0.0, 10.0)}}, "vary.sigma_r[0] must be in (0.0"),
        ({"vary": {"detection_prob": (0.0, 1.0)}}, "vary.detection_prob[0] must be in (0.0"),
        ({"vary": {"outlier_prob": (0.0, 1.5)}}, "vary.outlier_prob[1] must be in [0.0, 1.0]"),
        ({"vary": {"sigma_r": "10-50"}}, "vary.sigma_r (low, high)"),
        ({"vary": {"sigmar": (1.0, 2.0)}}, "unknown key(s) ['sigmar']"),
        ({"vary": {"share": 0.5}}, "vary.share (0.5) is the share of episodes that draw"),
        ({"vary": {"sigma_r": (10.0, 50.0)}, "engine": "numpy"}, "vary needs engine"),
        ({"vary": {"speed": (5.0, 50.0)}, "scenario": "atc"}, "vary.speed needs scenario"),
        ({"vary": {"q_scale": (0.0, 5.0)}}, "vary.q_scale[0] must be in (0.0"),
        ({"vary": {"q_maneuver": (0.0, 5.0)}}, "vary.q_maneuver[0] must be in (0.0"),
        ({"vary": {"q_maneuver": (5.0, 1.0)}}, "vary.q_maneuver[1] must be in [5.0"),
        ({"vary": {"sigma_r": (10.0, 50.0)}, "bank": "hetero"},
         "vary (sigma_r) needs a linear bank"),
        ({"vary": {"velocity_std": (5.0, 20.0)}, "bank": "hetero"},
         "vary (velocity_std) needs a linear bank"),
    ],
)
def test_a_variation_that_cannot_apply_is_a_config_error(changes, message) -> None:
    if changes.get("bank") == "hetero":
        from imm_gym.sim.presets import BANK_PRESETS

        changes = {**changes, **BANK_PRESETS["hetero"]}
    with pytest.raises(ConfigError) as err:
        EnvConfig(**changes)
    assert message in str(err.value)


def test_nothing_varies_by_default_and_the_draws_are_unchanged() -> None:
    assert not EnvConfig().vary.active
    plain = draw_batch(RandomFamily(), Sonar(), 6, 11)
    none = draw_batch(RandomFamily(), Sonar(), 6, 11, variation=Variation())
    np.testing.assert_array_equal(plain.measurements.z, none.measurements.z)
    assert none.conditions is None


def test_conditions_are_a_function_of_the_seed_and_lie_in_their_ranges() -> None:
    variation = Variation(**BROAD)
    rngs = [streams(s)[0] for s in range(2000)]
    c = draw_conditions(variation, 1.0, Sonar(), rngs)
    again = draw_conditions(variation, 1.0, Sonar(), [streams(s)[0] for s in range(2000)])
    np.testing.assert_array_equal(c.T, again.T)
    assert np.all((c.T >= 0.5) & (c.T <= 5.0))
    sigma_r = np.array([s.sigma_r for s in c.sensors])
    p_d = np.array([s.detection_prob for s in c.sensors])
    assert np.all((sigma_r >= 10.0) & (sigma_r <= 100.0)) and np.all((p_d >= 0.8) & (p_d <= 1.0))
    # log-uniform scales: half below the geometric mean; uniform probabilities: half below the mean
    assert abs(np.mean(c.T < math.sqrt(0.5 * 5.0)) - 0.5) < 0.04
    assert abs(np.mean(sigma_r < math.sqrt(10.0 * 100.0)) - 0.5) < 0.04
    assert abs(np.mean(p_d < 0.9) - 0.5) < 0.04
    np.testing.assert_allclose(c.R[:, 0, 0], sigma_r**2)


@pytest.mark.parametrize("name", ["velocity_std", "sigma_theta_deg", "q_scale", "outlier_prob"])
def test_a_pinned_or_hair_wide_range_draws_inside_its_ends(name: str) -> None:
    # exp(uniform(log lo, log hi)) rounds one step past an end: velocity_std (1e6, 1e6) drew
    # 999999.9999999995 unclipped
    ends = {"velocity_std": 1e6, "sigma_theta_deg": 180.0, "q_scale": 3.7, "outlier_prob": 0.3}
    lo = ends[name]
    at_limit = name in ("velocity_std", "sigma_theta_deg")  # the end is the condition's limit
    for hi in (lo, float(np.nextafter(lo, 0.0 if at_limit else math.inf))):
        low, high = min(lo, hi), max(lo, hi)
        drawn = [Variation(**{name: (low, high)}).draw(np.random.default_rng(s))[name]
                 for s in range(200)]
        assert all(low <= v <= high for v in drawn)
    pinned = Variation(**{name: (lo, lo)}).draw(np.random.default_rng(0))[name]
    assert pinned == lo


def test_a_position_sensor_varies_its_own_noise() -> None:
    variation = Variation(sigma_pos=(5.0, 50.0))
    variation.check(PositionSensor())
    batch = draw_batch(RandomFamily(), PositionSensor(), 50, 0, variation=variation)
    sigmas = np.array([s.sigma_pos for s in batch.conditions.sensors])
    assert np.all((sigmas >= 5.0) & (sigmas <= 50.0)) and np.ptp(sigmas) > 10.0


def test_each_run_moves_at_its_own_sampling_period() -> None:
    config = broad_config()
    batch = draw_batch(config.source, config.sensor, 8, 5, variation=config.vary)
    truth = batch.truth
    assert truth.T.shape == (8,) and np.ptp(truth.T) > 0.5
    np.testing.assert_allclose(
        np.linalg.norm(truth.states[:, 0, 2:], axis=-1), batch.conditions.speed, rtol=1e-12
    )
    straight = truth.turn_rate == 0.0
    step = np.linalg.norm(np.diff(truth.states[:, :, :2], axis=1), axis=-1)
    speed = np.linalg.norm(truth.states[:, :-1, 2:], axis=-1)
    np.testing.assert_allclose(step[straight], (speed * truth.T[:, None])[straight], rtol=1e-9)


def test_each_slot_tracks_as_an_imm_built_for_its_own_conditions() -> None:
    """Slot i of the compiled core = the numpy reference IMM at slot i's T and sensor, on the
    slot's measurements (zero actions in scale mode keep the initial TPM)."""
    N, K = 5, 60
    config = broad_config(shadow="none", reward="error", p_min=1e-4)
    core = TrackingCore(config, N)
    core.reset(np.arange(N), list(range(100, 100 + N)))
    assert np.ptp(core.sampling_period) > 0.5
    x0 = core.state_a.x[:, 0].copy()
    P0 = core.state_a.P[:, 0].copy()
    estimates = []
    for _ in range(K):
        result = core.step(np.zeros((N, 9)))
        estimates.append(result.info["estimate"])
    estimates = np.stack(estimates, axis=1)
    R = core.kernel_args[2]
    # the slots' draws, again: their scenario streams' first draws (Variation.draw)
    conditions = draw_conditions(
        config.vary, 1.0, config.sensor, [streams(s)[0] for s in range(100, 100 + N)]
    )
    assert np.ptp(conditions.q_scale) > 1.0
    for i in range(N):
        T = float(core.sampling_period[i])
        assert T == conditions.T[i]
        sensor = Sonar(
            sigma_r=math.sqrt(R[i, 0, 0]), sigma_theta_deg=math.degrees(math.sqrt(R[i, 1, 1]))
        )
        bank = [m.scaled(conditions.q_scale[i]) for m in CONTINUOUS_BANK]
        reference = IMM(bank, sensor, T=T, engine="numpy")
        run = reference.run(
            core.z[i, 1 : K + 1], stay_tpm(3, config.initial_stay), x0[i], P0[i],
            detected=core.detected[i, 1 : K + 1],
        )
        np.testing.assert_allclose(estimates[i], run.x, rtol=1e-9, atol=1e-9)


def test_a_maneuver_noise_factor_scales_every_model_but_the_cv_one() -> None:
    """``vary.q_maneuver``: slot i = the numpy reference IMM whose CV model carries slot i's
    ``q_scale`` and whose CT models carry ``q_scale * q_maneuver``; the other conditions are
    those drawn without it, bit for bit (it is drawn after them)."""
    N, K = 4, 40
    config = EnvConfig(
        bank=CONTINUOUS_BANK, vary={**BROAD, "q_maneuver": (0.5, 50.0)}, shadow="none",
        reward="error", p_min=1e-4,
    )
    core = TrackingCore(config, N)
    seeds = list(range(200, 200 + N))
    core.reset(np.arange(N), seeds)
    x0, P0 = core.state_a.x[:, 0].copy(), core.state_a.P[:, 0].copy()
    estimates = np.stack(
        [core.step(np.zeros((N, 9))).info["estimate"] for _ in range(K)], axis=1
    )
    drawn = draw_conditions(config.vary, 1.0, config.sensor, [streams(s)[0] for s in seeds])
    plain = draw_conditions(
        Variation(**BROAD), 1.0, config.sensor, [streams(s)[0] for s in seeds]
    )
    np.testing.assert_array_equal(drawn.T, plain.T)
    np.testing.assert_array_equal(drawn.q_scale, plain.q_scale)
    assert np.all((drawn.q_maneuver >= 0.5) & (drawn.q_maneuver <= 50.0))
    assert np.ptp(drawn.q_maneuver) > 1.0
    for i in range(N):
        cv, *ct = CONTINUOUS_BANK
        s, a = drawn.q_scale[i], drawn.q_maneuver[i]
        bank = [cv.scaled(s), *(m.scaled(s * a) for m in ct)]
        reference = IMM(bank, drawn.sensors[i], T=float(drawn.T[i]), engine="numpy")
        run = reference.run(
            core.z[i, 1 : K + 1], stay_tpm(3, config.initial_stay), x0[i], P0[i],
            detected=core.detected[i, 1 : K + 1],
        )
        np.testing.assert_allclose(estimates[i], run.x, rtol=1e-9, atol=1e-9)


def test_the_maneuver_factor_follows_the_models_kind_not_their_place() -> None:
    """A bank listing CT(+), CV, CT(-) (the same tracker as the suite's order) scales the CT
    models' noise by ``q_maneuver``, not the first model's."""
    cv, ct_plus, ct_minus = CONTINUOUS_BANK
    T, s, a = np.array([1.0]), np.array([2.0]), np.array([4.0])
    Q = bank_noise((ct_plus, cv, ct_minus), T, s, a)[0]
    n = Q.shape[-1]
    expected = [ct_plus.scaled(8.0), cv.scaled(2.0), ct_minus.scaled(8.0)]
    for j, m in enumerate(expected):
        np.testing.assert_array_equal(Q[j], m.noise_covariance(n, 1.0))


def test_a_maneuver_factor_without_a_cv_model_is_refused() -> None:
    _, ct_plus, ct_minus = CONTINUOUS_BANK
    with pytest.raises(ConfigError, match="q_maneuver needs a bank with a CV model"):
        EnvConfig(bank=(ct_plus, ct_minus), vary={"q_maneuver": (0.5, 5.0)})


def test_the_heading_rate_feature_uses_each_slot_period() -> None:
    config = broad_config(obs_features=("turn_rate",))
    env = gymnasium.make_vec(
        "imm_gym/TPMAdapt-v0", num_envs=3, vectorization_mode="vector_entry_point", config=config
    )
    env.reset(seed=7)
    core = env.unwrapped.core
    env.step(np.zeros((3, 9)))
    obs, *_ = env.step(np.zeros((3, 9)))
    v0, v1 = core.velocity_prev, core.velocity
    rate = np.arctan2(v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0], np.sum(v0 * v1, axis=-1))
    from imm_gym.sim.features import TURN_RATE_SCALE

    expected = np.clip(rate / core.sampling_period / TURN_RATE_SCALE, -1.0, 1.0)
    np.testing.assert_allclose(obs[:, -1], expected, rtol=1e-5, atol=1e-6)


def test_replay_ignores_the_variation() -> None:
    from imm_gym.sim.replay import ReplayCore

    core = ReplayCore(broad_config(), 2)
    assert not core.config.vary.active
    np.testing.assert_array_equal(core.sampling_period, [1.0, 1.0])


def test_a_sojourn_tpm_follows_each_episode_period() -> None:
    """``sojourn``: every slot starts at exp(A T) for its own T (bank B and the shadow too)."""
    from imm_gym.tracking.tpm import tpm_from_sojourn

    config = broad_config(sojourn=(60.0, 20.0, 20.0), parallel=True)
    core = TrackingCore(config, 4)
    core.reset(np.arange(4), [1, 2, 3, 4])
    for i in range(4):
        expected = tpm_from_sojourn((60.0, 20.0, 20.0), float(core.sampling_period[i]))
        np.testing.assert_array_equal(core.tpm[i], expected)
        np.testing.assert_array_equal(core.fixed_tpms[i], expected)
        np.testing.assert_array_equal(core.shadow_tpms[i], expected)
    assert np.ptp(core.tpm[:, 0, 0]) > 0.01  # the stay differs with T


def test_a_sojourn_tpm_replaces_the_stay_and_is_checked() -> None:
    from imm_gym.tracking.tpm import tpm_from_sojourn

    config = EnvConfig(sojourn=(60.0, 20.0, 20.0), shadow_stay=0.6)
    core = TrackingCore(config, 2)
    np.testing.assert_array_equal(core.tpm[0], tpm_from_sojourn((60.0, 20.0, 20.0), 1.0))
    np.testing.assert_array_equal(core.shadow_tpms[0], stay_tpm(3, 0.6))
    with pytest.raises(ConfigError, match=r"sojourn\[1\]"):
        EnvConfig(sojourn=(60.0, -1.0, 20.0))
    with pytest.raises(ConfigError, match="sojourn"):
        EnvConfig(sojourn=(60.0, 20.0))
    # a sojourn whose exp(A T) is out of range at the longest sampling period drawn: refused
    # when the configuration is built, naming the field
    with pytest.raises(ConfigError, match=r"sojourn\[2\] must be at least T / 1e\+12 = 5e-12 s"):
        EnvConfig(bank=CONTINUOUS_BANK, sojourn=(60.0, 20.0, 2e-12), vary={"T": (0.5, 5.0)})


def test_the_measurement_reward_scale_is_each_episode_accuracy() -> None:
    """``reward_scale="measurement"``: the advantage in units of the slot's first-measurement
    position accuracy sqrt(tr P0_pos / 2), by hand from the track start's covariance, at
    every step of random actions (a zero action makes the advantage 0 whatever the scale)."""
    config = broad_config(reward_scale="measurement")
    core = TrackingCore(config, 4)
    core.reset(np.arange(4), [5, 6, 7, 8])
    P0 = core.state_a.P[:, 0]
    scale = np.sqrt(0.5 * (P0[:, 0, 0] + P0[:, 1, 1]))
    assert np.ptp(scale) > 1.0
    rng = np.random.default_rng(0)
    for _ in range(10):
        result = core.step(rng.uniform(-1, 1, (4, 9)))
        advantage = result.info["shadow_position_error"] - result.info["position_error"]
        assert np.all(np.abs(advantage) > 1e-9)
        np.testing.assert_allclose(result.reward, advantage / scale, rtol=1e-12)
    with pytest.raises(ConfigError, match="reward_scale"):
        EnvConfig(reward_scale="sensor")


def test_a_share_of_the_episodes_keeps_the_configured_tracker() -> None:
    """``vary.share``: the runs that do not vary are the configured ones — their sampling period,
    sensor and bank, their speed from the family — and about ``share`` of them vary."""
    variation = Variation(**BROAD, share=0.3)
    rngs = [streams(s)[0] for s in range(1000)]
    c = draw_conditions(variation, 1.0, Sonar(), rngs)
    varied = c.T != 1.0
    assert abs(varied.mean() - 0.3) < 0.05
    assert all(c.sensors[i] == Sonar() for i in np.flatnonzero(~varied))
    assert np.all(np.isnan(c.speed[~varied])) and np.all(c.q_scale[~varied] == 1.0)
    assert np.all(~np.isnan(c.speed[varied]))
    config = EnvConfig(bank=CONTINUOUS_BANK, vary={**BROAD, "share": 0.3})
    batch = draw_batch(config.source, config.sensor, 40, 0, variation=config.vary)
    kept = batch.truth.T == 1.0
    speeds = np.linalg.norm(batch.truth.states[kept, 0, 2:], axis=-1)
    assert kept.any() and np.all((speeds >= 5.0) & (speeds <= 25.0))  # the family's own range
    with pytest.raises(ConfigError, match=r"vary.share"):
        Variation(share=0.0)


def test_a_varied_track_start_draws_last_and_spreads_the_first_velocity_estimate() -> None:
    """``vary.velocity_std``: each run's track starts with its own drawn prior spread on the
    velocity (P0's velocity variances; the estimate itself is the true velocity, SPEC §6); the
    other conditions are those of the same variation without it, bit for bit (drawn before it);
    runs that keep the configured conditions (``share``) start at the configured spread."""
    base = {"sigma_r": (10.0, 100.0), "q_scale": (0.3, 30.0), "share": 0.7}
    runs, seed = 400, 3
    plain = draw_batch(RandomFamily(), Sonar(), runs, seed, 7.0, Variation(**base))
    varied = draw_batch(
        RandomFamily(), Sonar(), runs, seed, 7.0, Variation(**base, velocity_std=(2.0, 40.0))
    )
    np.testing.assert_array_equal(varied.conditions.q_scale, plain.conditions.q_scale)
    np.testing.assert_array_equal(
        [s.sigma_r for s in varied.conditions.sensors],
        [s.sigma_r for s in plain.conditions.sensors],
    )
    np.testing.assert_array_equal(varied.x0[:, 2:], varied.truth.states[:, 0, 2:])
    spread = varied.conditions.velocity_std
    np.testing.assert_array_equal(plain.conditions.velocity_std, 7.0)
    np.testing.assert_array_equal(varied.P0[:, 2, 2], spread**2)
    np.testing.assert_array_equal(varied.P0[:, 3, 3], spread**2)
    kept = spread == 7.0
    assert 0.2 < kept.mean() < 0.4  # the 30 % of runs outside the share
    drawn = spread[~kept]
    assert np.all((drawn >= 2.0) & (drawn <= 40.0))
    assert abs(np.mean(drawn < math.sqrt(2.0 * 40.0)) - 0.5) < 0.08  # log-uniform


def test_a_varied_track_start_must_be_a_positive_range() -> None:
    with pytest.raises(ConfigError, match=r"vary.velocity_std\[0\] must be in \(1.49\d*e-154"):
        Variation(velocity_std=(0.0, 10.0))


def test_a_track_start_whose_variance_underflows_is_refused_by_the_configuration() -> None:
    """EnvConfig and vary take the track start's own range: a velocity_std of 1e-160 was
    accepted and refused by the first reset."""
    with pytest.raises(ConfigError, match=r"velocity_std must be in \[1.49\d*e-154, 1000000.0\]"):
        EnvConfig(velocity_std=1e-160)
    with pytest.raises(ConfigError, match=r"vary.velocity_std\[0\] must be in \(1.49\d*e-154"):
        Variation(velocity_std=(1e-160, 10.0))


def test_the_tracking_index_follows_each_slots_drawn_tracker() -> None:
    """``tracking_index`` by hand: for white-noise acceleration of intensity ``q_j`` the velocity
    variance per step is ``q_j T``, so the index is ``sqrt(q_j T³) / σ_p``, with CV's ``q`` times
    the slot's ``q_scale`` and the CT models' times ``q_scale * q_maneuver`` too."""
    N = 6
    config = EnvConfig(
        bank=CONTINUOUS_BANK, vary={**BROAD, "q_maneuver": (0.5, 50.0)},
        obs_features=("tracking_index",),
    )
    core = TrackingCore(config, N)
    seeds = list(range(300, 300 + N))
    core.reset(np.arange(N), seeds)
    obs = core.step(np.zeros((N, 9))).obs[:, 6:]
    drawn = draw_conditions(config.vary, 1.0, config.sensor, [streams(s)[0] for s in seeds])
    q = np.array([m.intensity for m in CONTINUOUS_BANK])
    a = drawn.q_maneuver
    factors = drawn.q_scale[:, None] * np.column_stack([np.ones(N), a, a])
    index = np.sqrt(q * factors * drawn.T[:, None] ** 3) / core.position_accuracy[:, None]
    assert np.all(np.abs(obs) < 1.0)  # inside the clip
    np.testing.assert_allclose(obs, np.log10(index) / 4, rtol=1e-5, atol=1e-6)
    ratio = obs[:, 1] - obs[:, 0]  # the maneuver models' noise against CV's, per slot
    np.testing.assert_allclose(ratio, np.log10(np.sqrt(0.5 * a)) / 4, rtol=1e-4, atol=1e-6)


def test_every_model_but_cv_takes_the_maneuver_factor() -> None:
    """CA models are maneuver models too (the Variation docstring): a CV/CA/CT bank's factors
    are q_scale, q_scale q_maneuver, q_scale q_maneuver."""
    bank = (SimpleNamespace(kind="cv"), SimpleNamespace(kind="ca"), SimpleNamespace(kind="ct"))
    assert maneuver_factors(bank, 2.0, 3.0) == [2.0, 6.0, 6.0]


def test_the_conditions_are_drawn_in_their_documented_order() -> None:
    """speed before q_scale, one uniform each from the episode's generator, log-uniform: the
    order fixes every varied episode of a seed (a reorder would silently change them all)."""
    got = Variation(speed=(100.0, 200.0), q_scale=(0.5, 2.0)).draw(np.random.default_rng(7))
    u = np.random.default_rng(7).uniform(size=2)
    assert got["speed"] == pytest.approx(100.0 * 2.0 ** u[0], rel=1e-12)
    assert got["q_scale"] == pytest.approx(0.5 * 4.0 ** u[1], rel=1e-12)


def test_a_track_starts_at_the_first_measurement_with_the_true_velocity_at_t0() -> None:
    """SPEC §6's filter start: the first measurement converted to a position (range and bearing
    from the sensor's position) and the truth's velocity at t = 0, the scenario's own; a target
    that turns from the first step with truth noise moves at another velocity at t = 1."""
    from imm_gym.scenarios.segments import Scenario, Segment

    velocity = (6.0, 15.0)
    scenario = Scenario(
        segments=(Segment(30, 3.0),),
        position=(3000.0, 4000.0),
        velocity=velocity,
        truth_q=(0.0, 0.0, 0.5, 0.5),
    )
    sensor = Sonar(position=(100.0, -200.0))
    batch = draw_batch(scenario, sensor, 6, 4)
    np.testing.assert_array_equal(batch.truth.states[:, 0, 2:4], np.tile(velocity, (6, 1)))
    assert np.all(np.abs(batch.truth.states[:, 1, 2:4] - velocity).max(axis=1) > 0.1)
    np.testing.assert_array_equal(batch.x0[:, 2:4], np.tile(velocity, (6, 1)))
    r, bearing = batch.measurements.z[:, 0, 0], batch.measurements.z[:, 0, 1]
    np.testing.assert_allclose(batch.x0[:, 0], 100.0 + r * np.cos(bearing), rtol=0, atol=1e-9)
    np.testing.assert_allclose(batch.x0[:, 1], -200.0 + r * np.sin(bearing), rtol=0, atol=1e-9)


def test_a_period_that_does_not_vary_is_the_configured_one() -> None:
    """Varying the sensor alone leaves every run at the configured period: a family at
    T = 2.5 s draws runs at 2.5 s, whose straight steps cover ``|v| * 2.5`` m by hand (and the
    conditions' T is 2.5 for every run, not the default 1 s)."""
    variation = Variation(sigma_r=(10.0, 100.0))
    family = RandomFamily(T=2.5, horizon=40, n_segments=(1, 3))
    rngs = [np.random.default_rng(s) for s in range(5)]
    np.testing.assert_array_equal(draw_conditions(variation, 2.5, Sonar(), rngs).T, 2.5)
    batch = draw_batch(family, Sonar(), 5, 3, variation=variation)
    truth = batch.truth
    np.testing.assert_array_equal(truth.T, 2.5)
    np.testing.assert_array_equal(batch.conditions.T, 2.5)
    straight = truth.turn_rate == 0.0
    step = np.linalg.norm(np.diff(truth.states[:, :, :2], axis=1), axis=-1)
    speed = np.linalg.norm(truth.states[:, :-1, 2:], axis=-1)
    assert straight.any()
    np.testing.assert_allclose(step[straight], 2.5 * speed[straight], rtol=1e-12)


def test_the_track_start_prior_left_unset_is_the_configurations_default() -> None:
    """``draw_conditions`` without ``velocity_std`` gives every run that does not vary it the
    configuration's default prior, ``EnvConfig().velocity_std`` (5 m/s), as ``draw_batch`` does."""
    rngs = [np.random.default_rng(s) for s in range(4)]
    c = draw_conditions(Variation(sigma_r=(10.0, 100.0)), 1.0, Sonar(), rngs)
    assert EnvConfig().velocity_std == 5.0
    np.testing.assert_array_equal(c.velocity_std, EnvConfig().velocity_std)


#: A range for every condition of DRAWS, in its order; the log-uniform ones span decades.
EVERY = {
    "T": (0.5, 5.0),
    "sigma_r": (10.0, 100.0),
    "sigma_theta_deg": (0.02, 0.5),
    "sigma_pos": (1.0, 50.0),
    "outlier_prob": (0.0, 0.1),
    "detection_prob": (0.1, 1.0),
    "speed": (5.0, 300.0),
    "q_scale": (0.3, 30.0),
    "q_maneuver": (0.5, 50.0),
    "velocity_std": (2.0, 40.0),
}


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_every_condition_is_drawn_by_its_documented_law(seed: int) -> None:
    """One uniform ``u`` per condition from the episode's generator, in the order of the module
    docstring's list; a scale (T, the noise deviations, speed, the noise factors, the track
    start's spread) is log-uniform, ``lo (hi / lo)^u``, a probability uniform, ``lo + (hi - lo)
    u`` (a detection probability of 0.1-1 drawn log-uniformly is below 0.55 three times in four,
    uniformly half the time)."""
    got = Variation(**EVERY).draw(np.random.default_rng(seed))
    u = np.random.default_rng(seed).uniform(size=len(EVERY))
    probabilities = ("outlier_prob", "detection_prob")
    assert list(got) == list(EVERY)
    for (name, (lo, hi)), ui in zip(EVERY.items(), u, strict=True):
        expected = lo + (hi - lo) * ui if name in probabilities else lo * (hi / lo) ** ui
        assert got[name] == pytest.approx(expected, rel=1e-12), name


def test_draw_conditions_gives_each_run_its_drawn_values_and_keeps_the_rest() -> None:
    """Run r's conditions are the values worked by hand from ``default_rng(r)``'s uniforms in the
    documented order (T, sigma_r, speed, q_scale, q_maneuver, velocity_std, each log-uniform);
    the sensor keeps its fields that do not vary. A variation of the sensor alone leaves every
    run's T, factors and spread at the configured ones and has no speed (None)."""
    vary = {name: EVERY[name] for name in
            ("T", "sigma_r", "speed", "q_scale", "q_maneuver", "velocity_std")}
    runs = 5
    rngs = [np.random.default_rng(r) for r in range(runs)]
    c = draw_conditions(Variation(**vary), 1.0, Sonar(), rngs)
    by_hand = np.array([
        [lo * (hi / lo) ** u for (lo, hi), u in
         zip(vary.values(), np.random.default_rng(r).uniform(size=6), strict=True)]
        for r in range(runs)
    ])
    np.testing.assert_allclose(c.T, by_hand[:, 0], rtol=1e-12)
    np.testing.assert_allclose([s.sigma_r for s in c.sensors], by_hand[:, 1], rtol=1e-12)
    np.testing.assert_allclose(c.speed, by_hand[:, 2], rtol=1e-12)
    np.testing.assert_allclose(c.q_scale, by_hand[:, 3], rtol=1e-12)
    np.testing.assert_allclose(c.q_maneuver, by_hand[:, 4], rtol=1e-12)
    np.testing.assert_allclose(c.velocity_std, by_hand[:, 5], rtol=1e-12)
    assert all(s.sigma_theta_deg == Sonar().sigma_theta_deg for s in c.sensors)
    rngs = [np.random.default_rng(r) for r in range(runs)]
    sensor_only = draw_conditions(Variation(sigma_r=(10.0, 100.0)), 2.0, Sonar(), rngs, 7.0)
    assert sensor_only.speed is None
    np.testing.assert_array_equal(sensor_only.T, 2.0)
    np.testing.assert_array_equal(sensor_only.q_scale, 1.0)
    np.testing.assert_array_equal(sensor_only.q_maneuver, 1.0)
    np.testing.assert_array_equal(sensor_only.velocity_std, 7.0)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"sigma_theta_deg": (1.0, 200.0)}, "vary.sigma_theta_deg[1] must be in [1.0, 180.0]"),
        ({"detection_prob": (0.5, 1.5)}, "vary.detection_prob[1] must be in [0.5, 1.0]"),
        ({"velocity_std": (5.0, 2e6)}, "vary.velocity_std[1] must be in [5.0, 1000000.0]"),
        ({"share": 0.0, "sigma_r": (10.0, 100.0)}, "vary.share must be in (0.0, 1.0]"),
    ],
)
def test_a_range_past_its_conditions_limit_is_refused_when_configured(changes, message) -> None:
    """A bearing noise above 180°, a detection probability above 1, a track-start spread above
    the initiation's 1e6 m/s and a share of 0 (no episode would vary) are refused by the
    configuration, naming the end, not by some later episode's sensor (or never)."""
    with pytest.raises(ConfigError) as err:
        Variation(**changes)
    assert message in str(err.value)


def test_a_varied_period_needs_every_model_of_the_bank_continuous() -> None:
    """A bank whose CV model has continuous-time noise but whose CT models keep the paper's
    per-step ``Q`` is right at one T only: ``vary.T`` is refused naming the first such model."""
    bank = (CONTINUOUS_BANK[0], *paper_bank()[1:])
    with pytest.raises(ConfigError) as err:
        EnvConfig(bank=bank, vary={"T": (0.5, 5.0)})
    assert "bank[1] has per-step noise" in str(err.value)
