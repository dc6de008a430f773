"""Seed 002's evaluation: the scenario family, the metrics, the IMM-EKF's consistency."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym import ConfigError, Scenario, Segment, generate_truth
from imm_gym.evaluation.metrics import trajectory_metrics
from imm_gym.papers.systems import draw, hetero_ekf_evaluation, hetero_ekf_sensor
from imm_gym.scenarios.profiles import (
    DRIVING_DURATIONS,
    DrivingFamily,
    ManeuverFamily,
    maneuver_profile,
    maneuver_truth,
    profile_truth,
)


def test_profile_truth_matches_segment_truth_on_turns() -> None:
    """The CTRA truth equals the closed-form CT truth of :mod:`imm_gym.scenarios.segments`."""
    scenario = Scenario(
        (Segment(20), Segment(30, 2.0), Segment(10), Segment(15, -3.0)),
        position=(100.0, -50.0),
        velocity=(6.0, 8.0),
        T=1.0,
    )
    ref = generate_truth([scenario])
    omega, accel = scenario.profile()
    pt = profile_truth(
        omega[None],
        accel[None],
        np.array([[100.0, -50.0]]),
        np.array([10.0]),
        np.array([math.atan2(8.0, 6.0)]),
        1.0,
    )
    np.testing.assert_allclose(pt.states, ref.states, atol=1e-9)


def _profile_args() -> dict[str, np.ndarray]:
    return {
        "omega": np.array([[0.1, 0.0]]),
        "accel": np.array([[0.0, 0.5]]),
        "position": np.array([[0.0, 0.0]]),
        "speed": np.array([5.0]),
        "heading": np.array([0.3]),
        "cart_accel": np.zeros((1, 2, 2)),
    }


@pytest.mark.parametrize(
    ("name", "index"),
    [("omega", (0, 1)), ("accel", (0, 0)), ("position", (0, 1)), ("speed", (0,)),
     ("heading", (0,)), ("cart_accel", (0, 1, 0))],
)
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_profile_truth_refuses_a_non_finite_profile_by_name(name, index, bad) -> None:
    """A NaN or infinite entry was propagated into the whole truth; it is refused, named."""
    args = _profile_args()
    args[name][index] = bad
    with pytest.raises(ConfigError, match=rf"^{name} must be finite everywhere, got {bad}"):
        profile_truth(T=1.0, **args)


@pytest.mark.parametrize("T", [0.0, -1.0, math.nan])
def test_profile_truth_refuses_a_period_that_is_not_positive(T: float) -> None:
    """At T < 0 the truth ran backwards (and T = 0 stood still)."""
    with pytest.raises(ConfigError, match=r"^T must be in \(0.0, inf\)"):
        profile_truth(T=T, **_profile_args())


def test_driving_family_has_its_maneuvers() -> None:
    fam = DrivingFamily()
    pt = fam.truth([np.random.default_rng(s) for s in range(4)])
    w, speed = pt.turn_rate, np.linalg.norm(pt.states[..., 2:], axis=-1)
    T = fam.T
    sharp = np.abs(w) > 0.3
    # two sharp 90° turns per run
    np.testing.assert_allclose(np.sum(np.abs(w) * sharp, axis=1) * T, math.pi, atol=1e-9)
    # the speed is lowest in the sharp turns
    assert np.all(speed[:, 1:][sharp].reshape(4, -1).max(axis=1) < speed.max(axis=1) - 3.0)
    # the S-curve turns back: net heading change of the gentle part is 0
    gentle = (np.abs(w) > 0) & ~sharp
    np.testing.assert_allclose(np.sum(w * gentle, axis=1), 0.0, atol=1e-9)
    # the speed at each segment's end: cruise, the curve speed through the S-curve, back to
    # cruise, the turn speed through each 90° turn, back to cruise after it
    ends = np.round(np.cumsum(DRIVING_DURATIONS) / T).astype(int)
    v = speed[:, ends]
    cruise, curve, turn = speed[:, 0], v[:, 1], v[:, 7]
    assert np.all((fam.cruise[0] <= cruise) & (cruise <= fam.cruise[1]))
    assert np.all((fam.curve[0] <= curve) & (curve <= fam.curve[1]))
    assert np.all((fam.turn[0] <= turn) & (turn <= fam.turn[1]))
    expected = np.stack(
        [cruise, curve, curve, curve, curve, cruise, cruise, turn, turn, cruise, cruise, turn, turn,
         cruise, cruise], axis=1,
    )
    np.testing.assert_allclose(v, expected, rtol=1e-12)


def test_a_driving_family_whose_curves_are_faster_than_cruise_is_refused() -> None:
    """A curve or turn speed above the cruise speed made "slow down" speed up."""
    with pytest.raises(ConfigError, match=r"^family\.curve\[1\] must be <= family\.cruise\[0\]"):
        DrivingFamily(curve=(20.0, 21.0))
    with pytest.raises(ConfigError, match=r"^family\.turn\[1\] must be <= family\.cruise\[0\]"):
        DrivingFamily(cruise=(12.0, 16.0), turn=(5.0, 13.0))
    DrivingFamily(cruise=(12.0, 16.0), curve=(12.0, 12.0), turn=(12.0, 12.0))


def test_trajectory_metrics_closed_form() -> None:
    truth = np.zeros((2, 3, 4))
    truth[..., 2] = 1.0  # heading 0
    est = truth.copy()
    est[0, :, 0] = [3.0, 0.0, 4.0]
    est[1, :, 3] = 1.0  # heading 45°
    m = trajectory_metrics(est, truth, np.zeros((2, 3)))
    assert m["pos_rmse"] == pytest.approx(math.sqrt(25 / 6))
    assert m["pos_mae"] == pytest.approx(7 / 6)
    assert m["pos_max"] == pytest.approx(2.0)
    assert m["fde"] == pytest.approx(2.0)
    assert m["vel_rmse"] == pytest.approx(math.sqrt(0.5))
    assert m["yaw_rmse_deg"] == pytest.approx(math.sqrt(45.0**2 / 2))


def test_heterogeneous_imm_is_consistent_on_the_driving_family() -> None:
    """Seed 002 reports 94.16 % of NIS inside the 95 % bound, mean 4.39 (dimension 4)."""
    result = hetero_ekf_evaluation(runs=20, seed=0)
    m = result["metrics"]
    assert m["failed"] == 0
    assert m["nis_inside"] >= 0.90
    assert abs(m["nis_mean"] - 4.0) <= 0.25 * 4.0
    assert m["pos_rmse"] < 0.5  # sigma_p = 0.5 m; seed 002: 0.31 m on their trajectory
    assert m["yaw_rmse_deg"] < 5.0


def test_seed_batches_are_reproducible_and_reject_bad_input() -> None:
    a = draw(DrivingFamily(), hetero_ekf_sensor(), 3, 7)
    b = draw(DrivingFamily(), hetero_ekf_sensor(), 3, 7)
    np.testing.assert_array_equal(a.measurements.z, b.measurements.z)
    with pytest.raises(ConfigError, match="runs"):
        draw(DrivingFamily(), hetero_ekf_sensor(), 0, 7)
    with pytest.raises(ConfigError, match="shape"):
        profile_truth(
            np.zeros((1, 3)), np.zeros((1, 4)), np.zeros((1, 2)), np.ones(1), np.zeros(1), 0.1
        )


def test_maneuver_profile_follows_the_source() -> None:
    """Seed 003 §4's stated velocities at the segment ends, exact (closed-form truth)."""
    p = maneuver_profile(0.1)
    assert p.omega.shape == p.accel.shape == (430,) and p.cart_accel.shape == (430, 2)
    assert p.speed == 5.0
    pt = maneuver_truth(1)
    x, vel = pt.states[0, :, :2], pt.states[0, :, 2:]
    k = {t: round(t / 0.1) for t in (10, 14, 34, 38, 43)}
    np.testing.assert_allclose(vel[: k[10] + 1], np.tile((0.0, -5.0), (k[10] + 1, 1)), atol=1e-12)
    # 10-14 s: constant Cartesian acceleration (0.25, 1) m/s^2, ending at v = (1, -1) m/s
    np.testing.assert_allclose(
        np.diff(vel[k[10] : k[14] + 1], axis=0), 0.1 * np.array([[0.25, 1.0]] * 40), atol=1e-12
    )
    np.testing.assert_allclose(vel[k[14]], (1.0, -1.0), atol=1e-12)
    np.testing.assert_allclose(
        x[k[14]] - x[k[10]], (0.0, -20.0) + 0.5 * 16 * np.array((0.25, 1.0)), atol=1e-9
    )
    # 14-34 s: a uniform (left) turn at |(1, -1)| m/s
    speed = np.linalg.norm(vel, axis=-1)
    np.testing.assert_allclose(speed[k[14] : k[34] + 1], math.sqrt(2.0), atol=1e-12)
    assert np.all(pt.turn_rate[0, k[14] : k[34]] > 0)
    # 34-38 s: uniform acceleration ending at v = (0, 8) m/s; straight to 43 s
    np.testing.assert_allclose(
        vel[k[38] :], np.tile((0.0, 8.0), (k[43] - k[38] + 1, 1)), atol=1e-12
    )
    accel = np.diff(vel[k[34] : k[38] + 1], axis=0)
    np.testing.assert_allclose(accel, np.tile(accel[0], (40, 1)), atol=1e-12)
    # the recorded profile marks both accelerations (the bank's CA), the turn and the legs
    assert np.all(pt.accel[0, k[10] : k[14]] != 0) and np.all(
        pt.accel[0, k[34] : k[38]] != 0
    )
    assert np.all(pt.accel[0, : k[10]] == 0) and np.all(pt.turn_rate[0, k[38] :] == 0)
    with pytest.raises(ConfigError, match="Cartesian"):
        profile_truth(
            np.full((1, 3), 0.1),
            np.zeros((1, 3)),
            np.zeros((1, 2)),
            np.ones(1),
            np.zeros(1),
            0.1,
            np.ones((1, 3, 2)),
        )


