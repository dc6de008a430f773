r"""Compiled fast path of the IMM cycle for the built-in sensors (numba).

:class:`imm_gym.tracking.imm.IMM` runs one of two engines with the same equations:

* ``"numpy"`` — the vectorized reference in :mod:`imm_gym.tracking.imm` and
  :mod:`imm_gym.tracking.filters`; works with any sensor that implements
  :class:`imm_gym.tracking.filters.MeasurementModel`;
* ``"compiled"`` — this module: the whole cycle (mix, predict, update, likelihood, probability
  update, combination, NIS) fused into one compiled call over the trackers, for
  :class:`~imm_gym.Sonar` and :class:`~imm_gym.PositionSensor`. The trackers run in blocks of
  ``TRACKER_BLOCK``, copied into structure-of-arrays scratch with the lane (model ``j`` of the
  block's tracker ``b``) as the last, contiguous axis, so every step of the cycle is a loop over
  the lanes that the compiler vectorizes: the Jacobi eigendecompositions of all the block's
  predicted covariances together (:func:`imm_gym.tracking.linalg.jacobi_eig_lanes`), the sigma
  points and a branch-free :func:`_atan2`, the closed-form inverse of a 2x2 innovation
  covariance. No fast-math: IEEE arithmetic rounds the same in the vectorized loops and their
  scalar remainders, so a tracker's numbers do not depend on its batch.

The tests run both engines on the same inputs and require the same numbers (to rounding).

Sensor codes: ``RANGE_BEARING`` (``h = [|p - s|, atan2]``, params = sensor position ``s``),
``LINEAR`` (``h = x[:m]``). Filter codes: ``UKF`` (SVD sigma points), ``UKF_CHOLESKY`` (Cholesky
sigma points), ``EKF`` (the Kalman filter is the EKF of a linear sensor).
"""

from __future__ import annotations

import numba
import numpy as np
from numba.extending import overload
from numpy.typing import NDArray

from imm_gym.tracking.kernels.scratch import scratch
from imm_gym.tracking.linalg import (
    JACOBI_MAX_SWEEPS,
    LOG_2PI,
    cholesky_lanes,
    jacobi_sweeps,
    jacobi_sweeps_inlined,
)

Array = NDArray[np.float64]
F8 = np.float64

RANGE_BEARING = 0
LINEAR = 1
UKF = 0
EKF = 1
UKF_CHOLESKY = 2


# fmt: off

_TINY = 1e-300
_TWO_PI = 2.0 * np.pi
_PI_2 = 0.5 * np.pi
_PI_4 = 0.25 * np.pi
#: the part of pi / 2 that its double misses (Cephes' MOREBITS)
_PI_2_LO = 6.123233995736765886130e-17
_TAN_3PI_8 = 2.41421356237309504880
#: Trackers per block of :func:`imm_step`: the block's trackers and models are the SIMD lanes of
#: every loop (structure of arrays, the lane index innermost).
TRACKER_BLOCK = 32
#: ``(M, n, m)`` of the trackers :func:`imm_step_one` runs with these sizes compiled in: three
#: models of four states (the CV / CT banks), a 2-D measurement
ONE_SHAPE = (3, 4, 2)


def sensor_spec(sensor: object) -> tuple[int, Array] | None:
    """``(kind, params)`` of a built-in sensor for the kernel, or ``None`` for any other."""
    from imm_gym.tracking.sensors import PositionSensor, Sonar

    if isinstance(sensor, Sonar):
        return RANGE_BEARING, np.array(sensor.position, dtype=np.float64)
    if isinstance(sensor, PositionSensor):
        return LINEAR, np.zeros(2)
    return None


