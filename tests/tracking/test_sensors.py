"""Tests of imm_gym.tracking.sensors: the range-bearing sonar and the linear position sensor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym import ConfigError, EnvConfig, PositionSensor, Sonar, initiate

PI = np.pi


def _gens(seeds: range | list[int]) -> list[np.random.Generator]:
    return [np.random.default_rng(s) for s in seeds]


def _static_states(n: int, k1: int, xy: tuple[float, float]) -> np.ndarray:
    s = np.zeros((n, k1, 4))
    s[..., 0], s[..., 1] = xy
    return s


# --------------------------------------------------------------------------- measurement model


@pytest.mark.parametrize(
    ("xy", "expected"),
    [
        ((3000.0, 4000.0), (5000.0, math.atan2(4000.0, 3000.0))),
        ((-100.0, 0.0), (100.0, PI)),
        ((0.0, -250.0), (250.0, -PI / 2)),
        ((-3.0, -4.0), (5.0, math.atan2(-4.0, -3.0))),
    ],
)
def test_sonar_h(xy: tuple[float, float], expected: tuple[float, float]) -> None:
    z = Sonar().h(np.array([xy[0], xy[1], 7.0, -3.0]))
    np.testing.assert_allclose(z, expected, rtol=1e-14)


def test_sonar_h_position_offset() -> None:
    sonar = Sonar(position=(100.0, -200.0))
    z = sonar.h(np.array([103.0, -196.0, 1.0, 1.0]))
    np.testing.assert_allclose(z, [5.0, math.atan2(4.0, 3.0)], rtol=1e-13)
    H = sonar.jacobian(np.array([103.0, -196.0, 1.0, 1.0]))
    np.testing.assert_allclose(H[0, :2], [0.6, 0.8], rtol=1e-13)
    np.testing.assert_allclose(H[1, :2], [-4.0 / 25.0, 3.0 / 25.0], rtol=1e-13)


@pytest.mark.parametrize("position", [(0.0, 0.0), (250.0, -1200.0)])
def test_sonar_jacobian_finite_differences(position: tuple[float, float]) -> None:
    sonar = Sonar(position=position)
    rng = np.random.default_rng(1)
    for _ in range(20):
        r, b = rng.uniform(500.0, 10000.0), rng.uniform(-3.0, 3.0)
        x = np.array([r * math.cos(b), r * math.sin(b), *rng.normal(0, 20, 2)])
        x[:2] += position
        H = sonar.jacobian(x)
        assert H.shape == (2, 4)
        num = np.empty((2, 4))
        for j in range(4):
            e = np.zeros(4)
            e[j] = 1e-3
            num[:, j] = sonar.residual(sonar.h(x + e), sonar.h(x - e)) / 2e-3
        np.testing.assert_allclose(H, num, rtol=1e-6, atol=1e-12)


def test_sonar_jacobian_batched() -> None:
    sonar = Sonar()
    x = np.random.default_rng(2).normal(0.0, 3000.0, size=(3, 5, 4))
    H = sonar.jacobian(x)
    assert H.shape == (3, 5, 2, 4)
    np.testing.assert_array_equal(H[1, 2], sonar.jacobian(x[1, 2]))


def test_sonar_R() -> None:
    sonar = Sonar(sigma_r=50.0, sigma_theta_deg=0.05)
    np.testing.assert_allclose(sonar.R, np.diag([2500.0, math.radians(0.05) ** 2]))
    assert sonar.dim_z == 2
    assert sonar.linear_matrix(4) is None


def test_sonar_residual_wraps() -> None:
    sonar = Sonar()
    a = np.array([[100.0, PI - 0.01], [100.0, -PI + 0.01]])
    b = np.array([[90.0, -PI + 0.01], [90.0, PI - 0.01]])
    d = sonar.residual(a, b)
    np.testing.assert_allclose(d, [[10.0, -0.02], [10.0, 0.02]], atol=1e-12)


def test_sonar_initial_position() -> None:
    sonar = Sonar(position=(10.0, 20.0))
    z = np.array([[1000.0, 0.3], [500.0, -2.0]])
    pos, cov = sonar.initial_position(z)
    np.testing.assert_allclose(pos[0], [10.0 + 1000.0 * math.cos(0.3), 20.0 + 1000 * math.sin(0.3)])
    np.testing.assert_allclose(sonar.h(np.concatenate([pos, np.zeros((2, 2))], axis=1)), z)
    # covariance = J R J^T with J the polar-to-Cartesian Jacobian = inverse of h's Jacobian
    H = sonar.jacobian(np.concatenate([pos, np.zeros((2, 2))], axis=1))[..., :2]
    expected = np.linalg.inv(H) @ sonar.R @ np.swapaxes(np.linalg.inv(H), -1, -2)
    np.testing.assert_allclose(cov, expected, rtol=1e-9)


# --------------------------------------------------------------------------- simulation


def test_measurements_reproducible() -> None:
    sonar = Sonar(outlier_prob=0.1, detection_prob=0.9)
    states = _static_states(3, 50, (3000.0, 4000.0))
    a = sonar.measure(states, _gens([1, 2, 3]))
    b = sonar.measure(states, _gens([1, 2, 3]))
    np.testing.assert_array_equal(a.z, b.z)
    np.testing.assert_array_equal(a.detected, b.detected)
    np.testing.assert_array_equal(a.outlier, b.outlier)
    c = sonar.measure(states, _gens([1, 2, 4]))
    np.testing.assert_array_equal(a.z[:2], c.z[:2])  # each run has its own generator
    assert not np.array_equal(a.z[2], c.z[2])


@pytest.mark.parametrize("sensor", [Sonar(outlier_prob=0.2, detection_prob=0.7),
                                    PositionSensor(outlier_prob=0.1, sigma_vel=0.5)])
def test_measurement_draws_in_documented_order(sensor: object) -> None:
    """Run by run: ``standard_normal((K+1, m))``, ``random(K+1)`` (outliers), ``random(K+1)``
    (detections), and nothing else: the same bits and the same generator states after."""
    states = _static_states(5, 31, (3000.0, -4000.0))
    states[..., :2] += np.random.default_rng(0).normal(0.0, 500.0, (5, 31, 2))
    gens, ref = _gens(range(5)), _gens(range(5))
    got = sensor.measure(states, gens)  # type: ignore[attr-defined]
    for n, g in enumerate(ref):
        noise = g.standard_normal((31, sensor.dim_z))  # type: ignore[attr-defined]
        outlier = g.random(31) < sensor.outlier_prob  # type: ignore[attr-defined]
        detected = g.random(31) < sensor.detection_prob  # type: ignore[attr-defined]
        detected[0] = True
        scale = np.where(outlier, sensor.outlier_scale, 1.0)[:, None]  # type: ignore[attr-defined]
        z = sensor.wrap(sensor.h(states[n]) + scale * noise * sensor.sigma)  # type: ignore[attr-defined]
        assert got.z[n].tobytes() == z.tobytes()
        assert np.array_equal(got.outlier[n], outlier)
        assert np.array_equal(got.detected[n], detected)
    assert [g.bit_generator.state for g in gens] == [g.bit_generator.state for g in ref]


def test_measurement_shapes() -> None:
    m = Sonar().measure(_static_states(4, 11, (1000.0, 0.0)), _gens(range(4)))
    assert m.z.shape == (4, 11, 2)
    assert m.detected.shape == m.outlier.shape == (4, 11)
    assert m.detected.dtype == np.bool_
    assert m.detected.all()
    assert not m.outlier.any()


def test_measure_needs_one_generator_per_run() -> None:
    with pytest.raises(ConfigError):
        Sonar().measure(_static_states(3, 5, (1000.0, 0.0)), _gens([1, 2]))
    with pytest.raises(ConfigError):
        Sonar().measure(np.zeros((5, 4)), _gens([1]))


def test_sonar_noise_statistics() -> None:
    sonar = Sonar()
    states = _static_states(20, 1000, (3000.0, 4000.0))
    m = sonar.measure(states, _gens(range(20)))
    err = sonar.residual(m.z, sonar.h(states)).reshape(-1, 2)
    std = err.std(axis=0)
    assert std[0] == pytest.approx(50.0, rel=0.03)
    assert std[1] == pytest.approx(math.radians(0.05), rel=0.03)
    assert abs(err[:, 0].mean()) < 2.0  # 5.7 standard errors
    assert abs(err[:, 1].mean()) < math.radians(0.002)
    assert abs(np.corrcoef(err.T)[0, 1]) < 0.05


def test_sonar_position_offset_in_simulation() -> None:
    sonar = Sonar(position=(-2000.0, 500.0), sigma_r=1.0, sigma_theta_deg=0.001)
    states = _static_states(2, 200, (1000.0, 4500.0))  # offset (3000, 4000) from the sensor
    m = sonar.measure(states, _gens([0, 1]))
    np.testing.assert_allclose(m.z[..., 0].mean(), 5000.0, atol=0.5)
    np.testing.assert_allclose(m.z[..., 1].mean(), math.atan2(4000.0, 3000.0), atol=1e-5)


def test_measured_bearing_wrapped() -> None:
    # Target on the -x axis: bearings straddle +-pi. Large noise to cross the cut often.
    sonar = Sonar(sigma_theta_deg=5.0)
    states = _static_states(5, 400, (-5000.0, 0.0))
    m = sonar.measure(states, _gens(range(5)))
    b = m.z[..., 1]
    assert np.all(b > -PI) and np.all(b <= PI)
    assert (b > 3.0).any() and (b < -3.0).any()
    # wrapped measurements are the same directions as the unwrapped ones
    err = sonar.residual(m.z, sonar.h(states))[..., 1]
    assert np.abs(err).max() < math.radians(40.0)


def test_outliers() -> None:
    states = _static_states(40, 500, (3000.0, 4000.0))
    clean = Sonar()
    dirty = Sonar(outlier_prob=0.05, outlier_scale=10.0)
    mc = clean.measure(states, _gens(range(40)))
    md = dirty.measure(states, _gens(range(40)))
    share = md.outlier.mean()
    assert share == pytest.approx(0.05, abs=0.006)
    assert not mc.outlier.any()
    noise = dirty.residual(md.z, dirty.h(states)) / dirty.sigma
    out_std = noise[md.outlier].std(axis=0)
    in_std = noise[~md.outlier].std(axis=0)
    np.testing.assert_allclose(in_std, 1.0, rtol=0.03)
    np.testing.assert_allclose(out_std, 10.0, rtol=0.1)
    # common random numbers: the non-outlier measurements are unchanged
    np.testing.assert_array_equal(md.z[~md.outlier], mc.z[~md.outlier])
    # and the outliers are the same normal draws scaled by 10 (bearing: before wrapping)
    np.testing.assert_allclose(
        (md.z - dirty.h(states))[md.outlier][:, 0],
        10.0 * (mc.z - clean.h(states))[md.outlier][:, 0],
        rtol=1e-9,
    )


def test_changing_outlier_prob_keeps_other_draws() -> None:
    states = _static_states(10, 300, (-1000.0, 7000.0))
    a = Sonar(outlier_prob=0.02, detection_prob=0.9).measure(states, _gens(range(10)))
    b = Sonar(outlier_prob=0.2, detection_prob=0.9).measure(states, _gens(range(10)))
    both_clean = ~a.outlier & ~b.outlier
    assert both_clean.sum() > 2000
    np.testing.assert_array_equal(a.z[both_clean], b.z[both_clean])
    np.testing.assert_array_equal(a.detected, b.detected)
    assert b.outlier.sum() > a.outlier.sum()
    assert np.all(b.outlier[a.outlier])  # a higher probability keeps the earlier outliers


def test_missed_detections() -> None:
    states = _static_states(40, 500, (3000.0, 4000.0))
    full = Sonar().measure(states, _gens(range(40)))
    m = Sonar(detection_prob=0.8).measure(states, _gens(range(40)))
    assert m.detected[:, 0].all()  # the initiating detection is never missed
    missed = 1.0 - m.detected[:, 1:].mean()
    assert missed == pytest.approx(0.2, abs=0.01)
    np.testing.assert_array_equal(m.z, full.z)  # would-be measurements kept, same noise


def test_missed_detections_never_at_t0_even_if_rare() -> None:
    m = Sonar(detection_prob=0.01).measure(_static_states(200, 3, (1.0, 1.0)), _gens(range(200)))
    assert m.detected[:, 0].all()
    assert m.detected[:, 1:].mean() < 0.05


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"sigma_r": -1.0}, "sensor.sigma_r"),
        ({"sigma_r": 0.0}, "sensor.sigma_r"),
        ({"sigma_theta_deg": -0.05}, "sensor.sigma_theta_deg"),
        ({"position": (0.0, 0.0, 0.0)}, "sensor.position"),
        ({"position": (0.0, float("inf"))}, "sensor.position"),
        ({"outlier_prob": 1.5}, "sensor.outlier_prob"),
        ({"outlier_scale": 0.5}, "sensor.outlier_scale"),
        ({"detection_prob": 0.0}, "sensor.detection_prob"),
    ],
)
def test_sonar_invalid_config(kwargs: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        Sonar(**kwargs)


# --------------------------------------------------------------------------- position sensor


@pytest.mark.parametrize(
    ("sigma_vel", "m", "R"),
    [
        (None, 2, np.diag([100.0, 100.0])),
        (2.0, 4, np.diag([100.0, 100.0, 4.0, 4.0])),
    ],
)
@pytest.mark.parametrize("n", [4, 6])
def test_position_sensor(sigma_vel: float | None, m: int, R: np.ndarray, n: int) -> None:
    sensor = PositionSensor(sigma_pos=10.0, sigma_vel=sigma_vel)
    assert sensor.dim_z == m
    np.testing.assert_array_equal(sensor.R, R)
    H = sensor.linear_matrix(n)
    assert H.shape == (m, n)
    np.testing.assert_array_equal(H, np.eye(m, n))
    x = np.arange(2 * 3 * n, dtype=float).reshape(2, 3, n)
    np.testing.assert_array_equal(sensor.h(x), x[..., :m])
    J = sensor.jacobian(x)
    assert J.shape == (2, 3, m, n)
    np.testing.assert_array_equal(J[1, 2], H)
    np.testing.assert_array_equal(sensor.h(x[0, 0]), H @ x[0, 0])


@pytest.mark.parametrize("sigma_vel", [None, 2.0])
def test_position_sensor_noise(sigma_vel: float | None) -> None:
    sensor = PositionSensor(sigma_pos=10.0, sigma_vel=sigma_vel)
    states = np.zeros((10, 1000, 4))
    states[..., :] = [100.0, -50.0, 3.0, 4.0]
    meas = sensor.measure(states, _gens(range(10)))
    assert meas.z.shape == (10, 1000, sensor.dim_z)
    err = (meas.z - sensor.h(states)).reshape(-1, sensor.dim_z)
    np.testing.assert_allclose(err.std(axis=0), sensor.sigma, rtol=0.03)


def test_position_sensor_invalid() -> None:
    with pytest.raises(ConfigError, match=r"position_sensor\.sigma_pos"):
        PositionSensor(sigma_pos=-1.0)
    with pytest.raises(ConfigError, match=r"position_sensor\.sigma_vel"):
        PositionSensor(sigma_vel=0.0)


# --------------------------------------------------------------------------- track initiation


@pytest.mark.parametrize(
    ("sensor", "named"),
    [
        (Sonar(sigma_r=1e-12), "sensor.sigma_r = 1e-12"),
        (Sonar(sigma_r=1e-100), "sensor.sigma_r = 1e-100"),
        (Sonar(sigma_theta_deg=1e-12), "sensor.sigma_theta_deg = 1e-12"),
    ],
)
def test_initiate_names_noise_float64_cannot_factor(sensor: object, named: str) -> None:
    """A first-measurement covariance whose Cholesky factorization fails in float64 (standard
    deviations 1e-12 m along range and 4 m across it) is refused naming the sensor's fields,
    not later as an anonymous "P0 must be positive definite"."""
    z0 = np.array([[5000.0, 0.3], [5000.0, 0.7]])
    with pytest.raises(ConfigError, match=named.replace(".", r"\.")):
        initiate(sensor, z0, np.zeros(2))


@pytest.mark.parametrize("sensor", [Sonar(sigma_r=1e-6), Sonar(), PositionSensor(sigma_pos=1e-6)])
def test_initiate_accepts_accurate_sensors(sensor: object) -> None:
    x0, P0 = initiate(sensor, np.array([[5000.0, 0.3]]), np.array([1.0, 2.0]))
    np.linalg.cholesky(P0)
    np.testing.assert_array_equal(x0[0, 2:], [1.0, 2.0])


def test_initiate_refuses_velocity_std_whose_variance_underflows() -> None:
    with pytest.raises(ConfigError, match="velocity_std"):
        initiate(Sonar(), np.array([[5000.0, 0.3]]), np.zeros(2), velocity_std=1e-160)


def test_sonar_residual_of_integer_measurements_keeps_the_wrapped_bearing() -> None:
    d = Sonar().residual(np.array([10, 3]), np.array([0, -3]))
    np.testing.assert_allclose(d, [10.0, 6.0 - 2.0 * math.pi])


def test_initiate_refuses_misshapen_inputs_and_a_velocity_std_beyond_any_target() -> None:
    z0 = np.array([[5000.0, 0.3]])
    with pytest.raises(ConfigError, match=r"z0 must have shape \(2,\) or \(N, 2\)"):
        initiate(Sonar(), np.array([[5000.0, 0.3, 7.0]]), np.zeros(2))
    for v in (np.zeros(3), np.zeros((2, 2))):
        with pytest.raises(ConfigError, match=r"velocity must have shape \(2,\) or \(1, 2\)"):
            initiate(Sonar(), z0, v)
    with pytest.raises(ConfigError, match=r"velocity_std must be in .*1000000.0\]"):
        initiate(Sonar(), z0, np.zeros(2), velocity_std=1e150)
    with pytest.raises(ConfigError, match=r"velocity_std must be in .*1000000.0\]"):
        EnvConfig(velocity_std=1e160)
    x0, _ = initiate(Sonar(), np.array([5000.0, 0.0]), np.array([1.0, 2.0]), velocity_std=1e6)
    np.testing.assert_allclose(x0, [[5000.0, 0.0, 1.0, 2.0]])


@pytest.mark.parametrize("sigma_vel", [None, 2.0])
def test_position_sensor_initial_position_is_the_measured_position_and_r(
    sigma_vel: float | None,
) -> None:
    """The start of a track on a position sensor is the measured position with covariance
    ``R``'s position block ``sigma_pos^2 I`` (the variance, 900 m² for 30 m), and
    ``initiate``'s ``P0`` carries it: ``P0[:2, :2] = R[:2, :2]``, velocity block
    ``velocity_std^2 I``."""
    sensor = PositionSensor(sigma_pos=30.0, sigma_vel=sigma_vel)
    z = np.array([[100.0, 200.0, 1.0, 2.0], [-50.0, 70.0, 3.0, 4.0]])[:, : sensor.dim_z]
    pos, cov = sensor.initial_position(z)
    np.testing.assert_array_equal(pos, z[:, :2])
    np.testing.assert_array_equal(cov, np.broadcast_to(900.0 * np.eye(2), (2, 2, 2)))
    x0, P0 = initiate(sensor, z, np.array([5.0, 0.0]), velocity_std=3.0)
    np.testing.assert_array_equal(x0, np.column_stack([z[:, :2], np.tile([5.0, 0.0], (2, 1))]))
    for P in P0:
        np.testing.assert_array_equal(P[:2, :2], sensor.R[:2, :2])
        np.testing.assert_array_equal(P[2:, 2:], 9.0 * np.eye(2))
        np.testing.assert_array_equal(P[:2, 2:], 0.0)


def test_sonar_implausible_rows_are_a_negative_range_or_a_bearing_beyond_2_pi() -> None:
    """``Sonar.implausible`` flags what its documented units exclude (a range >= 0 m, a bearing in
    rad with ``|bearing| <= 2 pi``): bearings of 4 and -3.5 rad (beyond pi, within 2 pi: a
    bearing in [0, 2 pi)) and -6.28 rad are plausible, 6.3 and 45 (degrees, likely) and a
    negative range are not, and a NaN row is not flagged."""
    sonar = Sonar()
    assert sonar.measurement_units == "a range >= 0 m and a bearing in rad, |bearing| <= 2 pi"
    z = np.array(
        [[1000.0, 4.0], [1000.0, -3.5], [1000.0, -6.28], [1000.0, 2.0 * PI], [1000.0, 6.3],
         [1000.0, 45.0], [-5.0, 0.1], [np.nan, np.nan]]
    )  # fmt: skip
    assert sonar.implausible(z).tolist() == [False, False, False, False, True, True, True, False]