def test_maneuver_family_keeps_the_turn_direction() -> None:
    from imm_gym.papers.systems import ManeuverFamily

    fam = ManeuverFamily()
    pt = fam.truth([np.random.default_rng(s) for s in range(20)])
    assert np.all(pt.turn_rate >= 0) and np.any(pt.turn_rate > 0.05)
    # the 10-14 s Cartesian acceleration, rotated with the run's heading and scaled
    vel = pt.states[..., 2:]
    dv = vel[:, 140] - vel[:, 100]
    rot = pt.heading[:, 0] + math.pi / 2
    back = np.stack(
        [
            np.cos(rot) * dv[:, 0] + np.sin(rot) * dv[:, 1],
            -np.sin(rot) * dv[:, 0] + np.cos(rot) * dv[:, 1],
        ],
        axis=-1,
    )
    scale = back / (4.0 * np.array([0.25, 1.0]))
    np.testing.assert_allclose(scale[:, 0], scale[:, 1], atol=1e-9)
    assert np.all((scale[:, 0] >= 0.5) & (scale[:, 0] <= 1.5))


def test_maneuver_family_draws_over_its_documented_ranges() -> None:
    """Per run: the turn rate is the source's (135° in 20 s) times ``U(0.6, 1.4)``, the start
    ``U(-20, 20)`` m per axis, the speed ``U(4, 6)`` m/s; 200 draws reach near each end."""
    pt = ManeuverFamily().truth([np.random.default_rng(s) for s in range(200)])
    scale = pt.turn_rate[:, 200] / (math.radians(135.0) / 20.0)  # 20 s, mid-turn (14-34 s)
    assert scale.min() >= 0.6 and scale.max() <= 1.4
    assert scale.min() < 0.65 and scale.max() > 1.35
    start = pt.states[:, 0, :2]
    assert start.min() >= -20.0 and start.max() <= 20.0
    for axis in (0, 1):
        assert start[:, axis].min() < -18.0 and start[:, axis].max() > 18.0
    speed = np.linalg.norm(pt.states[:, 0, 2:4], axis=-1)
    assert speed.min() >= 4.0 and speed.max() <= 6.0
    assert speed.min() < 4.1 and speed.max() > 5.9


