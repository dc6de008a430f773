r"""Compiled step of the whole environment core for the built-in banks (numba, no Gymnasium).

The compiled engine of :mod:`imm_gym.sim.engines`: with a bank that has the compiled IMM kernel
(:mod:`imm_gym.tracking.kernels.imm`: built-in sensor and filter) one step of all banks of N slots
is one call of :func:`env_step`. Its numpy reference, :func:`imm_gym.sim.engines.numpy_step`,
composes :mod:`imm_gym.sim.actions`, the tracker's ``step`` and :mod:`imm_gym.tracking.fusion`;
the tests hold the two equal over whole episodes. Per slot ``t``:

1. TPM from the action ``a`` (clipped to [-1, 1]): ``scale`` mode
   :math:`\pi_{ij} \leftarrow \pi_{ij}\, f^{a_{ij}}` (``f = max_factor``), ``set`` mode
   :math:`\pi_i = \operatorname{softmax}(\lambda a_i)` (``lambda = logit_scale``), the stay
   modes each row's stay moved on the logit scale (:mod:`imm_gym.sim.actions`); then each row
   normalized and floored to ``[p_min, 1 - p_min]`` as :func:`imm_gym.tracking.tpm.apply_floor` (a
   row that already sums to 1 and satisfies the floor passes bit for bit);
2. bank A's IMM cycle with that TPM (:func:`imm_gym.tracking.kernels.imm.imm_step`: the slots
   in blocks of ``TRACKER_BLOCK`` lanes, structure of arrays);
3. with ``parallel``: bank B's cycle with the fixed TPM, the entropy fusion (TIP-IMM eq. 19)
   :math:`U = \frac{H(U_B)}{H(U_A) + H(U_B)} U_A + \frac{H(U_A)}{H(U_A) + H(U_B)} U_B`,
   :math:`H(u) = -\sum_j u_j \log_2 u_j` (equal weights when both entropies are 0), fed back as
   both banks' model probabilities, and the output :math:`\hat x = \sum_j U_j x_j^A` with the
   spread term (SPEC §6);
4. with ``shadow``: the shadow IMM (fixed TPM, its own probabilities);
5. scores: position error :math:`e = \lVert \hat p - p \rVert` capped at ``divergence_error``
   (NaN of a failed tracker becomes the cap), the shadow's, and the divergence flag (a failed
   bank, the error above the cap or ``P_xx + P_yy`` above ``divergence_cov``). The reward terms
   are computed from these errors by :mod:`imm_gym.sim.rewards`.

Every output array is freshly allocated; slots are independent (a slot's numbers do not depend
on the batch it is in), so the vector env replays the scalar env bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.bank_step import BankStep
from imm_gym.tracking.kernels.imm import combine_into, imm_step, imm_step_one

Array = NDArray[np.float64]

# fmt: off

_ROW_SUM_EPS = 4 * float(np.finfo(np.float64).eps)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _floor_row(
    tpm: Array, t: int, i: int, p_min: float, fixed: NDArray[np.bool_]
) -> None:  # pragma: no cover
    """Row ``tpm[t, i]`` normalized and floored in place (:func:`imm_gym.tracking.tpm.apply_floor`).

    Entries below ``p_min`` are raised to it and the free entries rescaled by
    ``(1 - p_min * #floored) / sum(free)``, repeated until no free entry is below (at most M
    passes). ``fixed`` is an ``(M,)`` scratch array.
    """
    M = tpm.shape[2]
    total = 0.0
    for j in range(M):
        total += tpm[t, i, j]
    if abs(total - 1.0) > _ROW_SUM_EPS:
        for j in range(M):
            tpm[t, i, j] = tpm[t, i, j] / total
    if p_min == 0.0:
        return
    for j in range(M):
        fixed[j] = False
    for _ in range(M):
        grew = False
        for j in range(M):
            if not fixed[j] and tpm[t, i, j] < p_min:
                fixed[j] = True
                grew = True
        if not grew:
            return
        free_mass = 0.0
        n_fixed = 0
        for j in range(M):
            if fixed[j]:
                n_fixed += 1
            else:
                free_mass += tpm[t, i, j]
        ratio = (1.0 - p_min * n_fixed) / free_mass
        for j in range(M):
            tpm[t, i, j] = p_min if fixed[j] else tpm[t, i, j] * ratio


#: action modes of :func:`tpm_from_action` (``EnvConfig.action_mode``)
SCALE, SET, STAY, STAY_STEP = 0, 1, 2, 3
ACTION_MODE_CODES = {"scale": SCALE, "set": SET, "stay": STAY, "stay_step": STAY_STEP}


@numba.njit(cache=True, nogil=True, error_model="numpy")
def tpm_from_action(
    action: Array, tpm: Array, mode: int, gain: float, p_min: float, base: Array
) -> Array:  # pragma: no cover
    """The TPMs ``(N, M, M)`` that the actions produce (step 1 of the module doc;
    :mod:`imm_gym.sim.actions` gives the equations of each mode).

    ``mode`` is :data:`SCALE`, :data:`SET`, :data:`STAY` or :data:`STAY_STEP`; ``gain`` is
    ``max_factor`` (``scale``) or ``logit_scale``; ``base (N, M, M)`` are the trackers' own TPMs
    (the stay modes' structure, and ``stay``'s starting stays); actions (``(N, M*M)``, or
    ``(N, M)`` in the stay modes) are clipped to [-1, 1] here.
    """
    N, M, _ = tpm.shape
    out = np.empty((N, M, M))
    fixed = np.empty(M, dtype=np.bool_)
    log_gain = np.log(gain)  # f^a = exp(a log f): exp is cheaper than pow, and f^0 = 1 exactly
    least_leave = (M - 1) * p_min
    for t in range(N):
        for i in range(M):
            if mode == SET:
                top = -np.inf
                for j in range(M):
                    logit = gain * min(max(action[t, i * M + j], -1.0), 1.0)
                    out[t, i, j] = logit
                    top = max(top, logit)
                for j in range(M):
                    out[t, i, j] = np.exp(out[t, i, j] - top)
            elif mode == STAY or mode == STAY_STEP:
                a = min(max(action[t, i], -1.0), 1.0)
                source = base if mode == STAY else tpm
                stay0 = source[t, i, i]
                logit = np.log(stay0) - np.log1p(-stay0) + gain * a
                leave0 = 1.0 - base[t, i, i]
                most_leave = max(1.0 - 1.0 / M, leave0)
                leave = min(max(1.0 / (1.0 + np.exp(logit)), least_leave), most_leave)
                for j in range(M):
                    if a == 0.0:
                        out[t, i, j] = source[t, i, j]
                    elif j == i:
                        out[t, i, j] = 1.0 - leave
                    elif leave0 > 0.0:
                        out[t, i, j] = leave * (base[t, i, j] / leave0)
                    else:
                        out[t, i, j] = leave * (1.0 / max(M - 1, 1))
            else:
                for j in range(M):
                    a = min(max(action[t, i * M + j], -1.0), 1.0)
                    out[t, i, j] = tpm[t, i, j] * np.exp(a * log_gain)
            _floor_row(out, t, i, p_min, fixed)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def step_inputs(
    k: NDArray[np.int64], horizon: int, z: Array, detected: NDArray[np.bool_], truth: Array,
    true_model: NDArray[np.int64],
) -> tuple[
    NDArray[np.int64], NDArray[np.int64], Array, NDArray[np.bool_], Array, NDArray[np.int64]
]:  # pragma: no cover
    """What the step of every slot ``t`` reads, into fresh arrays: its step index
    ``k1_t = min(k_t + 1, K)`` (twice: the core's counter and the info's copy), the measurement
    ``z[t, k1_t]``, the detection flag ``detected[t, k1_t]``, the true state ``truth[t, k1_t]``
    and the true model ``true_model[t, k1_t - 1]`` of the interval it ends (``K = horizon``;
    ``z (N, K+1, m)``, ``detected (N, K+1)``, ``truth (N, K+1, d)``, ``true_model (N, K)``).
    """
    N = k.shape[0]
    k1 = np.empty(N, dtype=np.int64)
    step = np.empty(N, dtype=np.int64)
    z_k = np.empty((N, z.shape[2]))
    det = np.empty(N, dtype=np.bool_)
    truth_k = np.empty((N, truth.shape[2]))
    model = np.empty(N, dtype=np.int64)
    for t in range(N):
        kt = min(k[t] + 1, horizon)
        k1[t] = kt
        step[t] = kt
        z_k[t] = z[t, kt]
        det[t] = detected[t, kt]
        truth_k[t] = truth[t, kt]
        model[t] = true_model[t, kt - 1]
    return k1, step, z_k, det, truth_k, model


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _entropy(u: Array, t: int) -> float:  # pragma: no cover
    """Shannon entropy in bits of ``u[t]``, ``0 log 0 = 0``
    (:func:`imm_gym.tracking.fusion.entropy`)."""
    acc = 0.0
    for j in range(u.shape[1]):
        acc += u[t, j] * np.log2(u[t, j]) if u[t, j] > 0.0 else 0.0
    return -acc


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _fuse_into(t: int, u_a: Array, u_b: Array, U: Array) -> None:  # pragma: no cover
    """Entropy-weighted fusion (eq. 19) of slot ``t`` into ``U[t]`` (as :func:`.fusion.fuse`)."""
    M = U.shape[1]
    h_a = _entropy(u_a, t)
    h_b = _entropy(u_b, t)
    total = h_a + h_b
    w_a = h_b / total if total > 0.0 else 0.5
    acc = 0.0
    for j in range(M):
        U[t, j] = w_a * u_a[t, j] + (1.0 - w_a) * u_b[t, j]
        acc += U[t, j]
    for j in range(M):
        U[t, j] = U[t, j] / acc


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bank_step(
    x: Array, P: Array, mu: Array, tpm: Array, z: Array, detected: NDArray[np.bool_], bank: tuple,
    mixture_nis: bool, one: bool,
) -> tuple[
    Array, Array, Array, Array, Array, Array, Array, Array, Array, Array, NDArray[np.bool_]
]:  # pragma: no cover
    """One IMM cycle of a bank into fresh arrays: ``(x, P, mu, cbar, loglik, model_nis,
    innovation, nis, x_hat, P_hat, failed)`` (shapes as :meth:`imm_gym.tracking.imm.IMM.step`;
    ``bank`` is :attr:`imm_gym.tracking.imm.IMM.kernel_args`; ``nis`` is 0 without
    ``mixture_nis``), through
    :func:`~imm_gym.tracking.kernels.imm.imm_step_one` where ``one`` (a constant)."""
    N, M, n = x.shape
    x_out = np.empty((N, M, n))
    P_out = np.empty((N, M, n, n))
    mu_out = np.empty((N, M))
    cbar = np.empty((N, M))
    loglik = np.empty((N, M))
    model_nis = np.empty((N, M))
    innovation = np.empty((N, M, z.shape[1]))
    nis = np.empty(N)
    x_hat = np.empty((N, n))
    P_hat = np.empty((N, n, n))
    failed = np.empty(N, dtype=np.bool_)
    if one:
        imm_step_one(x, P, mu, tpm, z, detected, *bank, mixture_nis, x_out, P_out, mu_out, cbar,
                     loglik, model_nis, innovation, nis, x_hat, P_hat, failed)
    else:
        imm_step(x, P, mu, tpm, z, detected, *bank, mixture_nis, x_out, P_out, mu_out, cbar,
                 loglik, model_nis, innovation, nis, x_hat, P_hat, failed)
    return x_out, P_out, mu_out, cbar, loglik, model_nis, innovation, nis, x_hat, P_hat, failed


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _capped_error(
    x_hat: Array, truth: Array, t: int, cap: float
) -> tuple[float, float]:  # pragma: no cover
    """``(e, min(e, cap))`` for slot ``t``, ``e = |p_hat - p|`` (a NaN error is capped)."""
    dx = x_hat[t, 0] - truth[t, 0]
    dy = x_hat[t, 1] - truth[t, 1]
    e = np.sqrt(dx * dx + dy * dy)
    return e, e if e <= cap else cap


@numba.njit(cache=True, nogil=True, error_model="numpy")
def env_step(
    action: Array, tpm: Array, mode: int, gain: float, p_min: float, x_a: Array, P_a: Array,
    mu_a: Array, x_b: Array, P_b: Array, mu_b: Array, x_s: Array, P_s: Array, mu_s: Array,
    fixed_tpm: Array, shadow_tpm: Array, stay_base: Array, z: Array,
    detected: NDArray[np.bool_], truth: Array,
    bank: tuple, parallel: bool, shadow: bool, divergence_error: float, divergence_cov: float,
) -> BankStep:  # pragma: no cover
    """One step of all banks of N slots (the module docstring's steps 1-5).

    Args:
        action: ``(N, M*M)`` (the stay modes: ``(N, M)``) finite actions (clipped here); tpm:
            ``(N, M, M)`` current TPMs.
        mode, gain, p_min: the action mode (:data:`SCALE`, :data:`SET`, :data:`STAY`,
            :data:`STAY_STEP`), its ``max_factor`` or ``logit_scale``, and the floor.
        x_a, P_a, mu_a: bank A's posterior ``(N, M, n)``, ``(N, M, n, n)``, ``(N, M)``; x_b, P_b,
            mu_b: bank B's; x_s, P_s, mu_s: the shadow IMM's.
        fixed_tpm, shadow_tpm: ``(N, M, M)`` fixed TPMs of bank B and of the shadow.
        stay_base: ``(N, M, M)`` the TPMs the ``stay`` mode moves from (bank B's, or the stay
            bank's centre: :attr:`imm_gym.sim.core.TrackingCore.stay_base_tpms`).
        z: ``(N, m)`` measurements; detected: ``(N,)``; truth: ``(N, 4+)`` true states.
        bank: the bank's kernel constants (:attr:`imm_gym.tracking.imm.IMM.kernel_args`).
        parallel, shadow: run bank B (and fuse), the shadow IMM.

    Returns:
        the :class:`~imm_gym.sim.bank_step.BankStep` of the slots, fresh arrays.
    """
    return env_step_body(action, tpm, mode, gain, p_min, x_a, P_a, mu_a, x_b, P_b, mu_b, x_s,
                         P_s, mu_s, fixed_tpm, shadow_tpm, stay_base, z, detected, truth, bank,
                         parallel, shadow, divergence_error, divergence_cov, False)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def env_step_one(
    action: Array, tpm: Array, mode: int, gain: float, p_min: float, x_a: Array, P_a: Array,
    mu_a: Array, x_b: Array, P_b: Array, mu_b: Array, x_s: Array, P_s: Array, mu_s: Array,
    fixed_tpm: Array, shadow_tpm: Array, stay_base: Array, z: Array,
    detected: NDArray[np.bool_], truth: Array,
    bank: tuple, parallel: bool, shadow: bool, divergence_error: float, divergence_cov: float,
) -> BankStep:  # pragma: no cover
    """:func:`env_step` for one slot whose tracker fits
    :func:`~imm_gym.tracking.kernels.imm.imm_step_one` (the scalar env's: its banks' cycles in
    less than half the time, the same numbers bit for bit; compiled on first use)."""
    return env_step_body(action, tpm, mode, gain, p_min, x_a, P_a, mu_a, x_b, P_b, mu_b, x_s,
                         P_s, mu_s, fixed_tpm, shadow_tpm, stay_base, z, detected, truth, bank,
                         parallel, shadow, divergence_error, divergence_cov, True)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def env_step_body(
    action: Array, tpm: Array, mode: int, gain: float, p_min: float, x_a: Array, P_a: Array,
    mu_a: Array, x_b: Array, P_b: Array, mu_b: Array, x_s: Array, P_s: Array, mu_s: Array,
    fixed_tpm: Array, shadow_tpm: Array, stay_base: Array, z: Array,
    detected: NDArray[np.bool_], truth: Array,
    bank: tuple, parallel: bool, shadow: bool, divergence_error: float, divergence_cov: float,
    one: bool,
) -> BankStep:  # pragma: no cover
    """The body of :func:`env_step`, :func:`env_step_one` and
    :func:`imm_gym.sim.solo.solo_step` (``one``: a constant, :func:`env_step_one`'s cycle)."""
    N, M, _ = x_a.shape
    new_tpm = tpm_from_action(action, tpm, mode, gain, p_min, stay_base)
    xa, Pa, U, cbar, loglik, model_nis, innovation, nis, x_hat, P_hat, failed = _bank_step(
        x_a, P_a, mu_a, new_tpm, z, detected, bank, True, one)
    xb, Pb, Ub = x_b, P_b, mu_b
    if parallel:
        xb, Pb, Ub, _, _, _, _, _, _, _, failed_b = _bank_step(
            x_b, P_b, mu_b, fixed_tpm, z, detected, bank, False, one)
        u_a = U
        U = np.empty((N, M))
        for t in range(N):
            failed[t] = failed[t] or failed_b[t]
            _fuse_into(t, u_a, Ub, U)
            combine_into(t, U, xa, Pa, x_hat, P_hat)
    xs, Ps, mus, xs_hat = x_s, P_s, mu_s, x_hat
    cbar_s, loglik_s = np.zeros((N, M)), np.zeros((N, M))
    velocity_s = np.zeros((N, 2))
    shadow_error = np.zeros(N)
    if shadow:
        xs, Ps, mus, cbar_s, loglik_s, _, _, _, xs_hat, _, _ = _bank_step(
            x_s, P_s, mu_s, shadow_tpm, z, detected, bank, False, one)
    velocity = np.empty((N, 2))
    error = np.empty(N)
    diverged = np.empty(N, dtype=np.bool_)
    for t in range(N):
        e, error[t] = _capped_error(x_hat, truth, t, divergence_error)
        velocity[t, 0] = x_hat[t, 2]
        velocity[t, 1] = x_hat[t, 3]
        diverged[t] = (
            failed[t]
            or not e <= divergence_error
            or not P_hat[t, 0, 0] + P_hat[t, 1, 1] <= divergence_cov
        )
        if shadow:
            shadow_error[t] = _capped_error(xs_hat, truth, t, divergence_error)[1]
            velocity_s[t, 0] = xs_hat[t, 2]
            velocity_s[t, 1] = xs_hat[t, 3]
    return BankStep(
        tpm=new_tpm, x_a=xa, P_a=Pa, mode_probs=U, x_b=xb, P_b=Pb, mu_b=Ub, x_s=xs, P_s=Ps,
        mu_s=mus, estimate=x_hat, covariance=P_hat, cbar=cbar, loglik=loglik,
        model_nis=model_nis, innovation=innovation, cbar_s=cbar_s, loglik_s=loglik_s, nis=nis,
        velocity=velocity, velocity_s=velocity_s, position_error=error,
        shadow_position_error=shadow_error, diverged=diverged,
    )
