"""The seed systems (:mod:`imm_gym.papers.systems`) against their module docstring and by hand:
the seed-003 bank, sensor and TPM, a batch's seeds and track start, the metrics of a bank run with
missed detections."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym.papers.systems import (
    bbsca_imm,
    bbsca_models,
    bbsca_sensor,
    draw,
    system_setup,
)
from imm_gym.scenarios.profiles import ManeuverFamily
from imm_gym.seeding import streams


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
