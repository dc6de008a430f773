"""The heterogeneous engine (:class:`imm_gym.tracking.hetero.HeteroIMM`) on missed detections:
against the classical IMM's numpy engine on the linear bank, and by hand on seed 002's bank."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import IMM, PositionSensor, Sonar, paper_bank, stay_tpm
from imm_gym.tracking.hetero import HeteroBank, HeteroIMM, linear_models

ASYMMETRIC_TPM = np.array([[0.97, 0.02, 0.01], [0.30, 0.60, 0.10], [0.05, 0.45, 0.50]])
FIELDS = ("x", "P", "mode_probs", "cbar", "loglik", "model_nis", "innovation", "nis")


def test_missed_detections_match_the_classical_imm_on_the_linear_bank() -> None:
    """CV/CT(±4°/s) with the sonar, a third of the scans missed (their measurements NaN): every
    output of every step equals the classical IMM-EKF's (numpy engine), which on a miss
    predicts only and reports ``loglik``, ``model_nis``, ``innovation`` and ``nis`` 0."""
    rng = np.random.default_rng(11)
    sensor = Sonar()
    N, K = 3, 25
    x0 = np.array(
        [[3000.0, 4000.0, 20.0, 15.0], [-2500.0, 1000.0, -5.0, 18.0], [500.0, -6000.0, 12.0, 0.0]]
    )
    P0 = np.diag([400.0, 400.0, 25.0, 25.0])
    truth = x0[:, None, :2] + np.arange(1, K + 1)[None, :, None] * x0[:, None, 2:]
    z = sensor.h(np.concatenate([truth, np.zeros((N, K, 2))], axis=-1))
    z = z + rng.normal(size=(N, K, 2)) * sensor.sigma
    detected = rng.uniform(size=(N, K)) > 1 / 3
    detected[:, 0] = False  # a miss at the first step, too
    z[~detected] = np.nan
    ref = IMM(paper_bank(), sensor, filter="ekf", engine="numpy")
    imm = HeteroIMM(linear_models(paper_bank()), sensor, T=1.0)
    mu0 = np.full(3, 1 / 3)
    s_ref, s_het = ref.init(x0, P0, mu0), imm.init(x0, P0, mu0)
    for k in range(K):
        s_ref, o_ref = ref.step(s_ref, ASYMMETRIC_TPM, z[:, k], detected[:, k])
        s_het, o_het = imm.step(s_het, ASYMMETRIC_TPM, z[:, k], detected[:, k])
        for f in FIELDS:
            a, b = getattr(o_het, f), getattr(o_ref, f)
            np.testing.assert_allclose(
                a, b, rtol=1e-9, atol=1e-9 * max(1.0, np.abs(b).max()), err_msg=f"{f} at {k}"
            )
        missed = ~detected[:, k]
        for f in ("loglik", "model_nis", "innovation", "nis"):
            np.testing.assert_array_equal(getattr(o_het, f)[missed], 0.0, err_msg=f)
    assert (~detected).sum() > 20


@pytest.mark.parametrize("sensor", [Sonar(), PositionSensor(sigma_pos=5.0, sigma_vel=1.0)])
def test_a_missed_scan_of_seed_002s_bank_leaves_the_predicted_probabilities(sensor) -> None:
    """NCV/CT/CTRA: on a missed scan the model probabilities are the predicted ones,
    ``mu_k = mu_{k-1} @ tpm`` by hand, each model's posterior its own prediction (not updated by
    the measurement's placeholder), and the measurement terms 0; a detected tracker beside it is
    updated."""
    imm = HeteroIMM(HeteroBank(), sensor, T=1.0)
    x0 = np.array([[3000.0, 4000.0, 20.0, 15.0], [3000.0, 4000.0, 20.0, 15.0]])
    state = imm.init(x0, np.diag([100.0, 100.0, 25.0, 25.0]))
    tpm = stay_tpm(3, 0.9)
    z = sensor.h(x0 + np.array([20.0, 15.0, 0.0, 0.0])) + 3.0
    _, x0s, _ = imm.mix(state, tpm)
    post, out = imm.step(state, tpm, z, detected=np.array([False, True]))
    np.testing.assert_allclose(out.mode_probs[0], state.mu[0] @ tpm, rtol=1e-12)
    assert not np.allclose(out.mode_probs[1], state.mu[1] @ tpm, rtol=1e-3)
    for j, model in enumerate(imm.models):
        n = imm.dims[j]
        x_pred, _ = model.transition(x0s[j][:1], 1.0)
        np.testing.assert_allclose(post.x[0, j, :n], x_pred[0], rtol=1e-12, atol=1e-9)
        assert np.abs(post.x[1, j, :2] - x_pred[0, :2]).max() > 1e-3
    for f in ("loglik", "model_nis", "innovation", "nis"):
        np.testing.assert_array_equal(getattr(out, f)[0], 0.0, err_msg=f)
        assert np.any(getattr(out, f)[1] != 0.0), f
