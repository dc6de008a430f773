"""The seed systems (:mod:`imm_gym.papers.systems`) against their module docstring and by hand:
the seed-003 bank, sensor and TPM, a batch's seeds and track start, the metrics of a bank run with
missed detections."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from imm_gym import ConfigError
from imm_gym.papers.systems import (
    bbsca_imm,
    bbsca_models,
    bbsca_sensor,
    draw,
    hetero_ekf_evaluation,
    run_bank,
    score_run,
    system_setup,
)
from imm_gym.scenarios.profiles import DrivingFamily, ManeuverFamily
from imm_gym.seeding import streams
from imm_gym.tracking.imm import run
from imm_gym.tracking.sensors import PositionSensor


def _tpm(stay: float) -> np.ndarray:
    off = (1.0 - stay) / 2
    return np.full((3, 3), off) + np.eye(3) * (stay - off)


def test_seed003_is_the_documented_bank_sensor_and_tpm() -> None:
    """CV / CA / CT(+6.75°/s) with ``Q_CV = diag(1e-3, 1e-3, 1e-2, 1e-2)``, ``q_acc = 1e-2``,
    ``Q_CA`` adding 1e-1 on the accelerations, ``Q_CT = Q_CV``; ``sigma_p = 1`` m,
    ``sigma_v = 0.5`` m/s; TPM 0.90 / 0.05; ``T = 0.1`` s."""
    cv, ca, ct = bbsca_models()
    assert (cv.kind, ca.kind, ct.kind) == ("cv", "ca", "ct")
    assert cv.q == ct.q == (1e-3, 1e-3, 1e-2, 1e-2) and cv.q_acc == ct.q_acc == 1e-2
    assert ca.q == (1e-3, 1e-3, 1e-2, 1e-2, 1e-1, 1e-1)
    assert ct.turn_rate_deg == pytest.approx(6.75, rel=1e-12)
    sensor = bbsca_sensor()
    assert (sensor.sigma_pos, sensor.sigma_vel) == (1.0, 0.5)
    np.testing.assert_allclose(sensor.R, np.diag([1.0, 1.0, 0.25, 0.25]))
    imm, family, used, tpm = system_setup("seed003")
    assert isinstance(family, ManeuverFamily) and (used.sigma_pos, used.sigma_vel) == (1.0, 0.5)
    assert imm.T == 0.1 and bbsca_imm().T == 0.1
    np.testing.assert_allclose(tpm, _tpm(0.9), rtol=1e-12)


def test_seed002_runs_table_is_tpm() -> None:
    """Seed 002 Table I: TPM 0.90 on the diagonal, 0.05 off it."""
    _, family, _, tpm = system_setup("seed002")
    assert isinstance(family, DrivingFamily)
    np.testing.assert_allclose(tpm, _tpm(0.9), rtol=1e-12)
    with pytest.raises(ConfigError, match=r"scenario must be one of \['seed002', 'seed003'\]"):
        system_setup("seed001")


def test_a_batch_draws_run_r_from_seed_plus_r_and_starts_at_the_first_measurement() -> None:
    """Run 1 of a batch seeded 5 is the family's trajectory and the sensor's noise of the streams
    of seed 6; the track starts at the first measurement with ``P0 = R``."""
    family, sensor = ManeuverFamily(), bbsca_sensor()
    batch = draw(family, sensor, 2, 5)
    scen, noise = streams(6)
    truth = family.truth([scen])
    np.testing.assert_array_equal(batch.truth.states[1], truth.states[0])
    meas = sensor.measure(truth.states, [noise])
    np.testing.assert_array_equal(batch.measurements.z[1], meas.z[0])
    np.testing.assert_array_equal(batch.x0, batch.measurements.z[:, 0, :4])
    np.testing.assert_array_equal(batch.P0, np.stack([np.diag([1.0, 1.0, 0.25, 0.25])] * 2))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((PositionSensor(sigma_pos=1.0), 2, 0), "position\\+velocity sensor"),
        ((bbsca_sensor(), 2, -1), "seed"),
        ((bbsca_sensor(), 0, 0), "runs"),
    ],
)
def test_a_batch_refuses_a_sensor_without_velocity_and_bad_counts(args, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        draw(ManeuverFamily(), *args)


def test_the_metrics_of_a_bank_run_with_missed_detections_by_hand() -> None:
    """Seed 003's bank with a sensor detecting 70 % of the time: the run is the engine's on the
    steps after the first measurement, missed ones flagged; the metrics are computed on those
    steps' truth, the NIS only where a measurement came."""
    sensor = PositionSensor(sigma_pos=1.0, sigma_vel=0.5, detection_prob=0.7)
    imm = bbsca_imm(sensor)
    batch = draw(ManeuverFamily(), sensor, 2, 3)
    detected = batch.measurements.detected[:, 1:]
    assert 0 < (~detected).sum() < detected.size
    tpm = _tpm(0.9)
    result = run_bank(imm, batch, tpm)
    z = batch.measurements.z[:, 1:]
    alone = run(imm, z, tpm, batch.x0, batch.P0, detected=detected, allow_failure=True)
    np.testing.assert_array_equal(result.x, alone.x)
    m = score_run(result, batch, sensor.dim_z)
    truth = batch.truth.states[:, 1:]
    e = np.hypot(*(result.x[..., :2] - truth[..., :2]).transpose(2, 0, 1))
    assert m["pos_rmse"] == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-12)
    assert m["fde"] == pytest.approx(np.mean(e[:, -1]), rel=1e-12)
    yaw = np.arctan2(result.x[..., 3], result.x[..., 2]) - batch.truth.heading[:, 1:]
    yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
    assert m["yaw_rmse_deg"] == pytest.approx(math.degrees(np.sqrt(np.mean(yaw**2))), rel=1e-9)
    assert m["nis_mean"] == pytest.approx(result.nis[detected].mean(), rel=1e-12)
    assert m["failed"] == 0


