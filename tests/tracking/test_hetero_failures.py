"""A tracker of the heterogeneous engine that fails (:class:`imm_gym.tracking.hetero.HeteroIMM`
with ``allow_failure``): its outputs are NaN, the predicted measurement included, and the other
trackers, each with its own TPM, get the numbers they get alone."""

from __future__ import annotations

import numpy as np

from imm_gym import PositionSensor, Sonar, stay_tpm
from imm_gym.tracking.hetero import HeteroBank, HeteroIMM

ROWS = (
    stay_tpm(3, 0.95),
    np.array([[0.6, 0.3, 0.1], [0.2, 0.7, 0.1], [0.1, 0.1, 0.8]]),
    np.array([[0.5, 0.1, 0.4], [0.4, 0.5, 0.1], [0.3, 0.3, 0.4]]),
)


def test_a_failure_past_the_checks_leaves_the_others_their_own_tpms() -> None:
    """Three trackers, each with its own TPM; tracker 1's process noise (``q_scale`` 1e20) makes a
    factorization fail although its innovation covariance passed the pre-check, so that step
    runs tracker by tracker. Trackers 0 and 2 equal runs of their own, each with its TPM, and
    tracker 1's outputs are NaN from its failure on, its predicted measurement included."""
    sensor = Sonar()
    imm = HeteroIMM(HeteroBank(), sensor, T=1.0)
    truth = np.array([3000.0, 4500.0, 20.0, 15.0])
    P0 = np.diag([100.0, 100.0, 25.0, 25.0])
    tpm = np.stack(ROWS)
    q = np.ones((3, 3))
    q[1] = 1e20
    state = imm.init(np.tile(truth, (3, 1)), P0)
    alone = {i: imm.init(truth, P0) for i in (0, 2)}
    failed_at = None
    for k in range(1, 21):
        z = np.repeat(sensor.h(truth[None] + k * np.array([20.0, 15.0, 0.0, 0.0])), 3, axis=0)
        z[:, 0] += np.array([3.0, -2.0, 5.0])
        state, out = imm.step(state, tpm, z, allow_failure=True, q_scale=q)
        if failed_at is None and out.failed[1]:
            failed_at = k
        for i in (0, 2):
            alone[i], own = imm.step(alone[i], ROWS[i], z[i : i + 1])
            np.testing.assert_allclose(out.x[i], own.x[0], rtol=1e-12, err_msg=f"{i} at {k}")
            np.testing.assert_allclose(out.z_pred[i], own.z_pred[0], rtol=1e-12)
            np.testing.assert_allclose(out.mode_probs[i], own.mode_probs[0], atol=1e-13)
        if failed_at is not None:
            assert out.failed.tolist() == [False, True, False]
            assert np.isnan(out.x[1]).all() and np.isnan(out.z_pred[1]).all()
    assert failed_at is not None


def test_a_tracker_flagged_by_the_pre_check_has_no_predicted_measurement() -> None:
    """A finite innovation covariance that is not positive definite (a negative-definite ``P``)
    flags its tracker: every output NaN, the predicted measurement too (the tuner's objective
    reads it), while the other tracker's stays finite."""
    sensor = PositionSensor(sigma_pos=0.5, sigma_vel=0.5)
    imm = HeteroIMM(HeteroBank(), sensor, T=0.1)
    state = imm.init(np.tile([0.0, 0.0, 5.0, 0.0], (2, 1)), np.eye(4))
    state.P[1] = -1e3 * np.eye(state.P.shape[-1])
    _, out = imm.step(state, stay_tpm(3, 0.9), np.zeros((2, 4)), allow_failure=True)
    assert out.failed.tolist() == [False, True]
    for field in ("x", "P", "mode_probs", "nis", "z_pred"):
        value = getattr(out, field)
        assert np.isnan(value[1]).all(), field
        assert np.isfinite(value[0]).all(), field
