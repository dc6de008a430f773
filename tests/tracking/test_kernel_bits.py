"""Issue #19: what the faster kernel entry must keep exactly.

The kernel's outputs are held bit for bit against the previous revision by
``benchmarks/bench_kernel.py --baseline``; here: the frozen results built without their
``__init__`` are the dataclasses' own, and a diverged tracker in the middle of a block leaves the
others' outputs bit for bit as they are alone (the block's outputs are written lane by lane, the
failed trackers' NaN after).
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from imm_gym import (
    IMM,
    PositionSensor,
    RandomFamily,
    Sonar,
    draw_batch,
    paper_bank,
    paper_scenario,
    stay_tpm,
)
from imm_gym.tracking.imm import IMMState, IMMStep, _new_state, _new_step
from imm_gym.tracking.kernels import imm as kernel


def test_results_built_without_init_are_the_dataclasses() -> None:
    arrays = [np.full(2, float(k)) for k in range(10)]
    step = _new_step(*arrays)
    assert set(vars(step)) == {f.name for f in fields(IMMStep)}
    assert step == IMMStep(*arrays)
    assert step.z_pred is None
    state = _new_state(*arrays[:3])
    assert set(vars(state)) == {f.name for f in fields(IMMState)}
    assert state == IMMState(*arrays[:3])


def test_failed_tracker_leaves_the_block_unchanged() -> None:
    for filt in ("ukf", "ukf-cholesky", "ekf"):
        imm = IMM(paper_bank(), Sonar(), filter=filt)
        n = 40  # two blocks
        batch = draw_batch(paper_scenario(), Sonar(), n, 3)
        state = imm.init(batch.x0, batch.P0)
        tpm = stay_tpm(3, 0.99)
        detected = np.arange(n) % 5 != 0
        for k in range(1, 6):
            state, _ = imm.step(state, tpm, batch.measurements.z[:, k])
        P = state.P.copy()
        P[7] = np.nan  # diverged
        bad = IMMState(state.x, P, state.mu)
        z = batch.measurements.z[:, 6]
        post, out = imm.step(bad, tpm, z, detected, allow_failure=True)
        assert out.failed.tolist() == [t == 7 for t in range(n)]
        assert np.isnan(out.x[7]).all() and np.isnan(post.P[7]).all()
        keep = np.arange(n) != 7
        sub = IMMState(state.x[keep], state.P[keep], state.mu[keep])
        post_ok, out_ok = imm.step(sub, tpm, z[keep], detected[keep])
        for a, b in (
            (post.x[keep], post_ok.x),
            (post.P[keep], post_ok.P),
            (post.mu[keep], post_ok.mu),
            (out.x[keep], out_ok.x),
            (out.P[keep], out_ok.P),
            (out.cbar[keep], out_ok.cbar),
            (out.loglik[keep], out_ok.loglik),
            (out.model_nis[keep], out_ok.model_nis),
            (out.innovation[keep], out_ok.innovation),
            (out.nis[keep], out_ok.nis),
        ):
            assert a.tobytes() == b.tobytes()


@pytest.mark.parametrize("filt", ["ukf", "ekf"])
@pytest.mark.parametrize("n", [1, 6])
def test_numpy_engine_flags_a_failed_tracker_as_the_compiled_one(filt: str, n: int) -> None:
    """With ``allow_failure`` the numpy reference flags the tracker whose cycle fails (NaN
    outputs) and gives the others their own cycle's numbers, as the compiled engine does;
    without it, it raises."""
    batch = draw_batch(paper_scenario(), Sonar(), n, 3)
    z, tpm = batch.measurements.z[:, 1], stay_tpm(3, 0.95)
    detected = np.arange(n) % 4 != 1
    steps = {}
    for engine in ("numpy", "compiled"):
        imm = IMM(paper_bank(), Sonar(), filter=filt, engine=engine)
        state = imm.init(batch.x0, batch.P0)
        P = state.P.copy()
        P[n - 1] = np.nan
        bad = IMMState(state.x, P, state.mu)
        steps[engine] = imm.step(bad, tpm, z, detected, allow_failure=True)
        with pytest.raises(np.linalg.LinAlgError):
            imm.step(bad, tpm, z, detected)
    (post, out), (post_c, out_c) = steps["numpy"], steps["compiled"]
    assert out.failed.tolist() == out_c.failed.tolist() == [t == n - 1 for t in range(n)]
    assert out.detected.tolist() == detected.tolist()
    for a, b in ((post.x, post_c.x), (post.P, post_c.P), (post.mu, post_c.mu), (out.x, out_c.x),
                 (out.P, out_c.P), (out.mode_probs, out_c.mode_probs), (out.nis, out_c.nis),
                 (out.loglik, out_c.loglik), (out.innovation, out_c.innovation)):
        assert a.shape == b.shape
        assert np.isnan(a[n - 1]).all() and np.isnan(b[n - 1]).all()
        np.testing.assert_allclose(a[: n - 1], b[: n - 1], rtol=1e-7, atol=1e-9)


def test_one_tracker_alone_equals_its_lane_in_a_block() -> None:
    """The single-tracker path (``kernels.imm.imm_step_one``, which ``IMM.step`` takes at N = 1
    through ``checked_step_one``:
    the cycle compiled for one tracker of three models, four states, a 2-D measurement) gives
    each tracker the numbers its lane gets in a block of the general path, bit for bit: every
    output, each step, with missed detections, for both filters and both sensors, and a
    diverged tracker alone."""
    n = 7
    for filt in ("ukf", "ukf-cholesky", "ekf"):
        for sensor in (Sonar(), PositionSensor(sigma_pos=30.0)):
            imm = IMM(paper_bank(), sensor, filter=filt)
            batch = draw_batch(paper_scenario(), sensor, n, 5)
            state = imm.init(batch.x0, batch.P0)
            tpm = np.stack([stay_tpm(3, s) for s in np.linspace(0.4, 0.99, n)])
            detected = np.arange(n) % 3 != 1
            for k in range(1, 9):
                z = batch.measurements.z[:, k]
                post, out = imm.step(state, tpm, z, detected if k % 2 else None)
                for t in range(n):
                    alone = IMMState(state.x[t:t + 1], state.P[t:t + 1], state.mu[t:t + 1])
                    det = detected[t:t + 1] if k % 2 else None
                    post1, out1 = imm.step(alone, tpm[t:t + 1], z[t:t + 1], det)
                    for a, b in zip(_arrays(post, out), _arrays(post1, out1), strict=True):
                        assert a[t:t + 1].tobytes() == b.tobytes()
                state = post
            P = state.P[:1].copy()
            P[0, 1] = np.nan
            _, out1 = imm.step(IMMState(state.x[:1], P, state.mu[:1]), tpm[:1],
                               batch.measurements.z[:1, 9], allow_failure=True)
            assert out1.failed.tolist() == [True] and np.isnan(out1.x).all()


def _arrays(state: IMMState, out: IMMStep) -> list[np.ndarray]:
    return [state.x, state.P, state.mu, out.x, out.P, out.mode_probs, out.cbar, out.loglik,
            out.model_nis, out.innovation, out.nis, out.failed]


def test_one_tracker_entry_refuses_other_shapes() -> None:
    """``imm_step_one`` and ``checked_step_one`` have their sizes compiled in: two trackers are
    refused, not misread."""
    imm = IMM(paper_bank(), Sonar())
    batch = draw_batch(paper_scenario(), Sonar(), 2, 0)
    state = imm.init(batch.x0, batch.P0)
    N, M, n = state.x.shape
    assert kernel.fits_one(1, M, n, 2) and not kernel.fits_one(N, M, n, 2)
    outs = (np.empty((N, M, n)), np.empty((N, M, n, n)), *(np.empty((N, M)) for _ in range(4)),
            np.empty((N, M, 2)), np.empty(N), np.empty((N, n)), np.empty((N, n, n)),
            np.empty(N, dtype=bool))
    tpm = np.broadcast_to(stay_tpm(M, 0.9), (N, M, M)).copy()
    z = np.ascontiguousarray(batch.measurements.z[:, 1])  # the cached variant: no compile
    with pytest.raises(ValueError, match="one tracker"):
        kernel.imm_step_one(state.x, state.P, state.mu, tpm, z,
                            np.ones(N, dtype=bool), *imm.kernel_args, True, *outs)
    with pytest.raises(ValueError, match="one tracker"):
        kernel.checked_step_one(state.x, state.P, state.mu, tpm, z,
                                np.ones(N, dtype=bool), kernel.pack_one(*imm.kernel_args), -1.0,
                                *outs)


def test_packed_entry_equals_the_one_tracker_kernel() -> None:
    """``checked_step_one`` (what ``IMM.step`` calls for one tracker: the bank's constants
    packed by ``pack_one``, the inputs checked in the same call) gives ``imm_step_one``'s
    outputs bit for bit, with and without the check, for every filter and both sensors."""
    for filt in ("ukf", "ukf-cholesky", "ekf"):
        for sensor in (Sonar(), PositionSensor(sigma_pos=30.0)):
            imm = IMM(paper_bank(), sensor, filter=filt)
            batch = draw_batch(paper_scenario(), sensor, 1, 3)
            state = imm.init(batch.x0, batch.P0)
            tpm = stay_tpm(3, 0.9)[None].copy()
            for k in range(1, 6):
                z = np.ascontiguousarray(batch.measurements.z[:, k])
                detected = np.array([k != 3])
                ref = _outs(1)
                kernel.imm_step_one(state.x, state.P, state.mu, tpm, z, detected,
                                    *imm.kernel_args, True, *ref)
                for tol in (0.5e-8, -1.0):
                    outs = _outs(1)
                    code = kernel.checked_step_one(state.x, state.P, state.mu, tpm, z, detected,
                                                   kernel.pack_one(*imm.kernel_args), tol, *outs)
                    assert code == 0
                    for a, b in zip(outs, ref, strict=True):
                        assert a.tobytes() == b.tobytes()
                state = IMMState(ref[0], ref[1], ref[2])


def _outs(N: int, M: int = 3, n: int = 4) -> tuple[np.ndarray, ...]:
    return (np.empty((N, M, n)), np.empty((N, M, n, n)), *(np.empty((N, M)) for _ in range(4)),
            np.empty((N, M, 2)), np.empty(N), np.empty((N, n)), np.empty((N, n, n)),
            np.empty(N, dtype=bool))


def test_packing_refuses_other_banks() -> None:
    """``pack_one`` packs banks of the single-tracker shape only; ``IMM`` packs none for others."""
    imm = IMM(paper_bank(), Sonar())
    F, Q, R, *rest = imm.kernel_args
    with pytest.raises(ValueError, match="shape"):
        kernel.pack_one(F[:, :2], Q[:, :2], R, *rest)
    assert imm._bank_one is not None
    assert IMM(paper_bank()[:2], Sonar())._bank_one is None
    assert IMM(paper_bank(), Sonar(), engine="numpy")._bank_one is None


@pytest.mark.parametrize("engine", ["compiled", "numpy"])
@pytest.mark.parametrize("filt", ["ukf", "ukf-cholesky", "ekf"])
@pytest.mark.parametrize("n", [1, 3])
def test_a_cycle_whose_outputs_are_not_finite_is_failed(engine: str, filt: str, n: int) -> None:
    """A measurement of 1e160 m overflows every model's NIS: each likelihood is 0 and the mode
    probabilities 0/0. The innovation covariances are positive definite, yet the cycle failed:
    it is flagged (NaN outputs) or raises, as a lost positive definiteness is, and the other
    trackers get their own numbers (bit for bit in the compiled kernel's lanes)."""
    batch = draw_batch(paper_scenario(), Sonar(), n, 4)
    imm = IMM(paper_bank(), Sonar(), filter=filt, engine=engine)
    state = imm.init(batch.x0, batch.P0)
    z = batch.measurements.z[:, 1].copy()
    z[n - 1, 0] = 1e160
    tpm = stay_tpm(3, 0.95)
    post, out = imm.step(state, tpm, z, allow_failure=True)
    assert out.failed.tolist() == [t == n - 1 for t in range(n)]
    for a in (post.x, post.P, post.mu, out.x, out.P, out.mode_probs, out.nis):
        assert np.isnan(a[n - 1]).all()
    with pytest.raises(np.linalg.LinAlgError), np.errstate(all="ignore"):
        imm.step(state, tpm, z)
    if n > 1:
        keep = slice(0, n - 1)
        _, alone = imm.step(IMMState(state.x[keep], state.P[keep], state.mu[keep]), tpm, z[keep])
        if engine == "compiled":  # lanes do not interact
            assert out.x[keep].tobytes() == alone.x.tobytes()
        else:  # the reference reran tracker by tracker: numpy's products round by batch size
            np.testing.assert_allclose(out.x[keep], alone.x, rtol=1e-12)


@pytest.mark.parametrize("engine", ["compiled", "numpy"])
def test_an_overflowing_covariance_is_failed(engine: str) -> None:
    """An EKF started with a covariance of 1e160 m² overflows its innovation covariance's
    determinant to inf (which passes ``det > 0``) and every likelihood to 0: failed, not NaN
    outputs with ``failed`` False."""
    batch = draw_batch(paper_scenario(), Sonar(), 2, 4)
    P0 = batch.P0.copy()
    P0[1] *= 1e156
    imm = IMM(paper_bank(), Sonar(), filter="ekf", engine=engine)
    _, out = imm.step(imm.init(batch.x0, P0), stay_tpm(3, 0.95), batch.measurements.z[:, 1],
                      allow_failure=True)
    assert out.failed.tolist() == [False, True]
    assert np.isfinite(out.x[0]).all() and np.isnan(out.x[1]).all()


@pytest.mark.parametrize("engine", ["compiled", "numpy"])
def test_a_negative_definite_innovation_covariance_is_failed(engine: str) -> None:
    """Tracker 2's model covariances are ``-1e6 I`` (a corrupted state): its innovation covariance
    ``S = H P H^T + R`` is negative definite though its determinant is positive, so it is not
    positive definite (a 2x2 matrix is so when ``S_00 > 0`` and ``det S > 0``): the tracker is
    failed and its outputs NaN; the two others are not."""
    sensor = PositionSensor(sigma_pos=30.0)
    batch = draw_batch(RandomFamily(), sensor, 3, 5)
    imm = IMM(paper_bank(), sensor, "kf", engine=engine)
    state = imm.init(batch.x0, batch.P0)
    P = state.P.copy()
    P[2] = -1e6 * np.eye(4)
    S = P[2, 0, :2, :2] + sensor.R[:2, :2]
    assert S[0, 0] < 0 and np.linalg.det(S) > 0
    with np.errstate(all="ignore"):
        post, out = imm.step(
            IMMState(state.x, P, state.mu), np.full((3, 3), 1 / 3), batch.measurements.z[:, 1],
            allow_failure=True,
        )
    assert out.failed.tolist() == [False, False, True]
    for a in (post.x, post.P, post.mu, out.x, out.P, out.mode_probs, out.loglik):
        assert np.isnan(a[2]).all() and np.isfinite(a[:2]).all()


@pytest.mark.parametrize("engine", ["compiled", "numpy"])
def test_a_combined_covariance_that_overflows_alone_is_failed(engine: str) -> None:
    """Tracker 2's model 1 moves at 1e154 m/s with probability 1e-200 (identity TPM, T = 5 s, a
    missed detection): the mode probabilities and the combined estimate stay finite, but the
    combined covariance's spread term ``mu_1 (x_1 - x)(x_1 - x)^T`` is 1e-200 times a square of
    5e154 m, which overflows to inf. The combined variances are not finite, so the tracker is
    failed with NaN outputs; the two others are not."""
    batch = draw_batch(paper_scenario(), PositionSensor(), 3, 4)
    imm = IMM(paper_bank(), PositionSensor(), "kf", T=5.0, engine=engine)
    state = imm.init(batch.x0, batch.P0)
    x, mu = state.x.copy(), np.tile([0.5, 1e-200, 0.5], (3, 1))
    x[2, 1, 2] = 1e154
    with np.errstate(all="ignore"):
        _, out = imm.step(
            IMMState(x, state.P, mu), np.eye(3), batch.measurements.z[:, 1],
            detected=np.array([True, True, False]), allow_failure=True,
        )
    assert out.failed.tolist() == [False, False, True]
    for a in (out.x, out.P, out.mode_probs):
        assert np.isnan(a[2]).all() and np.isfinite(a[:2]).all()
