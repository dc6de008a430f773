"""The compiled IMM kernel (:mod:`imm_gym.tracking.kernels.imm`) against the numpy reference
engine to 1e-9 relative, and its per-tracker banks (``F``, ``Q``, ``R`` with a leading axis of
N) against one bank for all."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import IMM, MotionModel, PositionSensor, RandomFamily, Sonar, draw_batch, paper_bank
from imm_gym.tracking.imm import IMMState
from imm_gym.tracking.kernels import imm as kernel

FIELDS = ("x", "P", "mode_probs", "loglik", "model_nis", "nis")


def _random_tpm(rng: np.random.Generator, M: int, N: int) -> np.ndarray:
    tpm = rng.uniform(0.01, 1.0, (N, M, M)) + 20.0 * np.eye(M)
    return tpm / tpm.sum(axis=-1, keepdims=True)


@pytest.mark.parametrize(
    ("bank", "sensor", "filter_name"),
    [
        (paper_bank(), Sonar(), "ukf"),
        (paper_bank(), Sonar(), "ekf"),
        (paper_bank(), Sonar(), "ukf-cholesky"),
        (paper_bank(), Sonar(position=(500.0, -300.0)), "ukf"),
        (paper_bank(), PositionSensor(sigma_pos=30.0), "kf"),
        (paper_bank(), PositionSensor(sigma_pos=30.0, sigma_vel=2.0), "ukf"),
        (
            (MotionModel("cv"), MotionModel("ct", 3.0), MotionModel("ca", q=(0.1,) * 6)),
            PositionSensor(sigma_pos=30.0),
            "ukf",
        ),
        (
            (MotionModel("cv"), MotionModel("ct", 3.0), MotionModel("ca", q=(0.1,) * 6)),
            Sonar(),
            "ukf-cholesky",
        ),
    ],
    ids=[
        "sonar-ukf", "sonar-ekf", "sonar-ukf-cholesky", "sonar-offset", "pos-kf", "posvel-ukf",
        "ca-bank-ukf", "ca-bank-sonar-ukf-cholesky",
    ],
)
def test_compiled_equals_numpy_to_1e9(bank, sensor, filter_name: str) -> None:
    # 40 trackers (a full block and a partial one) over 40 steps with missed detections.
    N, K = 40, 40
    batch = draw_batch(RandomFamily(), sensor, N, 5)
    z = batch.measurements.z[:, 1 : K + 1]
    rng = np.random.default_rng(6)
    det = rng.random(z.shape[:2]) < 0.9
    tpm = _random_tpm(rng, len(bank), N)
    imms = [IMM(bank, sensor, filter_name, engine=e) for e in ("numpy", "compiled")]
    ref, got = (imm.run(z, tpm, batch.x0, batch.P0, detected=det) for imm in imms)
    for f in FIELDS:
        a, b = getattr(ref, f), getattr(got, f)
        # relative to each quantity's scale over the run (a velocity near 0 is a difference)
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9 * np.abs(a).max(), err_msg=f)

@pytest.mark.parametrize("T", [0.5, 5.0])
def test_compiled_equals_numpy_near_the_sonar_from_a_degenerate_start(T: float) -> None:
    """A target 63 m from the sonar, ``P0`` with repeated eigenvalues (the start's velocity block
    ``25 I``): the engines round ``P`` differently, and with the sigma points the columns of
    ``U sqrt(S)`` one IMM step differed by 4.6 m at T = 5 s; with the symmetric root they agree
    to rounding."""
    x, z = np.array([60.0, 20.0, 10.0, -5.0]), np.array([55.0, 0.4])
    P = np.diag([400.0, 400.0, 25.0, 25.0])
    out = []
    for engine in ("numpy", "compiled"):
        imm = IMM(paper_bank(), Sonar(), "ukf", T=T, engine=engine)
        state = imm.init(np.tile(x, (3, 1)), P)
        _, step = imm.step(state, _random_tpm(np.random.default_rng(0), 3, 3), np.tile(z, (3, 1)))
        out.append(step)
    np.testing.assert_allclose(out[1].x, out[0].x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(out[1].mode_probs, out[0].mode_probs, rtol=0, atol=1e-12)


@pytest.mark.parametrize("filter_name", ["ukf", "ukf-cholesky", "ekf"])
def test_bank_per_tracker_equals_each_trackers_own_bank(filter_name: str) -> None:
    # B = N: trackers at their own sampling period and sensor noise, each bit for bit what the
    # B = 1 kernel of its own bank gives it.
    N = 37
    rng = np.random.default_rng(8)
    sonars = (Sonar(), Sonar(sigma_r=80.0, sigma_theta_deg=0.1))
    imms = [IMM(paper_bank(), s, filter_name, T=T) for s, T in zip(sonars, (1.0, 2.5), strict=True)]
    which = rng.random(N) < 0.5
    batch = draw_batch(RandomFamily(), Sonar(), N, 9)
    state = imms[0].init(batch.x0, batch.P0)
    tpm = _random_tpm(rng, 3, N)
    z = np.ascontiguousarray(batch.measurements.z[:, 1])  # as IMM.step passes it
    det = rng.random(N) < 0.8
    args = [imm.kernel_args for imm in imms]
    F = np.where(which[:, None, None, None], args[1][0], args[0][0])
    Q = np.where(which[:, None, None, None], args[1][1], args[0][1])
    R = np.where(which[:, None, None], args[1][2], args[0][2])
    M, n = 3, imms[0].n
    outs = [
        np.empty((N, M, n)), np.empty((N, M, n, n)), *(np.empty((N, M)) for _ in range(4)),
        np.empty((N, M, 2)), np.empty(N), np.empty((N, n)), np.empty((N, n, n)),
        np.empty(N, dtype=bool),
    ]  # fmt: skip
    failures = kernel.imm_step(
        state.x, state.P, state.mu, tpm, z, det, F, Q, R, *args[0][3:], True, *outs
    )
    assert failures == 0
    for k, imm in enumerate(imms):
        rows = np.flatnonzero(which == bool(k))
        sub = IMMState(state.x[rows], state.P[rows], state.mu[rows])
        s, o = imm.step(sub, tpm[rows], z[rows], det[rows])
        own = (s.x, s.P, o.mode_probs, o.cbar, o.loglik, o.model_nis, o.innovation, o.nis, o.x, o.P)
        for a, b in zip(outs[:10], own, strict=True):
            np.testing.assert_array_equal(a[rows], b)
    # the two banks differ, and so do their steps from the same state
    _, o0 = imms[0].step(state, tpm, z, det)
    assert not np.allclose(o0.x[which], outs[8][which])


def test_atan2_matches_numpy() -> None:
    rng = np.random.default_rng(1)
    y = np.concatenate([rng.normal(0, 1, 4000), rng.normal(0, 1e4, 4000), [0.0, 1.0, -1.0, 0.0]])
    x = np.concatenate([rng.normal(0, 1, 4000), rng.normal(0, 1e-3, 4000), [1.0, 0.0, 0.0, -1.0]])
    got = np.array([kernel._atan2(a, b) for a, b in zip(y, x, strict=True)])
    np.testing.assert_allclose(got, np.arctan2(y, x), rtol=4e-16, atol=1e-300)


def test_an_unreachable_model_mixes_with_the_mode_probabilities_in_both_engines() -> None:
    """A TPM whose last column is 0 makes model 2 unreachable (``cbar_2 = 0``, log-probability
    -inf): both engines step without failing and agree to 1e-9, model 2 ends at probability 0, and
    its mixed start is the documented fallback ``x0_2 = sum_i mu_i x_i``, ``P0_2 = sum_i mu_i
    [P_i + (x_i - x0_2)(x_i - x0_2)^T]`` (mixing weights ``mu`` when ``cbar_j`` is 0), which a
    missed detection carries through model 2's prediction ``F x0_2``, ``F P0_2 F^T + Q``,
    computed here by hand from the models' spread states."""
    N = 40
    sensor = Sonar()
    batch = draw_batch(RandomFamily(), sensor, N, 5)
    rng = np.random.default_rng(12)
    imms = [IMM(paper_bank(), sensor, "ukf", engine=e) for e in ("numpy", "compiled")]
    # one ordinary step first, so that the models' estimates and probabilities differ
    state, _ = imms[0].step(
        imms[0].init(batch.x0, batch.P0), _random_tpm(rng, 3, N), batch.measurements.z[:, 1]
    )
    tpm = np.array([[0.9, 0.1, 0.0], [0.1, 0.9, 0.0], [0.5, 0.5, 0.0]])
    det = rng.random(N) < 0.5
    steps = [imm.step(state, tpm, batch.measurements.z[:, 2], det) for imm in imms]
    (ref_state, ref), (got_state, got) = steps
    assert not ref.failed.any() and not got.failed.any()
    for f in FIELDS:
        a, b = getattr(ref, f), getattr(got, f)
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9 * np.abs(a).max(), err_msg=f)
    for a, b, f in ((ref_state.x, got_state.x, "state.x"), (ref_state.P, got_state.P, "state.P")):
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9 * np.abs(a).max(), err_msg=f)
    assert np.all(ref.mode_probs[:, 2] == 0.0) and np.all(got.mode_probs[:, 2] == 0.0)
    model = paper_bank()[2]
    F, Q = model.transition_matrix(1.0, 4), model.noise_covariance(4, 1.0)
    for n in np.flatnonzero(~det):
        mu, x, P = state.mu[n], state.x[n], state.P[n]
        x0 = sum(mu[i] * x[i] for i in range(3))
        P0 = sum(mu[i] * (P[i] + np.outer(x[i] - x0, x[i] - x0)) for i in range(3))
        for s in (ref_state, got_state):
            np.testing.assert_allclose(s.x[n, 2], F @ x0, rtol=1e-9, atol=1e-6)
            np.testing.assert_allclose(s.P[n, 2], F @ P0 @ F.T + Q, rtol=1e-9, atol=1e-6)