@numba.njit(cache=True, nogil=True, error_model="numpy")
def clearly_stochastic(tpm: Array, row_sum_tol: float) -> bool:  # pragma: no cover
    """Whether every entry of the C-contiguous ``tpm`` ``(..., M, M)`` is finite and ``>= 0`` and
    every row sum ``s`` has ``|s - 1| <= row_sum_tol`` (the sum taken left to right).

    The fast half of :func:`imm_gym.tracking.tpm.validate_tpm`: :meth:`IMM.step` calls the
    validator only where this says no (with half its tolerance, so a row whose sum lies near the
    tolerance gets the validator's own verdict and message).
    """
    M = tpm.shape[-1]
    rows = tpm.reshape((tpm.size // M, M))
    for r in range(rows.shape[0]):
        total = 0.0
        for j in range(M):
            v = rows[r, j]
            if not (v >= 0.0 and v - v == 0.0):  # NaN, inf or negative
                return False
            total += v
        if not abs(total - 1.0) <= row_sum_tol:
            return False
    return True


@numba.njit(cache=True, nogil=True, error_model="numpy")
def all_finite(z: Array) -> bool:  # pragma: no cover
    """Whether every entry of the 2-D ``z`` is finite (``z - z == 0``)."""
    for t in range(z.shape[0]):
        for d in range(z.shape[1]):
            v = z[t, d]
            if not v - v == 0.0:
                return False
    return True


#: :func:`unclear_inputs` flags: the TPM, the measurements need the reference checks
TPM_UNCLEAR = 1
Z_UNCLEAR = 2


@numba.njit(cache=True, nogil=True, error_model="numpy")
def unclear_inputs(tpm: Array, z: Array, row_sum_tol: float) -> int:  # pragma: no cover
    """Which inputs of a step need the reference checks, in one call: ``TPM_UNCLEAR`` where
    ``tpm`` is not :func:`clearly_stochastic`, plus ``Z_UNCLEAR`` where ``z`` is not
    :func:`all_finite` (0: both clear)."""
    tpm_flag = 0 if clearly_stochastic(tpm, row_sum_tol) else TPM_UNCLEAR
    return tpm_flag | (0 if all_finite(z) else Z_UNCLEAR)


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


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _wrap_near(a: float) -> float:  # pragma: no cover
    """:func:`_wrap` of an angle in (-3 pi, 3 pi] (a difference of wrapped angles), branch-free
    (selects: it vectorizes)."""
    w = a - _TWO_PI if a > np.pi else a
    return w + _TWO_PI if w <= -np.pi else w


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _atan2(y: float, x: float) -> float:  # pragma: no cover
    """``atan2(y, x)`` branch-free (selects and one division: it vectorizes), within an ulp or
    two of ``numpy.arctan2``.

    ``r = min(|x|, |y|) / max(|x|, |y|)`` in [0, 1]; above 0.66 ``atan r = pi/4 +
    atan((r - 1) / (r + 1))``; ``atan u = u + u z P(z) / Q(z)``, ``z = u^2``, the rational
    approximation of Cephes' ``atan`` (Moshier 1989; relative error 2e-16 on
    ``|u| <= 0.66``); then ``pi/2 - atan r`` when ``|y| > |x|``, ``pi - .`` when ``x < 0`` and
    the sign of ``y``. ``atan2(0, 0) = 0``.
    """
    ax = abs(x)
    ay = abs(y)
    swap = ay > ax
    hi = ay if swap else ax
    lo = ax if swap else ay
    r = lo / hi if hi > 0.0 else 0.0
    big = r > 0.66
    u = (r - 1.0) / (r + 1.0) if big else r
    z = u * u
    p = (((-8.750608600031904122785e-1 * z - 1.615753718733365076637e1) * z
          - 7.500855792314704667340e1) * z - 1.228866684490136173410e2) * z \
        - 6.485021904942025371773e1
    q = ((((z + 2.485846490142306297962e1) * z + 1.650270098316988542046e2) * z
          + 4.328810604912902668951e2) * z + 4.853903996359136964868e2) * z \
        + 1.945506571482613964425e2
    a = u + u * (z * p / q)
    a = (_PI_4 + (a + 0.5 * _PI_2_LO)) if big else a
    a = ((_PI_2 - a) + _PI_2_LO) if swap else a
    a = ((np.pi - a) + 2.0 * _PI_2_LO) if x < 0.0 else a
    return -a if y < 0.0 else a


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

    Returns the number of trackers whose cycle failed (a diverged tracker): an innovation
    covariance not positive definite, or mode probabilities, a combined estimate or its
    variances not finite (every model's likelihood underflowing, an overflow); those are flagged
    in ``failed_out`` and their outputs filled with NaN, the others are unaffected.

    ``tpm`` is ``(N, M, M)`` (a broadcast view is fine). ``F``, ``Q`` (``(B, M, n, n)``) and
    ``R`` (``(B, m, m)``) hold one bank per tracker (``B = N``: trackers at their own sampling
    period and sensor noise) or one for all (``B = 1``). Per tracker: mixing (SPEC §1 step 1),
    ``x = F x0``, ``P = F P0 F^T + Q``, the UKF or EKF update (Joseph form for the EKF), the
    log-domain probability update, the combination with the spread term, and (with
    ``mixture_nis``; else ``nis_out`` is 0) the NIS of the moment-matched predicted measurement
    mixture.

    Layout: the trackers run in blocks of ``TRACKER_BLOCK``, copied into structure-of-arrays
    scratch whose last axis is the lane: ``j * nb + b`` for model ``j`` of the block's tracker
    ``b`` (``nb`` trackers in the block; per-tracker arrays have lane ``b``). Every step is a
    loop over the lanes (the compiler vectorizes it), the ``M * nb`` predicted covariances are
    diagonalized together (:func:`imm_gym.tracking.linalg.jacobi_eig_lanes`), ``atan2`` is
    :func:`_atan2`, a 2x2 innovation covariance is inverted in closed form. Lanes do not
    interact and sums keep their order, so every tracker's numbers are those it would get alone
    (whatever its block, position and N). :func:`imm_step_one` is the same cycle for one
    tracker, faster.
    """
    N, M, n = x.shape
    outs = (x_out, P_out, mu_out, cbar_out, loglik_out, model_nis_out, innov_out, nis_out,
            xhat_out, Phat_out, failed_out)
    return _cycle(x, P, mu, tpm, z, detected, F, Q, R, sensor_kind, sensor_params, filter_kind,
                  wm, wc, gamma, mixture_nis, outs, N, min(N, TRACKER_BLOCK), M, n, z.shape[1],
                  False)


def fits_one(N: int, M: int, n: int, m: int) -> bool:
    """Whether N trackers of M models, n states and m measurement components can run
    through :func:`imm_step_one`."""
    return N == 1 and (M, n, m) == ONE_SHAPE


@numba.njit(cache=True, nogil=True, error_model="numpy")
def imm_step_one(
    x: Array, P: Array, mu: Array, tpm: Array, z: Array, detected: NDArray[np.bool_], F: Array,
    Q: Array, R: Array, sensor_kind: int, sensor_params: Array, filter_kind: int, wm: Array,
    wc: Array, gamma: float, mixture_nis: bool, x_out: Array, P_out: Array, mu_out: Array,
    cbar_out: Array, loglik_out: Array, model_nis_out: Array, innov_out: Array, nis_out: Array,
    xhat_out: Array, Phat_out: Array, failed_out: NDArray[np.bool_],
) -> int:  # pragma: no cover
    """:func:`imm_step` (same arguments, same outputs bit for bit) for one tracker of the shape
    :data:`ONE_SHAPE` (:func:`fits_one`; ``ValueError`` otherwise): the cycle compiled with its
    sizes as constants and its scratch in its own stack frame (:func:`_step_one`): 4.0 against
    10.8 µs for :func:`imm_step` at N = 1 (SVD-UKF; EKF 2.7 against 8.7). Compiled on first
    use (~1 min, cached after), so that callers with many trackers never pay for it."""
    M, n, m = ONE_SHAPE
    if x.shape != (1, M, n) or z.shape != (1, m):
        raise ValueError("imm_step_one takes one tracker of three 4-state models, 2-D z")
    outs = (x_out, P_out, mu_out, cbar_out, loglik_out, model_nis_out, innov_out, nis_out,
            xhat_out, Phat_out, failed_out)
    return _step_one(
        _owned(x), _owned(P), _owned(mu), _owned(tpm), _owned(z), _owned(detected), _owned(F),
        _owned(Q), _owned(R), sensor_kind, _owned(sensor_params), filter_kind, _owned(wm),
        _owned(wc), gamma, mixture_nis, outs,
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _step_one(
    x: Array, P: Array, mu: Array, tpm: Array, z: Array, detected: NDArray[np.bool_], F: Array,
    Q: Array, R: Array, sensor_kind: int, sensor_params: Array, filter_kind: int, wm: Array,
    wc: Array, gamma: float, mixture_nis: bool, outs: tuple,
) -> int:  # pragma: no cover
    """The cycle of one tracker of the shape :data:`ONE_SHAPE` (three models, four states, a 2-D
    measurement; arrays writable and C-contiguous): :func:`_cycle` compiled with these sizes as
    constants, so its loops have known lengths (unrolled, without the vector loops' checks and
    remainders that cost more than the arithmetic at 3 lanes). The same operations in the same
    order: the same numbers bit for bit."""
    M, n, m = ONE_SHAPE
    return _cycle(x, P, mu, tpm, z, detected, F, Q, R, sensor_kind, sensor_params, filter_kind,
                  wm, wc, gamma, mixture_nis, outs, 1, 1, M, n, m, True)


#: the header of :func:`pack_one`'s array: sensor code, filter code, ``gamma``, the lengths of
#: the sensor's parameters and of the sigma-point weights
_PACK_HEADER = 5


def pack_one(
    F: Array, Q: Array, R: Array, sensor_kind: int, sensor_params: Array, filter_kind: int,
    wm: Array, wc: Array, gamma: float,
) -> Array:
    """A bank's kernel constants (:attr:`imm_gym.tracking.imm.IMM.kernel_args`, a bank of
    :data:`ONE_SHAPE`) in one flat array for :func:`checked_step_one`: the header (sensor code,
    filter code, ``gamma``, ``len(sensor_params)``, ``len(wm)``), then ``F``, ``Q``, ``R``,
    ``sensor_params``, ``wm``, ``wc`` (:func:`unpack_one` reads them back). One argument instead
    of nine: a compiled call pays ~60 ns for each argument it types and unboxes."""
    M, n, m = ONE_SHAPE
    if F.shape != (1, M, n, n) or Q.shape != (1, M, n, n) or R.shape != (1, m, m):
        raise ValueError(f"pack_one takes a bank of the shape {ONE_SHAPE}, got F {F.shape}")
    header = np.array([sensor_kind, filter_kind, gamma, sensor_params.size, wm.size], F8)
    return np.concatenate([header, *(np.ravel(a) for a in (F, Q, R, sensor_params, wm, wc))])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def checked_step_one(
    x: Array, P: Array, mu: Array, tpm: Array, z: Array, detected: NDArray[np.bool_],
    bank: Array, row_sum_tol: float, x_out: Array, P_out: Array, mu_out: Array,
    cbar_out: Array, loglik_out: Array, model_nis_out: Array, innov_out: Array, nis_out: Array,
    xhat_out: Array, Phat_out: Array, failed_out: NDArray[np.bool_],
) -> int:  # pragma: no cover
    """:func:`imm_step_one` (same outputs bit for bit, the mixture NIS included) as
    :meth:`imm_gym.tracking.imm.IMM.step` calls it for one tracker: the bank's constants as
    :func:`pack_one`'s array, and the inputs first checked in the same call as
    :func:`unclear_inputs` does where ``row_sum_tol >= 0``. Returns the number of failed trackers
    (0 or 1), or minus :func:`unclear_inputs`' flags, without stepping, where the inputs need the
    reference checks. Nineteen arguments and one call instead of twenty-seven and two: ~1 µs of a
    ~9 µs ``IMM.step``."""
    if row_sum_tol >= 0.0:
        unclear = unclear_inputs(tpm, z, row_sum_tol)
        if unclear:
            return -unclear
    M, n, m = ONE_SHAPE
    if x.shape != (1, M, n) or z.shape != (1, m):
        raise ValueError("checked_step_one takes one tracker of three 4-state models, 2-D z")
    F, Q, R, sensor_kind, sensor_params, filter_kind, wm, wc, gamma = unpack_one(bank)
    outs = (x_out, P_out, mu_out, cbar_out, loglik_out, model_nis_out, innov_out, nis_out,
            xhat_out, Phat_out, failed_out)
    return _step_one(
        _owned(x), _owned(P), _owned(mu), _owned(tpm), _owned(z), _owned(detected), F, Q, R,
        sensor_kind, sensor_params, filter_kind, wm, wc, gamma, True, outs,
    )


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def unpack_one(
    bank: Array,
) -> tuple[Array, Array, Array, int, Array, int, Array, Array, float]:  # pragma: no cover
    """:func:`pack_one`'s array back as the nine kernel constants ``(F, Q, R, sensor_kind,
    sensor_params, filter_kind, wm, wc, gamma)``, the arrays views of ``bank``."""
    M, n, m = ONE_SHAPE
    n_params = int(bank[3])
    n_w = int(bank[4])
    start = _PACK_HEADER
    F = bank[start:start + M * n * n].reshape((1, M, n, n))
    start += M * n * n
    Q = bank[start:start + M * n * n].reshape((1, M, n, n))
    start += M * n * n
    R = bank[start:start + m * m].reshape((1, m, m))
    start += m * m
    sensor_params = bank[start:start + n_params]
    start += n_params
    wm = bank[start:start + n_w]
    wc = bank[start + n_w:start + 2 * n_w]
    return F, Q, R, int(bank[0]), sensor_params, int(bank[1]), wm, wc, bank[2]


def _owned(a: Array) -> Array:
    """``a`` where it is a writable C-contiguous array, else a copy that is: the arrays
    :func:`imm_step_one` hands :func:`_step_one` are of one type whatever its callers pass (a
    broadcast TPM, a read-only or strided view), so that copy is compiled once (~1 min)."""
    return a if a.flags.c_contiguous and a.flags.writeable else a.copy()


@overload(_owned, inline="always")
def _owned_compiled(a):  # type: ignore[no-untyped-def]
    """:func:`_owned` in compiled code, decided from ``a``'s type: no copy for the usual one."""
    if a.layout == "C" and a.mutable:
        return lambda a: a
    return lambda a: a.copy()


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _cycle(
    x: Array, P: Array, mu: Array, tpm: Array, z: Array, detected: NDArray[np.bool_], F: Array,
    Q: Array, R: Array, sensor_kind: int, sensor_params: Array, filter_kind: int, wm: Array,
    wc: Array, gamma: float, mixture_nis: bool, outs: tuple, N: int, W: int, M: int, n: int,
    m: int, one: bool,
) -> int:  # pragma: no cover
    """The body of :func:`imm_step` (its layout and equations), for ``N`` trackers in blocks of
    ``W``, ``M`` models, ``n`` states, ``m`` measurement components (constants where the caller
    knows them); ``outs`` are its eleven output arrays, in order. ``one`` (a constant): one
    tracker of :data:`ONE_SHAPE`, its scratch in the caller's stack frame
    (:func:`~imm_gym.tracking.kernels.scratch.scratch`: no allocation, and arrays the compiler
    knows apart) and the Jacobi sweeps inlined."""
    (x_out, P_out, mu_out, cbar_out, loglik_out, model_nis_out, innov_out, nis_out, xhat_out,
     Phat_out, failed_out) = outs
    L = M * W
    K = 1 if filter_kind == EKF else 2 * n + 1
    per_tracker = F.shape[0] > 1  # else one bank for all trackers
    # structure-of-arrays scratch, the lane axis last (in this frame for one tracker)
    s = one
    Fl, Ql = scratch((n, n, L), F8, s), scratch((n, n, L), F8, s)
    Xm, Pm = scratch((n, L), F8, s), scratch((n, n, L), F8, s)
    Rl, mul, tpml = scratch((m, m, W), F8, s), scratch((M, W), F8, s), scratch((M, M, W), F8, s)
    cbar, wgt, spread = scratch((M, W), F8, s), scratch((M, W), F8, s), scratch((M, n, W), F8, s)
    X0, P0, FP = scratch((n, L), F8, s), scratch((n, n, L), F8, s), scratch((n, n, L), F8, s)
    Xp, Pp = scratch((n, L), F8, s), scratch((n, n, L), F8, s)
    eig, U = scratch((n, n, L), F8, s), scratch((n, n, L), F8, s)
    O, Z = scratch((K, n, L), F8, s), scratch((K, m, L), F8, s)
    H = scratch((m, n, L), F8, s)
    zp, S, C = scratch((m, L), F8, s), scratch((m, m, L), F8, s), scratch((n, m, L), F8, s)
    Kg, Si, Lc = scratch((n, m, L), F8, s), scratch((m, m, L), F8, s), scratch((m, m, L), F8, s)
    logdet, ok = scratch((L,), F8, s), scratch((L,), F8, s)
    nu, Sinu, innov = scratch((m, L), F8, s), scratch((m, L), F8, s), scratch((m, L), F8, s)
    nis, loglik = scratch((L,), F8, s), scratch((L,), F8, s)
    Xu, Pu = scratch((n, L), F8, s), scratch((n, n, L), F8, s)
    mu_new, xhat, Phat = scratch((M, W), F8, s), scratch((n, W), F8, s), scratch((n, n, W), F8, s)
    hz, Sm = scratch((m, W), F8, s), scratch((m, m, W), F8, s)
    Smi, Smc = scratch((m, m, W), F8, s), scratch((m, m, W), F8, s)
    num, okm, nism = scratch((m, W), F8, s), scratch((W,), F8, s), scratch((W,), F8, s)
    det = scratch((W,), F8, s)
    # the Jacobi sweeps' scratch (jacobi_eig_lanes allocates it per call: per block)
    half = (n + n % 2) // 2
    jconv, joff, jdiag = scratch((L,), np.bool_, s), scratch((L,), F8, s), scratch((L,), F8, s)
    jc, js = scratch((half, L), F8, s), scratch((half, L), F8, s)
    jpairs, jold = scratch((half, 2), np.int64, s), scratch((2, L), F8, s)
    bank_lanes = -1  # the lane count the bank's F, Q, R were spread for (one bank)
    failures = 0
    for t0 in range(0, N, W):
        nb = min(W, N - t0)
        lanes = M * nb
        if per_tracker or bank_lanes != nb:
            _spread_bank(F, Q, R, t0, nb, per_tracker, Fl, Ql, Rl)
            bank_lanes = nb
        _load(x, P, mu, tpm, detected, t0, nb, Xm, Pm, mul, tpml, det)
        _mix(Xm, Pm, mul, tpml, nb, cbar, wgt, spread, X0, P0)
        _predict(Fl, Ql, X0, P0, lanes, Xp, Pp, FP)
        if filter_kind == EKF:
            _ekf_moments(Xp, Pp, lanes, sensor_kind, sensor_params, zp, S, C, H)
        else:
            if filter_kind == UKF:  # Pp = U diag(eig) U^T
                for r in range(n):
                    for c in range(r, n):
                        for i in range(lanes):
                            eig[r, c, i] = Pp[r, c, i]
                if one:  # inlined: unrolled with this tracker's sizes
                    jacobi_sweeps_inlined(eig, U, lanes, JACOBI_MAX_SWEEPS, jconv, joff, jdiag,
                                          jc, js, jpairs, jold)
                else:
                    jacobi_sweeps(eig, U, lanes, JACOBI_MAX_SWEEPS, jconv, joff, jdiag, jc, js,
                                  jpairs, jold)
            else:  # Pp = L L^T: U = L and unit eig, so the offsets are gamma L's columns
                # (the Jacobi sweeps' off-diagonal and diagonal sums, unused by this filter, are
                # the factorization's pivot and inverse-pivot rows)
                cholesky_lanes(Pp, U, lanes, joff, jdiag)
                for k in range(n):
                    for i in range(lanes):
                        eig[k, k, i] = 1.0
            _ukf_moments(Xp, eig, U, filter_kind == UKF, lanes, sensor_kind, sensor_params, wm,
                         wc, gamma, zp, S, C, O, Z)
        _add_noise(S, Rl, M, nb)
        _inverse(S, lanes, Si, Lc, logdet, ok)
        _innovation(z, t0, nb, M, sensor_kind, zp, nu)
        _update(Xp, Pp, zp, C, H, Rl, Si, Lc, logdet, ok, nu, M, nb, filter_kind, Sinu, Kg, FP,
                eig, nis, loglik, innov, Xu, Pu)
        _keep_prediction(Xp, Pp, M, nb, det, Xu, Pu)
        _probabilities(loglik, cbar, M, nb, det, mu_new, nism)
        _combine_lanes(mu_new, Xu, Pu, M, nb, xhat, Phat)
        if mixture_nis:
            _mixture_nis(z, t0, zp, S, cbar, M, nb, sensor_kind, hz, Sm, Smi, Smc, num, okm, nism)
        else:
            for b in range(nb):
                okm[b] = 1.0
        failures += _store(t0, nb, M, det, mixture_nis, ok, okm, nism, Xu, Pu, mu_new,
                           cbar, loglik, nis, innov, xhat, Phat, x_out, P_out, mu_out, cbar_out,
                           loglik_out, model_nis_out, innov_out, nis_out, xhat_out, Phat_out,
                           failed_out)
    return failures


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _spread_bank(
    F: Array, Q: Array, R: Array, t0: int, nb: int, per_tracker: bool, Fl: Array, Ql: Array,
    Rl: Array,
) -> None:  # pragma: no cover
    """The block's ``F_j``, ``(Q_j + Q_j^T) / 2`` into lanes ``j nb + b`` of ``Fl``, ``Ql``, and
    ``(R + R^T) / 2`` into lanes ``b`` of ``Rl`` (tracker ``t0 + b``'s bank, or bank 0)."""
    M, n = F.shape[1], F.shape[2]
    m = R.shape[1]
    for b in range(nb):
        g = t0 + b if per_tracker else 0
        for j in range(M):
            for r in range(n):
                for c in range(n):
                    Fl[r, c, j * nb + b] = F[g, j, r, c]
                    Ql[r, c, j * nb + b] = 0.5 * (Q[g, j, r, c] + Q[g, j, c, r])
        for r in range(m):
            for c in range(m):
                Rl[r, c, b] = 0.5 * (R[g, r, c] + R[g, c, r])


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _load(
    x: Array, P: Array, mu: Array, tpm: Array, detected: NDArray[np.bool_], t0: int, nb: int,
    Xm: Array, Pm: Array, mul: Array, tpml: Array, det: Array,
) -> None:  # pragma: no cover
    """Trackers ``t0 .. t0 + nb - 1`` into the block's lanes (transposed: lane last).

    The lane loop innermost: contiguous stores, and the tracker index ``t0 + b`` as ``uint64``
    (no negative-index wraparound code in the loop). With the model's row innermost (4 or 6
    long) the copies in and out of the block (:func:`_store`) ran as scatters, gathers and
    scalar index arithmetic, 15 % of the UKF kernel at N = 1024 (perf).
    """
    M, n = x.shape[1], x.shape[2]
    for b in range(nb):
        det[b] = 1.0 if detected[np.uint64(t0 + b)] else 0.0
    for i in range(M):
        for b in range(nb):
            mul[i, b] = mu[np.uint64(t0 + b), i]
        for j in range(M):
            for b in range(nb):
                tpml[i, j, b] = tpm[np.uint64(t0 + b), i, j]
        for r in range(n):
            for b in range(nb):
                Xm[r, i * nb + b] = x[np.uint64(t0 + b), i, r]
            for c in range(n):
                for b in range(nb):
                    Pm[r, c, i * nb + b] = P[np.uint64(t0 + b), i, r, c]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _mix(
    Xm: Array, Pm: Array, mul: Array, tpml: Array, nb: int, cbar: Array, wgt: Array,
    spread: Array, X0: Array, P0: Array,
) -> None:  # pragma: no cover
    """Mixing (SPEC §1 step 1), lane by lane.

    ``cbar_j = sum_i pi_ij mu_i``; ``x0_j = sum_i mu_i|j x_i``, ``P0_j = sum_i mu_i|j [P_i +
    (x_i - x0_j)(x_i - x0_j)^T]`` with ``mu_i|j = pi_ij mu_i / cbar_j`` (``mu`` itself when
    ``cbar_j`` underflows).
    """
    M = mul.shape[0]
    n = Xm.shape[0]
    for j in range(M):
        for b in range(nb):
            cbar[j, b] = 0.0
        for i in range(M):
            for b in range(nb):
                cbar[j, b] += tpml[i, j, b] * mul[i, b]
    for j in range(M):
        for i in range(M):
            for b in range(nb):
                cb = cbar[j, b]
                wgt[i, b] = tpml[i, j, b] * mul[i, b] * (1.0 / cb) if cb > _TINY else mul[i, b]
        o = j * nb
        for d in range(n):
            for b in range(nb):
                X0[d, o + b] = 0.0
            for i in range(M):
                for b in range(nb):
                    X0[d, o + b] += wgt[i, b] * Xm[d, i * nb + b]
            for i in range(M):
                for b in range(nb):
                    spread[i, d, b] = Xm[d, i * nb + b] - X0[d, o + b]
        for r in range(n):
            for c in range(r, n):
                for b in range(nb):
                    P0[r, c, o + b] = 0.0
                for i in range(M):
                    for b in range(nb):
                        P0[r, c, o + b] += wgt[i, b] * (
                            Pm[r, c, i * nb + b] + spread[i, r, b] * spread[i, c, b])
                for b in range(nb):
                    P0[c, r, o + b] = P0[r, c, o + b]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _predict(
    Fl: Array, Ql: Array, X0: Array, P0: Array, lanes: int, Xp: Array, Pp: Array, FP: Array,
) -> None:  # pragma: no cover
    """``xp = F x0``, ``Pp = F P0 F^T + (Q + Q^T) / 2`` (symmetric by construction), lane by
    lane (``FP`` scratch)."""
    n = X0.shape[0]
    for r in range(n):
        for i in range(lanes):
            Xp[r, i] = 0.0
        for k in range(n):
            for i in range(lanes):
                Xp[r, i] += Fl[r, k, i] * X0[k, i]
        for c in range(n):
            for i in range(lanes):
                FP[r, c, i] = 0.0
            for k in range(n):
                for i in range(lanes):
                    FP[r, c, i] += Fl[r, k, i] * P0[k, c, i]
    for r in range(n):
        for c in range(r, n):
            for i in range(lanes):
                Pp[r, c, i] = 0.0
            for k in range(n):
                for i in range(lanes):
                    Pp[r, c, i] += FP[r, k, i] * Fl[c, k, i]
            for i in range(lanes):
                Pp[r, c, i] += Ql[r, c, i]
                Pp[c, r, i] = Pp[r, c, i]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _ukf_moments(
    xp: Array, s: Array, U: Array, symmetric: bool, lanes: int, kind: int, params: Array,
    wm: Array, wc: Array, gamma: float, zp: Array, S: Array, C: Array, O: Array, Z: Array,
) -> None:  # pragma: no cover
    """SVD-UKF predicted measurements ``zp[:, l]``, spreads of the predicted measurement
    ``S[:, :, l]`` (the innovation covariance without ``R``, added by :func:`_add_noise`) and
    cross covariances ``C[:, :, l]`` of the lanes ``l < lanes``.

    Sigma offsets ``O_0 = 0``, ``O_{1+i} = -O_{1+n+i} = gamma (U diag(sqrt|s|) U^T)_{:, i}``,
    the columns of the symmetric square root (``symmetric``; continuous in ``Pp`` where
    eigenvalues repeat: :meth:`~imm_gym.tracking.filters.UnscentedKalmanFilter.sigma_offsets`),
    or ``gamma sqrt|s_i| U_{:, i}`` (the Cholesky factor's columns, ``U = L`` and ``s = 1``), from
    the eigendecomposition ``Pp = U diag(s) U^T`` of the predicted covariance (``s`` on the diagonal
    of :func:`jacobi_eig_lanes`'s output; ``xp`` the predicted state), ``Z_k = h(xp + O_k) -
    h(xp)`` (bearing wrapped: averaged as residuals about the centre point),
    ``zp = h(xp) + sum_k wm_k Z_k``, ``S = sum_k wc_k dZ_k dZ_k^T``,
    ``C = sum_k wc_k O_k dZ_k^T`` with ``dZ_k = Z_k - sum_k wm_k Z_k`` (``O``, ``Z``:
    ``(2n+1, n, L)``, ``(2n+1, m, L)`` scratch).
    """
    n = xp.shape[0]
    m = zp.shape[0]
    L = 2 * n + 1
    for c in range(n):
        for i in range(lanes):
            O[0, c, i] = 0.0
    if symmetric:
        for k in range(n):
            for c in range(n):
                for i in range(lanes):
                    O[1 + k, c, i] = 0.0
        for j in range(n):
            # gamma sqrt|s_j| once per lane, kept in Z's row 0 until Z is computed
            for i in range(lanes):
                Z[0, 0, i] = gamma * np.sqrt(abs(s[j, j, i]))
            for k in range(n):
                for c in range(n):
                    for i in range(lanes):
                        O[1 + k, c, i] += U[k, j, i] * Z[0, 0, i] * U[c, j, i]
    else:
        for k in range(n):
            # gamma sqrt|s_k| once per lane (the same product as gamma * sqrt|s_k| * U_ck, left
            # to right), kept in Z's row 0 until Z is computed
            for i in range(lanes):
                Z[0, 0, i] = gamma * np.sqrt(abs(s[k, k, i]))
            for c in range(n):
                for i in range(lanes):
                    O[1 + k, c, i] = Z[0, 0, i] * U[c, k, i]
    for k in range(n):
        for c in range(n):
            for i in range(lanes):
                O[1 + n + k, c, i] = -O[1 + k, c, i]
    # Z holds h(sigma point) minus h(centre), bearing wrapped
    px, py = params[0], params[1]
    for k in range(L):
        if kind == RANGE_BEARING:
            _range_bearing_lanes(xp, O, k, px, py, lanes, Z)
        else:
            for d in range(m):
                for i in range(lanes):
                    Z[k, d, i] = xp[d, i] + O[k, d, i]
    for k in range(L - 1, -1, -1):
        for d in range(m):
            for i in range(lanes):
                Z[k, d, i] -= Z[0, d, i]
        if kind == RANGE_BEARING:
            for i in range(lanes):
                Z[k, 1, i] = _wrap_near(Z[k, 1, i])
    for d in range(m):
        for i in range(lanes):
            zp[d, i] = 0.0
        for k in range(L):
            for i in range(lanes):
                zp[d, i] += wm[k] * Z[k, d, i]
        for k in range(L):
            for i in range(lanes):
                Z[k, d, i] -= zp[d, i]
    # zp = h(centre) + mean residual
    if kind == RANGE_BEARING:
        for i in range(lanes):
            dx = xp[0, i] - params[0]
            dy = xp[1, i] - params[1]
            zp[0, i] = np.sqrt(dx * dx + dy * dy) + zp[0, i]
            zp[1, i] = _wrap_near(_atan2(dy, dx) + zp[1, i])
    else:
        for d in range(m):
            for i in range(lanes):
                zp[d, i] += xp[d, i]
    for r in range(m):
        for c in range(r, m):
            for i in range(lanes):
                S[r, c, i] = 0.0
            for k in range(L):
                for i in range(lanes):
                    S[r, c, i] += wc[k] * Z[k, r, i] * Z[k, c, i]
    for r in range(n):
        for c in range(m):
            for i in range(lanes):
                C[r, c, i] = 0.0
            for k in range(1, L):
                for i in range(lanes):
                    C[r, c, i] += wc[k] * O[k, r, i] * Z[k, c, i]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _range_bearing_lanes(
    xp: Array, O: Array, k: int, px: float, py: float, lanes: int, Z: Array
) -> None:  # pragma: no cover
    """``Z[k, :, l] = h(xp[:, l] + O[k, :, l])`` for the range-bearing sensor at ``(px, py)``.

    Compiled apart from :func:`imm_step` (not inlined): inside it the loop ran scalar (perf: 23 %
    of the UKF kernel at N = 1024; presumably the vectorizer's runtime alias checks among the many
    arrays there), on its own it vectorizes, :func:`_atan2` included.
    """
    for i in range(lanes):
        dx = xp[0, i] + O[k, 0, i] - px
        dy = xp[1, i] + O[k, 1, i] - py
        Z[k, 0, i] = np.sqrt(dx * dx + dy * dy)
        Z[k, 1, i] = _atan2(dy, dx)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _ekf_moments(
    xp: Array, Pp: Array, lanes: int, kind: int, params: Array, zp: Array, S: Array, C: Array,
    H: Array,
) -> None:  # pragma: no cover
    """EKF predicted measurement ``zp = h(xp)``, ``C = Pp H^T`` and ``S = H C`` (without ``R``)
    with ``H = dh/dx`` at ``xp`` (range-bearing: ``[[dx, dy], [-dy / r, dx / r]] / r`` in the
    position columns; linear: ``[I 0]``), lane by lane."""
    n = xp.shape[0]
    m = zp.shape[0]
    for r in range(m):
        for c in range(n):
            for i in range(lanes):
                H[r, c, i] = 0.0
    if kind == RANGE_BEARING:
        for i in range(lanes):
            dx = xp[0, i] - params[0]
            dy = xp[1, i] - params[1]
            zp[0, i] = np.sqrt(dx * dx + dy * dy)
            zp[1, i] = _atan2(dy, dx)
            r2 = max(dx * dx + dy * dy, 1e-12)
            rr = np.sqrt(r2)
            H[0, 0, i] = dx / rr
            H[0, 1, i] = dy / rr
            H[1, 0, i] = -dy / r2
            H[1, 1, i] = dx / r2
    else:
        for d in range(m):
            for i in range(lanes):
                zp[d, i] = xp[d, i]
                H[d, d, i] = 1.0
    for r in range(n):
        for c in range(m):
            for i in range(lanes):
                C[r, c, i] = 0.0
            for k in range(n):
                for i in range(lanes):
                    C[r, c, i] += Pp[r, k, i] * H[c, k, i]
    for r in range(m):
        for c in range(r, m):
            for i in range(lanes):
                S[r, c, i] = 0.0
            for k in range(n):
                for i in range(lanes):
                    S[r, c, i] += H[r, k, i] * C[k, c, i]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _add_noise(S: Array, Rl: Array, M: int, nb: int) -> None:  # pragma: no cover
    """``S += (R + R^T) / 2`` (the tracker's, in every model's lane), upper triangle mirrored."""
    m = S.shape[0]
    for r in range(m):
        for c in range(r, m):
            for j in range(M):
                for b in range(nb):
                    S[r, c, j * nb + b] += Rl[r, c, b]
                    S[c, r, j * nb + b] = S[r, c, j * nb + b]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _inverse(
    S: Array, lanes: int, Si: Array, Lc: Array, logdet: Array, ok: Array
) -> None:  # pragma: no cover
    """``S^-1``, ``log det S`` and the Cholesky factor ``S = L L^T`` of the SPD ``S`` lane by
    lane; ``ok`` is 1 where ``S`` is positive definite, 0 elsewhere (its outputs are then
    meaningless).

    2x2: ``S^-1 = [[d, -b], [-b, a]] / (a d - b^2)``, ``log det = log(a d - b^2)``,
    ``L = [[sqrt a, 0], [b / sqrt a, sqrt(d - b^2 / a)]]``; larger: Cholesky, then ``S^-1 =
    L^-T L^-1`` column by column.
    """
    m = S.shape[0]
    if m == 2:
        for i in range(lanes):
            a = S[0, 0, i]
            b = S[0, 1, i]
            d = S[1, 1, i]
            dt = a * d - b * b
            ok[i] = 1.0 if (a > 0.0) & (dt > 0.0) else 0.0
            inv = 1.0 / dt
            Si[0, 0, i] = d * inv
            Si[1, 1, i] = a * inv
            Si[0, 1, i] = -b * inv
            Si[1, 0, i] = -b * inv
            l0 = np.sqrt(a)
            l1 = b / l0
            Lc[0, 0, i] = l0
            Lc[1, 0, i] = l1
            Lc[1, 1, i] = np.sqrt(d - l1 * l1)
        for i in range(lanes):
            logdet[i] = np.log(S[0, 0, i] * S[1, 1, i] - S[0, 1, i] * S[0, 1, i]) if ok[i] else 0.0
        return
    for i in range(lanes):
        ok[i] = 1.0
    for r in range(m):
        for c in range(r + 1):
            for i in range(lanes):
                acc = S[r, c, i]
                for k in range(c):
                    acc -= Lc[r, k, i] * Lc[c, k, i]
                if r == c:
                    ok[i] = ok[i] if acc > 0.0 else 0.0
                    Lc[r, r, i] = np.sqrt(acc)
                else:
                    Lc[r, c, i] = acc / Lc[c, c, i]
    for c in range(m):
        for r in range(m):
            for i in range(lanes):
                acc = 1.0 if r == c else 0.0
                for k in range(r):
                    acc -= Lc[r, k, i] * Si[k, c, i]
                Si[r, c, i] = acc / Lc[r, r, i]
        for r in range(m - 1, -1, -1):
            for i in range(lanes):
                acc = Si[r, c, i]
                for k in range(r + 1, m):
                    acc -= Lc[k, r, i] * Si[k, c, i]
                Si[r, c, i] = acc / Lc[r, r, i]
    for i in range(lanes):
        acc = 0.0
        if ok[i]:
            for r in range(m):
                acc += 2.0 * np.log(Lc[r, r, i])
        logdet[i] = acc


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _innovation(
    z: Array, t0: int, nb: int, M: int, kind: int, zp: Array, nu: Array
) -> None:  # pragma: no cover
    """``nu = z - zp`` per model lane (the bearing wrapped)."""
    m = zp.shape[0]
    for d in range(m):
        for j in range(M):
            for b in range(nb):
                nu[d, j * nb + b] = z[t0 + b, d] - zp[d, j * nb + b]
    if kind == RANGE_BEARING:
        for i in range(M * nb):
            nu[1, i] = _wrap(nu[1, i])


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _update(
    Xp: Array, Pp: Array, zp: Array, C: Array, H: Array, Rl: Array, Si: Array, Lc: Array,
    logdet: Array, ok: Array, nu: Array, M: int, nb: int, filter_kind: int, Sinu: Array,
    Kg: Array, T: Array, A: Array, nis: Array, loglik: Array, innov: Array, Xu: Array, Pu: Array,
) -> None:  # pragma: no cover
    """The measurement update of every model lane: ``K = C S^-1``, ``x = xp + K nu``, ``P =
    Pp - K C^T`` (UKF) or ``(I - K H) Pp (I - K H)^T + K R K^T`` (Joseph form, EKF), symmetrized;
    ``NIS = nu^T S^-1 nu``, ``log Lambda = -(NIS + log det S + m log 2 pi) / 2`` and the whitened
    innovation ``L^-1 nu`` (``T``, ``A``: ``(n, n, L)`` scratch)."""
    n = Xp.shape[0]
    m = zp.shape[0]
    lanes = M * nb
    for r in range(m):
        for i in range(lanes):
            Sinu[r, i] = 0.0
        for c in range(m):
            for i in range(lanes):
                Sinu[r, i] += Si[r, c, i] * nu[c, i]
    for i in range(lanes):
        nis[i] = 0.0
    for r in range(m):
        for i in range(lanes):
            nis[i] += nu[r, i] * Sinu[r, i]
    for i in range(lanes):
        loglik[i] = -0.5 * (nis[i] + logdet[i] + m * LOG_2PI)
    # whitened innovation L^-1 nu (S = L L^T): signed, |.|^2 = NIS
    for r in range(m):
        for i in range(lanes):
            innov[r, i] = nu[r, i]
        for k in range(r):
            for i in range(lanes):
                innov[r, i] -= Lc[r, k, i] * innov[k, i]
        for i in range(lanes):
            innov[r, i] = innov[r, i] / Lc[r, r, i]
    for r in range(n):
        for c in range(m):
            for i in range(lanes):
                Kg[r, c, i] = 0.0
            for k in range(m):
                for i in range(lanes):
                    Kg[r, c, i] += C[r, k, i] * Si[k, c, i]
        for i in range(lanes):
            Xu[r, i] = 0.0
        for k in range(m):
            for i in range(lanes):
                Xu[r, i] += C[r, k, i] * Sinu[k, i]
        for i in range(lanes):
            Xu[r, i] += Xp[r, i]
    if filter_kind != EKF:
        # P = Pp - K C^T
        for r in range(n):
            for c in range(n):
                for i in range(lanes):
                    Pu[r, c, i] = 0.0
                for k in range(m):
                    for i in range(lanes):
                        Pu[r, c, i] += Kg[r, k, i] * C[c, k, i]
                for i in range(lanes):
                    Pu[r, c, i] = Pp[r, c, i] - Pu[r, c, i]
    else:
        # Joseph form: T = (I - K H) Pp, P = T (I - K H)^T + K R K^T; I - K H into C
        for r in range(n):
            for c in range(n):
                for i in range(lanes):
                    T[r, c, i] = 1.0 if r == c else 0.0
                for k in range(m):
                    for i in range(lanes):
                        T[r, c, i] -= Kg[r, k, i] * H[k, c, i]
        _joseph(T, Pp, Kg, Rl, M, nb, A, Pu)
    for r in range(n):
        for c in range(r, n):
            for i in range(lanes):
                v = 0.5 * (Pu[r, c, i] + Pu[c, r, i])
                Pu[r, c, i] = v
                Pu[c, r, i] = v


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _joseph(
    IKH: Array, Pp: Array, Kg: Array, Rl: Array, M: int, nb: int, A: Array, Pu: Array
) -> None:  # pragma: no cover
    """``Pu = (I - K H) Pp (I - K H)^T + K R K^T`` lane by lane (``IKH = I - K H``; ``A``
    scratch for ``(I - K H) Pp``: the UKF's eigenvalue array, unused by the EKF)."""
    n = Pp.shape[0]
    m = Kg.shape[1]
    lanes = M * nb
    for r in range(n):
        for c in range(n):
            for i in range(lanes):
                A[r, c, i] = 0.0
            for k in range(n):
                for i in range(lanes):
                    A[r, c, i] += IKH[r, k, i] * Pp[k, c, i]
    for r in range(n):
        for c in range(n):
            for i in range(lanes):
                Pu[r, c, i] = 0.0
            for k in range(n):
                for i in range(lanes):
                    Pu[r, c, i] += A[r, k, i] * IKH[c, k, i]
            for k in range(m):
                for q in range(m):
                    for j in range(M):
                        for b in range(nb):
                            i = j * nb + b
                            Pu[r, c, i] += Kg[r, k, i] * Rl[k, q, b] * Kg[c, q, i]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _keep_prediction(
    Xp: Array, Pp: Array, M: int, nb: int, det: Array, Xu: Array, Pu: Array
) -> None:  # pragma: no cover
    """A missed detection's posterior is its prediction: ``Xu, Pu <- Xp, Pp`` in its lanes
    (nothing to do, and no pass over ``Pu``, when the block has none)."""
    n = Xp.shape[0]
    missed = 0
    for b in range(nb):
        missed += det[b] == 0.0
    if missed == 0:  # nothing to replace (the common case)
        return
    for r in range(n):
        for j in range(M):
            for b in range(nb):
                i = j * nb + b
                Xu[r, i] = Xu[r, i] if det[b] > 0.0 else Xp[r, i]
        for c in range(n):
            for j in range(M):
                for b in range(nb):
                    i = j * nb + b
                    Pu[r, c, i] = Pu[r, c, i] if det[b] > 0.0 else Pp[r, c, i]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _probabilities(
    loglik: Array, cbar: Array, M: int, nb: int, det: Array, mu_new: Array, top: Array
) -> None:  # pragma: no cover
    """Model probabilities ``mu_j ∝ Lambda_j cbar_j`` as a log-sum-exp (``Lambda_j = 1`` on a
    missed detection; ``top`` scratch)."""
    for b in range(nb):
        top[b] = -np.inf
    for j in range(M):
        for b in range(nb):
            cb = cbar[j, b]
            ll = loglik[j * nb + b] if det[b] else 0.0
            lp = ll + (np.log(cb) if cb > 0.0 else -np.inf)
            mu_new[j, b] = lp
            top[b] = max(top[b], lp)
    for j in range(M):
        for b in range(nb):
            mu_new[j, b] = np.exp(mu_new[j, b] - top[b])
    for b in range(nb):
        top[b] = 0.0
    for j in range(M):
        for b in range(nb):
            top[b] += mu_new[j, b]
    for j in range(M):
        for b in range(nb):
            mu_new[j, b] = mu_new[j, b] / top[b]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _combine_lanes(
    mu_new: Array, Xu: Array, Pu: Array, M: int, nb: int, xhat: Array, Phat: Array
) -> None:  # pragma: no cover
    """Output combination with the spread-of-means term (SPEC §1 step 4), lane by lane:
    ``x_hat = sum_j mu_j x_j``, ``P_hat = sum_j mu_j [P_j + (x_j - x_hat)(x_j - x_hat)^T]``."""
    n = Xu.shape[0]
    for d in range(n):
        for b in range(nb):
            xhat[d, b] = 0.0
        for j in range(M):
            for b in range(nb):
                xhat[d, b] += mu_new[j, b] * Xu[d, j * nb + b]
    for r in range(n):
        for c in range(r, n):
            for b in range(nb):
                Phat[r, c, b] = 0.0
            for j in range(M):
                for b in range(nb):
                    i = j * nb + b
                    Phat[r, c, b] += mu_new[j, b] * (
                        Pu[r, c, i] + (Xu[r, i] - xhat[r, b]) * (Xu[c, i] - xhat[c, b]))
            for b in range(nb):
                Phat[c, r, b] = Phat[r, c, b]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _mixture_nis(
    z: Array, t0: int, zp: Array, S: Array, cbar: Array, M: int, nb: int, kind: int, hz: Array,
    Sm: Array, Smi: Array, Smc: Array, nu: Array, okm: Array, nism: Array,
) -> None:  # pragma: no cover
    """NIS of ``z`` under the predicted measurement mixture (weights ``cbar``), moment-matched
    (:func:`imm_gym.tracking.imm.measurement_mixture`): ``z_mix = z_0 + sum_j cbar_j (z_j -
    z_0)``, ``S_mix = sum_j cbar_j [S_j + (z_j - z_mix)(z_j - z_mix)^T]`` (bearing differences
    wrapped), ``NIS = nu^T S_mix^-1 nu`` with ``nu = z - z_mix``; ``okm`` is 0 where ``S_mix``
    is not positive definite."""
    m = zp.shape[0]
    for d in range(m):
        for b in range(nb):
            hz[d, b] = 0.0
        for j in range(M):
            for b in range(nb):
                diff = zp[d, j * nb + b] - zp[d, b]
                if kind == RANGE_BEARING and d == 1:
                    diff = _wrap_near(diff)
                hz[d, b] += cbar[j, b] * diff
        for b in range(nb):
            hz[d, b] = zp[d, b] + hz[d, b]
    for r in range(m):
        for c in range(m):
            for b in range(nb):
                Sm[r, c, b] = 0.0
    for j in range(M):
        for d in range(m):
            for b in range(nb):
                nu[d, b] = zp[d, j * nb + b] - hz[d, b]
        if kind == RANGE_BEARING:
            for b in range(nb):
                nu[1, b] = _wrap_near(nu[1, b])
        for r in range(m):
            for c in range(m):
                for b in range(nb):
                    Sm[r, c, b] += cbar[j, b] * (S[r, c, j * nb + b] + nu[r, b] * nu[c, b])
    _inverse(Sm, nb, Smi, Smc, nism, okm)
    for d in range(m):
        for b in range(nb):
            nu[d, b] = z[t0 + b, d] - hz[d, b]
    if kind == RANGE_BEARING:
        for b in range(nb):
            nu[1, b] = _wrap(nu[1, b])
    for b in range(nb):
        nism[b] = 0.0
    for r in range(m):
        for c in range(m):
            for b in range(nb):
                nism[b] += nu[r, b] * Smi[r, c, b] * nu[c, b]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _store(
    t0: int, nb: int, M: int, det: Array, mixture_nis: bool, ok: Array, okm: Array, nism: Array,
    Xu: Array, Pu: Array, mu_new: Array, cbar: Array, loglik: Array, nis: Array, innov: Array,
    xhat: Array, Phat: Array, x_out: Array, P_out: Array,
    mu_out: Array, cbar_out: Array, loglik_out: Array, model_nis_out: Array, innov_out: Array,
    nis_out: Array, xhat_out: Array, Phat_out: Array, failed_out: NDArray[np.bool_],
) -> int:  # pragma: no cover
    """The block's outputs into the trackers' rows (a missed detection keeps the prediction, its
    likelihood terms 0; a tracker whose innovation covariance, or its mixture's, is not positive
    definite, or whose mode probabilities, combined estimate or its variances are not finite, is
    flagged and filled with NaN); returns the number of such trackers.

    Every tracker's outputs first, lane loop innermost (as :func:`_load`), then the failed
    trackers' rows overwritten with NaN."""
    n = Xu.shape[0]
    m = innov.shape[0]
    # every tracker's outputs, lane by lane (contiguous reads); the failed ones after
    for j in range(M):
        for b in range(nb):
            i = j * nb + b
            seen = det[b] > 0.0
            mu_out[np.uint64(t0 + b), j] = mu_new[j, b]
            cbar_out[np.uint64(t0 + b), j] = cbar[j, b]
            loglik_out[np.uint64(t0 + b), j] = loglik[i] if seen else 0.0
            model_nis_out[np.uint64(t0 + b), j] = nis[i] if seen else 0.0
        for d in range(m):
            for b in range(nb):
                innov_out[np.uint64(t0 + b), j, d] = innov[d, j * nb + b] if det[b] > 0.0 else 0.0
        for r in range(n):
            for b in range(nb):
                x_out[np.uint64(t0 + b), j, r] = Xu[r, j * nb + b]
            for c in range(n):
                for b in range(nb):
                    P_out[np.uint64(t0 + b), j, r, c] = Pu[r, c, j * nb + b]
    for b in range(nb):
        nis_out[np.uint64(t0 + b)] = nism[b] if det[b] > 0.0 and mixture_nis else 0.0
    for r in range(n):
        for b in range(nb):
            xhat_out[np.uint64(t0 + b), r] = xhat[r, b]
        for c in range(n):
            for b in range(nb):
                Phat_out[np.uint64(t0 + b), r, c] = Phat[r, c, b]
    failures = 0
    for b in range(nb):
        t = t0 + b
        seen = det[b] > 0.0
        failed = False
        for j in range(M):
            failed = failed or not ok[j * nb + b] > 0.0
            failed = failed or not mu_new[j, b] - mu_new[j, b] == 0.0  # NaN or inf
        for r in range(n):
            failed = failed or not xhat[r, b] - xhat[r, b] == 0.0
            failed = failed or not Phat[r, r, b] - Phat[r, r, b] == 0.0
        if seen and mixture_nis:
            failed = failed or not okm[b] > 0.0
        failed_out[t] = failed
        if failed:
            failures += 1
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
    return failures


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
