r"""Compiled fast path of the IMM cycle for the built-in sensors (numba).

:class:`imm_gym.tracking.imm.IMM` runs one of two engines with the same equations:

* ``"numpy"`` — the vectorized reference in :mod:`imm_gym.tracking.imm` and
  :mod:`imm_gym.tracking.filters`; works with any sensor that implements
  :class:`imm_gym.tracking.filters.MeasurementModel`;
* ``"compiled"`` — this module: the whole cycle (mix, predict, update, likelihood, probability
  update, combination, NIS) fused into one compiled loop over the trackers, for
  :class:`~imm_gym.Sonar` and :class:`~imm_gym.PositionSensor`. Small 4x4 blocks make numpy's
  per-call overhead dominate; the fused loop is 10-30x faster at N = 1 and several times faster at
  N = 1024.

The tests run both engines on the same inputs and require the same numbers (to rounding).

Sensor codes: ``RANGE_BEARING`` (``h = [|p - s|, atan2]``, params = sensor position ``s``),
``LINEAR`` (``h = x[:m]``). Filter codes: ``UKF``, ``EKF`` (the Kalman filter is the EKF of a
linear sensor).
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.linalg import JACOBI_MAX_SWEEPS, LOG_2PI, jacobi_eig_lanes

Array = NDArray[np.float64]

RANGE_BEARING = 0
LINEAR = 1
UKF = 0
EKF = 1

# fmt: off

_TINY = 1e-300
_TWO_PI = 2.0 * np.pi
#: Trackers per block of :func:`imm_step`: the block's M predicted covariances per tracker are
#: diagonalized together, one SIMD lane each (:func:`imm_gym.tracking.linalg.jacobi_eig_lanes`).
TRACKER_BLOCK = 32


def sensor_spec(sensor: object) -> tuple[int, Array] | None:
    """``(kind, params)`` of a built-in sensor for the kernel, or ``None`` for any other."""
    from imm_gym.tracking.sensors import PositionSensor, Sonar

    if isinstance(sensor, Sonar):
        return RANGE_BEARING, np.array(sensor.position, dtype=np.float64)
    if isinstance(sensor, PositionSensor):
        return LINEAR, np.zeros(2)
    return None


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _wrap(a: float) -> float:  # pragma: no cover
    """Angle wrapped to (-pi, pi], as :func:`imm_gym.tracking.linalg.wrap_angle`.

    Differences of two wrapped angles lie in (-2 pi, 2 pi): one shift suffices there, without the
    cost of a floating-point modulo; other values take the general formula.
    """
    if -np.pi < a <= np.pi:
        return a
    if np.pi < a <= 3.0 * np.pi:
        return a - _TWO_PI
    if -3.0 * np.pi < a <= -np.pi:
        return a + _TWO_PI
    w = np.pi - np.mod(np.pi - a, _TWO_PI)
    return w + _TWO_PI if w <= -np.pi else w


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _h(kind: int, params: Array, x: Array, j: int, out: Array) -> None:  # pragma: no cover
    """Measurement function of the sensor ``kind`` at state ``x[j]``."""
    if kind == RANGE_BEARING:
        dx = x[j, 0] - params[0]
        dy = x[j, 1] - params[1]
        out[0] = np.sqrt(dx * dx + dy * dy)
        out[1] = np.arctan2(dy, dx)
    else:
        for i in range(out.shape[0]):
            out[i] = x[j, i]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _jacobian(kind: int, params: Array, x: Array, j: int, H: Array) -> None:  # pragma: no cover
    """``H = dh/dx`` at ``x[j]`` (``(m, n)``)."""
    H[:, :] = 0.0
    if kind == RANGE_BEARING:
        dx = x[j, 0] - params[0]
        dy = x[j, 1] - params[1]
        r2 = max(dx * dx + dy * dy, 1e-12)
        r = np.sqrt(r2)
        H[0, 0] = dx / r
        H[0, 1] = dy / r
        H[1, 0] = -dy / r2
        H[1, 1] = dx / r2
    else:
        for i in range(H.shape[0]):
            H[i, i] = 1.0


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _inv_logdet(S: Array, S_inv: Array, L: Array) -> tuple[float, bool]:  # pragma: no cover
    """Inverse and log-determinant of the SPD ``S`` by Cholesky; returns ``(logdet, ok)``."""
    m = S.shape[0]
    for i in range(m):
        for j in range(i + 1):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                if not acc > 0.0:
                    return 0.0, False
                L[i, i] = np.sqrt(acc)
            else:
                L[i, j] = acc / L[j, j]
    logdet = 0.0
    for i in range(m):
        logdet += 2.0 * np.log(L[i, i])
    # S^-1 = L^-T L^-1, column by column: solve L y = e_c, then L^T x = y.
    for c in range(m):
        for i in range(m):
            acc = 1.0 if i == c else 0.0
            for k in range(i):
                acc -= L[i, k] * S_inv[k, c]
            S_inv[i, c] = acc / L[i, i]
        for i in range(m - 1, -1, -1):
            acc = S_inv[i, c]
            for k in range(i + 1, m):
                acc -= L[k, i] * S_inv[k, c]
            S_inv[i, c] = acc / L[i, i]
    return logdet, True


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _ukf_moments_lanes(
    xp: Array,
    s: Array,
    U: Array,
    lanes: int,
    kind: int,
    params: Array,
    wm: Array,
    wc: Array,
    gamma: float,
    zp: Array,
    S: Array,
    C: Array,
    O: Array,
    Z: Array,
) -> None:  # pragma: no cover
    """SVD-UKF predicted measurements ``zp[:, l]``, spreads of the predicted measurement
    ``S[:, :, l]`` (the innovation covariance without ``R``, added per tracker by
    :func:`_from_lanes`) and cross covariances ``C[:, :, l]`` of the lanes ``l < lanes`` (one
    model of one tracker each).

    Sigma offsets ``O_0 = 0``, ``O_{1+i} = -O_{1+n+i} = gamma sqrt|s_i| U_{:, i}`` from the
    eigendecomposition ``Pp = U diag(s) U^T`` of the predicted covariance (lane ``l`` of
    :func:`jacobi_eig_lanes`'s output; ``xp[l]`` the predicted state), ``Z_k = h(xp + O_k) -
    h(xp)`` (bearing wrapped: averaged as residuals about the centre point),
    ``zp = h(xp) + sum_k wm_k Z_k``, ``S = sum_k wc_k dZ_k dZ_k^T``,
    ``C = sum_k wc_k O_k dZ_k^T`` with ``dZ_k = Z_k - sum_k wm_k Z_k``. Lane by lane the
    operations and their order are those of a single model; each step is a loop over the lanes
    (``O``, ``Z``: ``(2n+1, n, L)``, ``(2n+1, m, L)`` scratch), vectorized except ``atan2``.
    """
    n = xp.shape[1]
    m = zp.shape[0]
    L = 2 * n + 1
    for c in range(n):
        for lane in range(lanes):
            O[0, c, lane] = 0.0
    for i in range(n):
        for lane in range(lanes):
            scale = gamma * np.sqrt(abs(s[i, i, lane]))
            for c in range(n):
                O[1 + i, c, lane] = scale * U[c, i, lane]
                O[1 + n + i, c, lane] = -scale * U[c, i, lane]
    # Z holds h(sigma point) minus h(centre), bearing wrapped
    for k in range(L):
        if kind == RANGE_BEARING:
            for lane in range(lanes):
                dx = xp[lane, 0] + O[k, 0, lane] - params[0]
                dy = xp[lane, 1] + O[k, 1, lane] - params[1]
                Z[k, 0, lane] = np.sqrt(dx * dx + dy * dy)
            for lane in range(lanes):
                dx = xp[lane, 0] + O[k, 0, lane] - params[0]
                dy = xp[lane, 1] + O[k, 1, lane] - params[1]
                Z[k, 1, lane] = np.arctan2(dy, dx)
        else:
            for d in range(m):
                for lane in range(lanes):
                    Z[k, d, lane] = xp[lane, d] + O[k, d, lane]
    for k in range(L - 1, -1, -1):
        for d in range(m):
            for lane in range(lanes):
                Z[k, d, lane] -= Z[0, d, lane]
        if kind == RANGE_BEARING:
            for lane in range(lanes):
                Z[k, 1, lane] = _wrap(Z[k, 1, lane])
    for d in range(m):
        for lane in range(lanes):
            zp[d, lane] = 0.0
        for k in range(L):
            for lane in range(lanes):
                zp[d, lane] += wm[k] * Z[k, d, lane]
        for k in range(L):
            for lane in range(lanes):
                Z[k, d, lane] -= zp[d, lane]
    # zp = h(centre) + mean residual
    for lane in range(lanes):
        if kind == RANGE_BEARING:
            dx = xp[lane, 0] - params[0]
            dy = xp[lane, 1] - params[1]
            zp[0, lane] = np.sqrt(dx * dx + dy * dy) + zp[0, lane]
            zp[1, lane] = _wrap(np.arctan2(dy, dx) + zp[1, lane])
        else:
            for d in range(m):
                zp[d, lane] += xp[lane, d]
    for r in range(m):
        for c in range(r, m):
            for lane in range(lanes):
                S[r, c, lane] = 0.0
            for k in range(L):
                for lane in range(lanes):
                    S[r, c, lane] += wc[k] * Z[k, r, lane] * Z[k, c, lane]
    for r in range(n):
        for c in range(m):
            for lane in range(lanes):
                C[r, c, lane] = 0.0
            for k in range(1, L):
                for lane in range(lanes):
                    C[r, c, lane] += wc[k] * O[k, r, lane] * Z[k, c, lane]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _from_lanes(
    zp_l: Array, S_l: Array, C_l: Array, R: Array, lane: int, j: int, zp: Array, S: Array,
    C: Array,
) -> None:  # pragma: no cover
    """Model ``j``'s ``zp[j]``, ``S[j] = S_l + (R + R^T) / 2``, ``C`` from lane ``lane`` of
    :func:`_ukf_moments_lanes`'s outputs (``R``: the tracker's measurement noise)."""
    n, m = C.shape
    for r in range(m):
        zp[j, r] = zp_l[r, lane]
        for c in range(r, m):
            S[j, r, c] = S_l[r, c, lane] + 0.5 * (R[r, c] + R[c, r])
            S[j, c, r] = S[j, r, c]
    for r in range(n):
        for c in range(m):
            C[r, c] = C_l[r, c, lane]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _ekf_moments(
    xp: Array,
    Pp: Array,
    b: int,
    kind: int,
    params: Array,
    R: Array,
    j: int,
    zp: Array,
    S: Array,
    C: Array,
    H: Array,
    h: Array,
) -> None:  # pragma: no cover
    """EKF predicted measurement ``zp[j] = h(xp[b, j])``, ``S[j] = H Pp[b, j] H^T + R`` and
    ``C = Pp[b, j] H^T`` of model ``j`` of the block's tracker ``b``."""
    n = xp.shape[2]
    m = zp.shape[1]
    _h(kind, params, xp[b], j, h)
    for d in range(m):
        zp[j, d] = h[d]
    _jacobian(kind, params, xp[b], j, H)
    for r in range(n):
        for c in range(m):
            acc = 0.0
            for k in range(n):
                acc += Pp[b, j, r, k] * H[c, k]
            C[r, c] = acc
    for r in range(m):
        for c in range(r, m):
            acc = 0.0
            for k in range(n):
                acc += H[r, k] * C[k, c]
            S[j, r, c] = acc + 0.5 * (R[r, c] + R[c, r])
            S[j, c, r] = S[j, r, c]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def imm_step(
    x: Array,
    P: Array,
    mu: Array,
    tpm: Array,
    z: Array,
    detected: NDArray[np.bool_],
    F: Array,
    Q: Array,
    R: Array,
    sensor_kind: int,
    sensor_params: Array,
    filter_kind: int,
    wm: Array,
    wc: Array,
    gamma: float,
    mixture_nis: bool,
    x_out: Array,
    P_out: Array,
    mu_out: Array,
    cbar_out: Array,
    loglik_out: Array,
    model_nis_out: Array,
    innov_out: Array,
    nis_out: Array,
    xhat_out: Array,
    Phat_out: Array,
    failed_out: NDArray[np.bool_],
) -> int:  # pragma: no cover
    """One IMM cycle for N trackers (shapes as :meth:`imm_gym.tracking.imm.IMM.step`).

    Returns the number of trackers whose innovation covariance was not positive definite (a
    diverged tracker); those are flagged in ``failed_out`` and their outputs filled with NaN, the
    others are unaffected.

    ``tpm`` is ``(N, M, M)`` (a broadcast view is fine). ``F``, ``Q`` (``(B, M, n, n)``) and
    ``R`` (``(B, m, m)``) hold one bank per tracker (``B = N``: trackers at their own sampling
    period and sensor noise) or one for all (``B = 1``). Per tracker: mixing (SPEC §1 step 1),
    ``x = F x0``, ``P = F P0 F^T + Q``, the UKF or EKF update (Joseph form for the EKF), the
    log-domain probability update, the combination with the spread term, and (with
    ``mixture_nis``; else ``nis_out`` is 0) the NIS of the moment-matched predicted measurement
    mixture.

    The trackers run in blocks of ``TRACKER_BLOCK``: the block's mixing and predictions first,
    then the UKF's eigendecompositions of all its ``TRACKER_BLOCK * M`` predicted covariances
    in one vectorized Jacobi call (one SIMD lane per matrix), then tracker by tracker the rest.
    Every tracker's numbers are those it would get alone (the Jacobi lanes do not interact).
    """
    N, M, n = x.shape
    m = z.shape[1]
    L = 2 * n + 1
    x0 = np.empty((M, n))
    P0 = np.empty((M, n, n))
    w = np.empty(M)
    spread = np.empty((M, n))
    FP = np.empty((n, n))
    B = min(N, TRACKER_BLOCK)  # rows of the block arrays (a small batch allocates less)
    cbar = np.empty((B, M))
    xp = np.empty((B, M, n))
    Pp = np.empty((B, M, n, n))
    eig = np.empty((n, n, B * M))
    U = np.empty((n, n, B * M))
    xp_lanes = xp.reshape(B * M, n)  # lane l = b M + j: model j of row b
    zp_l = np.empty((m, B * M))
    S_l = np.empty((m, m, B * M))
    C_l = np.empty((n, m, B * M))
    O_l = np.empty((L, n, B * M))
    Z_l = np.empty((L, m, B * M))
    zp = np.empty((M, m))
    S = np.empty((M, m, m))
    C = np.empty((n, m))
    K = np.empty((n, m))
    S_inv = np.empty((m, m))
    Lc = np.zeros((m, m))
    nu = np.empty(m)
    Sinu = np.empty(m)
    Sj = np.empty((m, m))
    hz = np.empty(m)
    H = np.empty((m, n))
    IKH = np.empty((n, n))
    T1 = np.empty((n, n))
    logpost = np.empty(M)
    per_tracker = F.shape[0] > 1  # else one bank for all trackers
    failures = 0
    for t in range(N):
        b = t % TRACKER_BLOCK  # row of tracker t in its block
        if b == 0:  # 1. mixing and prediction of the block, 2a. its eigendecompositions
            nb = min(TRACKER_BLOCK, N - t)
            for i in range(nb):
                g = t + i if per_tracker else 0
                _mix_predict(t + i, i, x, P, mu, tpm, F[g], Q[g], cbar, xp, Pp, x0, P0, w, spread,
                             FP)
            if filter_kind == UKF:
                _to_lanes(Pp, nb, eig)
                jacobi_eig_lanes(eig, U, nb * M, JACOBI_MAX_SWEEPS)
                _ukf_moments_lanes(xp_lanes, eig, U, nb * M, sensor_kind, sensor_params, wm, wc,
                                   gamma, zp_l, S_l, C_l, O_l, Z_l)
        Rt = R[t if per_tracker else 0]
        failed_out[t] = False
        for j in range(M):
            if filter_kind == UKF:
                _from_lanes(zp_l, S_l, C_l, Rt, b * M + j, j, zp, S, C)
            else:
                _ekf_moments(xp, Pp, b, sensor_kind, sensor_params, Rt, j, zp, S, C, H, hz)
            for r in range(m):
                for c in range(m):
                    Sj[r, c] = S[j, r, c]
            logdet, ok = _inv_logdet(Sj, S_inv, Lc)
            if not ok:
                failed_out[t] = True
                break
            if not detected[t]:
                for r in range(n):
                    x_out[t, j, r] = xp[b, j, r]
                    for c in range(n):
                        P_out[t, j, r, c] = Pp[b, j, r, c]
                loglik_out[t, j] = 0.0
                model_nis_out[t, j] = 0.0
                for d in range(m):
                    innov_out[t, j, d] = 0.0
                continue
            for d in range(m):
                nu[d] = z[t, d] - zp[j, d]
            if sensor_kind == RANGE_BEARING:
                nu[1] = _wrap(nu[1])
            for r in range(m):
                acc = 0.0
                for c in range(m):
                    acc += S_inv[r, c] * nu[c]
                Sinu[r] = acc
            nis = 0.0
            for r in range(m):
                nis += nu[r] * Sinu[r]
            # whitened innovation L^-1 nu (S = L L^T): signed, |.|^2 = NIS
            for r in range(m):
                acc = nu[r]
                for k in range(r):
                    acc -= Lc[r, k] * innov_out[t, j, k]
                innov_out[t, j, r] = acc / Lc[r, r]
            for r in range(n):
                for c in range(m):
                    acc = 0.0
                    for k in range(m):
                        acc += C[r, k] * S_inv[k, c]
                    K[r, c] = acc
                acc = 0.0
                for k in range(m):
                    acc += C[r, k] * Sinu[k]
                x_out[t, j, r] = xp[b, j, r] + acc
            if filter_kind == UKF:
                # P = Pp - K C^T
                for r in range(n):
                    for c in range(n):
                        acc = 0.0
                        for k in range(m):
                            acc += K[r, k] * C[c, k]
                        T1[r, c] = Pp[b, j, r, c] - acc
            else:
                # Joseph form: (I - K H) Pp (I - K H)^T + K R K^T
                for r in range(n):
                    for c in range(n):
                        acc = 1.0 if r == c else 0.0
                        for k in range(m):
                            acc -= K[r, k] * H[k, c]
                        IKH[r, c] = acc
                for r in range(n):
                    for c in range(n):
                        acc = 0.0
                        for k in range(n):
                            acc += IKH[r, k] * Pp[b, j, k, c]
                        FP[r, c] = acc
                for r in range(n):
                    for c in range(n):
                        acc = 0.0
                        for k in range(n):
                            acc += FP[r, k] * IKH[c, k]
                        for k in range(m):
                            for l in range(m):
                                acc += K[r, k] * Rt[k, l] * K[c, l]
                        T1[r, c] = acc
            for r in range(n):
                for c in range(n):
                    P_out[t, j, r, c] = 0.5 * (T1[r, c] + T1[c, r])
            loglik_out[t, j] = -0.5 * (nis + logdet + m * LOG_2PI)
            model_nis_out[t, j] = nis
        if failed_out[t]:
            failures += 1
            _fill_nan(t, x_out, P_out, mu_out, cbar_out, loglik_out, model_nis_out, innov_out,
                      nis_out, xhat_out, Phat_out)
            continue
        # 3. model probabilities, mu_j ∝ Lambda_j cbar_j (log-sum-exp)
        top = -np.inf
        for j in range(M):
            logpost[j] = loglik_out[t, j] + (np.log(cbar[b, j]) if cbar[b, j] > 0.0 else -np.inf)
            top = max(top, logpost[j])
        total = 0.0
        for j in range(M):
            logpost[j] = np.exp(logpost[j] - top)
            total += logpost[j]
        for j in range(M):
            mu_out[t, j] = logpost[j] / total
            cbar_out[t, j] = cbar[b, j]
        # 4. combination
        combine_into(t, mu_out, x_out, P_out, xhat_out, Phat_out)
        # 5. NIS of the predicted measurement mixture (weights cbar)
        if not (detected[t] and mixture_nis):
            nis_out[t] = 0.0
            continue
        for d in range(m):
            acc = 0.0
            for j in range(M):
                diff = zp[j, d] - zp[0, d]
                if sensor_kind == RANGE_BEARING and d == 1:
                    diff = _wrap(diff)
                acc += cbar[b, j] * diff
            hz[d] = zp[0, d] + acc  # mixture mean
        for r in range(m):
            for c in range(m):
                Sj[r, c] = 0.0
        for j in range(M):
            for d in range(m):
                nu[d] = zp[j, d] - hz[d]
            if sensor_kind == RANGE_BEARING:
                nu[1] = _wrap(nu[1])
            for r in range(m):
                for c in range(m):
                    Sj[r, c] += cbar[b, j] * (S[j, r, c] + nu[r] * nu[c])
        logdet, ok = _inv_logdet(Sj, S_inv, Lc)
        if not ok:
            failed_out[t] = True
            failures += 1
            _fill_nan(t, x_out, P_out, mu_out, cbar_out, loglik_out, model_nis_out, innov_out,
                      nis_out, xhat_out, Phat_out)
            continue
        for d in range(m):
            nu[d] = z[t, d] - hz[d]
        if sensor_kind == RANGE_BEARING:
            nu[1] = _wrap(nu[1])
        acc = 0.0
        for r in range(m):
            for c in range(m):
                acc += nu[r] * S_inv[r, c] * nu[c]
        nis_out[t] = acc
    return failures


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _mix_predict(
    t: int, b: int, x: Array, P: Array, mu: Array, tpm: Array, F: Array, Q: Array, cbar: Array,
    xp: Array, Pp: Array, x0: Array, P0: Array, w: Array, spread: Array, FP: Array,
) -> None:  # pragma: no cover
    """Mixing (SPEC §1 step 1) and prediction of tracker ``t`` into row ``b`` of the block.

    ``cbar_j = sum_i pi_ij mu_i``; ``x0_j = sum_i mu_i|j x_i``, ``P0_j = sum_i mu_i|j [P_i +
    (x_i - x0_j)(x_i - x0_j)^T]`` with ``mu_i|j = pi_ij mu_i / cbar_j`` (``mu`` itself when
    ``cbar_j`` underflows); ``xp_j = F_j x0_j``, ``Pp_j = F_j P0_j F_j^T + Q_j``. ``x0``,
    ``P0``, ``w``, ``spread``, ``FP`` are scratch.
    """
    M, n = x.shape[1], x.shape[2]
    for j in range(M):
        acc = 0.0
        for i in range(M):
            acc += tpm[t, i, j] * mu[t, i]
        cbar[b, j] = acc
    for j in range(M):
        if cbar[b, j] > _TINY:
            inv_cbar = 1.0 / cbar[b, j]
            for i in range(M):
                w[i] = tpm[t, i, j] * mu[t, i] * inv_cbar
        else:
            for i in range(M):
                w[i] = mu[t, i]
        for d in range(n):
            acc = 0.0
            for i in range(M):
                acc += w[i] * x[t, i, d]
            x0[j, d] = acc
            for i in range(M):
                spread[i, d] = x[t, i, d] - acc  # x_i - x0_j
        for r in range(n):
            for c in range(r, n):
                acc = 0.0
                for i in range(M):
                    acc += w[i] * (P[t, i, r, c] + spread[i, r] * spread[i, c])
                P0[j, r, c] = acc
                P0[j, c, r] = acc
    for j in range(M):
        for r in range(n):
            acc = 0.0
            for k in range(n):
                acc += F[j, r, k] * x0[j, k]
            xp[b, j, r] = acc
            for c in range(n):
                acc = 0.0
                for k in range(n):
                    acc += F[j, r, k] * P0[j, k, c]
                FP[r, c] = acc
        for r in range(n):
            for c in range(r, n):
                acc = 0.0
                for k in range(n):
                    acc += FP[r, k] * F[j, c, k]
                Pp[b, j, r, c] = acc + 0.5 * (Q[j, r, c] + Q[j, c, r])
                Pp[b, j, c, r] = Pp[b, j, r, c]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _to_lanes(Pp: Array, nb: int, eig: Array) -> None:  # pragma: no cover
    """Upper triangles of the block's predicted covariances ``Pp[b, j]`` side by side as the
    lanes ``l = b M + j`` of ``eig (n, n, L)`` (the layout of :func:`jacobi_eig_lanes`)."""
    M, n = Pp.shape[1], Pp.shape[2]
    for r in range(n):
        for c in range(r, n):
            for b in range(nb):
                for j in range(M):
                    eig[r, c, b * M + j] = Pp[b, j, r, c]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def combine_into(
    t: int, mu: Array, x: Array, P: Array, x_hat: Array, P_hat: Array
) -> None:  # pragma: no cover
    """Output combination of tracker ``t`` with the spread-of-means term (SPEC §1 step 4).

    ``x_hat[t] = sum_j mu_tj x_tj``, ``P_hat[t] = sum_j mu_tj [P_tj + (x_tj - x_hat)(x_tj -
    x_hat)^T]``; ``mu (N, M)``, ``x (N, M, n)``, ``P (N, M, n, n)``.
    """
    M, n = x.shape[1], x.shape[2]
    for d in range(n):
        acc = 0.0
        for j in range(M):
            acc += mu[t, j] * x[t, j, d]
        x_hat[t, d] = acc
    for r in range(n):
        for c in range(r, n):
            acc = 0.0
            for j in range(M):
                acc += mu[t, j] * (
                    P[t, j, r, c] + (x[t, j, r] - x_hat[t, r]) * (x[t, j, c] - x_hat[t, c])
                )
            P_hat[t, r, c] = acc
            P_hat[t, c, r] = acc


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _fill_nan(
    t: int, x_out: Array, P_out: Array, mu_out: Array, cbar_out: Array, loglik_out: Array,
    model_nis_out: Array, innov_out: Array, nis_out: Array, xhat_out: Array, Phat_out: Array,
) -> None:  # pragma: no cover
    """Mark tracker ``t``'s outputs as invalid."""
    innov_out[t] = np.nan
    x_out[t] = np.nan
    P_out[t] = np.nan
    mu_out[t] = np.nan
    cbar_out[t] = np.nan
    loglik_out[t] = np.nan
    model_nis_out[t] = np.nan
    nis_out[t] = np.nan
    xhat_out[t] = np.nan
    Phat_out[t] = np.nan