def test_consistency_uses_the_one_sided_chi2_bound() -> None:
    """chi2(4) samples: 95 % inside the bound 9.4877 (seed 002's dashed line), mean 4."""
    from imm_gym.evaluation.metrics import consistency

    values = np.random.default_rng(0).chisquare(4, size=200_000)
    c = consistency(values, 4)
    assert c["bound"] == pytest.approx(9.4877, abs=1e-4)
    assert c["inside"] == pytest.approx(0.95, abs=0.003)
    assert c["mean"] == pytest.approx(4.0, abs=0.03)
    masked = consistency(values, 4, mask=values > 9.4877)
    assert masked["inside"] == 0.0


def test_seed002_sensor_is_table_i() -> None:
    """Seed 002 Table I: position measurement std. dev. sigma_p = 0.5 m, velocity measurement
    std. dev. sigma_v,meas = 0.5 m/s; the seed-002 system measures with that sensor."""
    from imm_gym.papers.systems import system_setup

    sensor = hetero_ekf_sensor()
    assert (sensor.sigma_pos, sensor.sigma_vel) == (0.5, 0.5)
    np.testing.assert_allclose(sensor.R, np.diag([0.25, 0.25, 0.25, 0.25]))
    used = system_setup("seed002")[2]
    assert (used.sigma_pos, used.sigma_vel) == (0.5, 0.5)