def test_the_seed002_evaluation_reports_its_runs() -> None:
    """One run seeded 4: seeds ``4..4``, the steps after the first measurement, the mean mode
    probabilities over the steps (summing to 1)."""
    out = hetero_ekf_evaluation(runs=1, seed=4)
    imm, family, sensor, tpm = system_setup("seed002")
    batch = draw(family, sensor, 1, 4)
    result = run_bank(imm, batch, tpm)
    assert out["meta"] == {"runs": 1, "seeds": "4..4", "steps": batch.truth.states.shape[1] - 1}
    probs = result.mode_probs.reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(out["mean_mode_probs"], probs, rtol=1e-12)
    assert sum(out["mean_mode_probs"]) == pytest.approx(1.0)
    assert out["paper"]["nis_inside"] == 0.9416 and out["paper"]["pos_rmse"] == 0.3117


def test_a_system_comparison_reports_each_row_and_its_runs(tmp_path) -> None:
    """``fixed`` is the untuned bank's run (factors 1, no training objective); a loaded bank's
    row reports its file, factors and objective; the meta names the runs; seed 003 has no
    published figures to stand beside."""
    from imm_gym.papers.tuned_comparison import evaluate_system
    from imm_gym.papers.tuning import TunedBank

    path = tmp_path / "bb.json"
    TunedBank("seed003", (2.0, 0.5, 1.5), 1.3, objective=0.8).save(path)
    out = evaluate_system("seed003", ["fixed", "bbsca"], runs=1, seed=2, tuned={"bbsca": str(path)})
    imm, family, sensor, tpm = system_setup("seed003")
    batch = draw(family, sensor, 1, 2)
    plain = score_run(run_bank(imm, batch, tpm), batch, sensor.dim_z)
    fixed, tuned = out["policies"]["fixed"], out["policies"]["bbsca"]
    assert fixed["pos_rmse"] == pytest.approx(plain["pos_rmse"], rel=1e-12)
    assert fixed["nis_mean"] == pytest.approx(plain["nis_mean"], rel=1e-12)
    assert (fixed["q_scale"], fixed["r_scale"], fixed["train_objective"]) == ([1.0] * 3, 1.0, None)
    assert (tuned["q_scale"], tuned["r_scale"]) == ([2.0, 0.5, 1.5], 1.3)
    assert (tuned["train_objective"], tuned["tuned_file"]) == (0.8, str(path))
    steps = batch.truth.states.shape[1] - 1
    assert out["meta"] == {
        "scenario": "seed003",
        "runs": 1,
        "seed": 2,
        "seeds": "2..2",
        "steps": steps,
        "filter": "ekf",
    }
    assert out["paper"] == {}