def test_score_run_nees_is_chi2_with_four_degrees_of_freedom() -> None:
    """The NEES on ``[x, y, vx, vy]`` has 4 degrees of freedom: ``nees_inside`` is the share of
    ``e^T P^-1 e`` (computed here by ``np.linalg.solve``) at most scipy's ``chi2.ppf(0.95, 4)``."""
    from scipy import stats

    from imm_gym.papers.systems import run_bank, score_run, system_setup

    imm, family, sensor, tpm = system_setup("seed002")
    batch = draw(family, sensor, 2, 0)
    result = run_bank(imm, batch, tpm)
    e = batch.truth.states[:, 1:, :4] - result.x[..., :4]
    solved = np.linalg.solve(result.P[..., :4, :4], e[..., None])[..., 0]
    values = np.einsum("rki,rki->rk", e, solved)
    bound4, bound2 = stats.chi2.ppf(0.95, 4), stats.chi2.ppf(0.95, 2)
    assert np.any((values > bound2) & (values <= bound4))  # the degrees of freedom matter here
    m = score_run(result, batch, sensor.dim_z)
    assert m["nees_inside"] == pytest.approx(np.mean(values <= bound4), abs=1e-12)
    assert m["nees_mean"] == pytest.approx(values.mean(), rel=1e-9)


def test_hetero_ekf_evaluation_takes_a_bank() -> None:
    from imm_gym.tracking.hetero import HeteroBank

    a = hetero_ekf_evaluation(runs=1, seed=4)["metrics"]
    b = hetero_ekf_evaluation(runs=1, seed=4, bank=HeteroBank(q_scale=(0.1, 0.1, 0.1)))["metrics"]
    assert a["pos_rmse"] != b["pos_rmse"]


@pytest.mark.parametrize(
    ("build", "name"),
    [
        (lambda: DrivingFamily(T=0.3), "family.T"),
        (lambda: ManeuverFamily(T=0.3), "family.T"),
        (lambda: maneuver_profile(T=0.7), "T"),
    ],
)
def test_a_period_that_does_not_divide_the_segments_is_refused(build, name: str) -> None:
    """The profiles' turns and accelerations are timed in seconds: at T = 0.3 s the driving
    family's 90° turns came out 87.75° and the run 66.6 s long, and at 0.7 s seed 003's final
    velocity missed (0, 8) m/s; both are refused when built, naming the field."""
    with pytest.raises(ConfigError, match=rf"^{name} must divide every segment's duration"):
        build()


@pytest.mark.parametrize("T", [0.05, 0.1, 0.25, 0.5])
def test_periods_that_divide_the_segments_are_accepted(T: float) -> None:
    family = DrivingFamily(T=T)
    truth = family.truth([np.random.default_rng(0)])
    assert truth.states.shape[1] == round(67.0 / T) + 1
    ManeuverFamily(T=T)


@pytest.mark.parametrize("family", [DrivingFamily(T=0.25), ManeuverFamily(T=0.05)])
def test_the_families_are_truth_sources_of_their_horizon(family) -> None:
    """Both families are truth sources (:class:`~imm_gym.scenarios.segments.TruthSource`):
    ``horizon`` is the steps their truth has after its start (they had no ``horizon``)."""
    truth = family.truth([np.random.default_rng(1), np.random.default_rng(2)])
    assert truth.states.shape[:2] == (2, family.horizon + 1)