def test_a_seed002_comparison_stands_beside_the_published_figures() -> None:
    """On seed 002 the comparison's ``paper`` entry is the heterogeneous-EKF paper's table
    (position RMSE 0.3117 m, 94.16 % of the NIS inside its interval), not seed 003's empty
    one."""
    from imm_gym.papers.tuned_comparison import evaluate_system

    out = evaluate_system("seed002", ["fixed"], runs=1, seed=0)
    assert out["paper"]["pos_rmse"] == 0.3117 and out["paper"]["nis_inside"] == 0.9416
    assert out["paper"]["nees_mean"] == 5.5006 and len(out["paper"]) == 10


@pytest.mark.parametrize(
    ("policies", "tuned", "message"),
    [
        (["fixed", "tip-imm"], None, r"the policies are \['fixed', 'bbsca', 'sca'\].*'tip-imm'"),
        (["fixed", "fixed"], None, r"--policy given twice: \['fixed', 'fixed'\]"),
        (["fixed"], {"sca": "x.json"}, r"'sca' is not a tuned policy evaluated here"),
        (["bbsca"], {"bbsca": "two"}, r"tuned bank has 2 Q scales for 3 models"),
    ],
)
def test_a_system_comparison_refuses_before_any_run(policies, tuned, message, tmp_path) -> None:
    """An unknown policy, one given twice, a tuned file no policy loads, a bank of two factors
    for seed 003's three models: refused by name."""
    from imm_gym.papers.tuned_comparison import evaluate_system
    from imm_gym.papers.tuning import TunedBank

    if tuned and tuned.get("bbsca") == "two":
        path = tmp_path / "two.json"
        TunedBank("seed003", (1.0, 2.0)).save(path)
        tuned = {"bbsca": str(path)}
    with pytest.raises(ConfigError, match=message):
        evaluate_system("seed003", policies, runs=1, seed=0, tuned=tuned)


def test_a_failed_run_is_counted() -> None:
    """A run whose measurements jump to 1e200 m fails (flagged, not raised): the metrics count
    one failed run of two."""
    imm, family, sensor, tpm = system_setup("seed003")
    batch = draw(family, sensor, 2, 1)
    z = batch.measurements.z.copy()
    z[0, 5:8] = 1e200
    broken = dataclasses.replace(batch, measurements=dataclasses.replace(batch.measurements, z=z))
    result = run_bank(imm, broken, tpm)
    assert result.failed.tolist() == [True, False]
    assert score_run(result, broken, sensor.dim_z)["failed"] == 1


def test_every_failed_run_is_counted() -> None:
    """Two runs of three broken (measurements jumping to 1e200 m): ``failed`` counts both, not
    whether any failed."""
    imm, family, sensor, tpm = system_setup("seed003")
    batch = draw(family, sensor, 3, 1)
    z = batch.measurements.z.copy()
    z[[0, 2], 5:8] = 1e200
    broken = dataclasses.replace(batch, measurements=dataclasses.replace(batch.measurements, z=z))
    result = run_bank(imm, broken, tpm)
    assert result.failed.tolist() == [True, False, True]
    assert score_run(result, broken, sensor.dim_z)["failed"] == 2
