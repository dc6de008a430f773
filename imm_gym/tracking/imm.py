r"""The Interacting Multiple Model estimator, batched over N trackers × M models (SPEC §1).

One IMM cycle, with ``tpm[i, j] = P(j at k | i at k-1)`` (:mod:`imm_gym.tracking.tpm`):

1. :func:`mix` — ``cbar_j = sum_i pi_ij mu_i``, ``mu_{i|j} = pi_ij mu_i / cbar_j``,
   ``x0_j = sum_i mu_{i|j} x_i``, ``P0_j = sum_i mu_{i|j} [P_i + (x_i - x0_j)(x_i - x0_j)^T]``;
2. model-matched filtering — :func:`imm_gym.tracking.filters.predict` and the filter's ``update``;
3. :func:`update_mode_probs` — ``mu_j ∝ Lambda_j cbar_j``, in the log domain;
4. :func:`combine` — ``x = sum_j mu_j x_j``, ``P = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]``.

The TPM is an input of every step (in the environments it is the agent's action). :class:`IMM`
runs the cycle; :meth:`IMM.run` runs it over a recorded measurement sequence.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.filters import (
    ExtendedKalmanFilter,
    Filter,
    KalmanFilter,
    MeasurementModel,
    UnscentedKalmanFilter,
    Update,
    make_filter,
)
from imm_gym.tracking.kernels import imm as kernels
from imm_gym.tracking.linalg import inv_logdet, mahalanobis
from imm_gym.tracking.models import MotionModel, bank_dim
from imm_gym.tracking.tpm import ROW_SUM_TOL, validate_tpm
from imm_gym.validation import ConfigError, check_range

#: the compiled TPM check's tolerance: half the validator's, so that a row sum near the
#: tolerance gets the validator's own verdict and message
_FAST_ROW_SUM_TOL = 0.5 * ROW_SUM_TOL

Array = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

# The shapes of one tracker's arrays in the kernel's single-tracker cycle (IMM._step_one): made
# once, as a fresh tuple costs a fifth of an allocation, and IMM.step allocates thirteen arrays.
_M1, _N1, _Z1 = kernels.ONE_SHAPE
_ONE_X, _ONE_P, _ONE_MU = (1, _M1, _N1), (1, _M1, _N1, _N1), (1, _M1)
_ONE_INNOVATION, _ONE_XHAT, _ONE_PHAT = (1, _M1, _Z1), (1, _N1), (1, _N1, _N1)
_ONE_Z, _ONE_TPM = (1, _Z1), (1, _M1, _M1)
#: copied for a step without ``detected`` (a copy takes a seventh of ``np.ones(1, bool)``)
_ONE_DETECTED = np.ones(1, dtype=bool)

_TINY = 1e-300

#: ``"auto"`` picks the compiled kernel for the built-in sensors and filters, numpy otherwise.
ENGINES = ("auto", "compiled", "numpy")


@dataclass(frozen=True)
class IMMState:
    """Posterior of N trackers.

    Attributes:
        x: ``(N, M, n)`` model-conditioned states.
        P: ``(N, M, n, n)`` model-conditioned covariances.
        mu: ``(N, M)`` model probabilities.
    """

    x: Array
    P: Array
    mu: Array


@dataclass(frozen=True)
class IMMStep:
    """Outputs of one cycle for N trackers.

    Attributes:
        x: ``(N, n)`` combined estimate; P: ``(N, n, n)`` its covariance.
        mode_probs: ``(N, M)`` updated model probabilities.
        cbar: ``(N, M)`` predicted model probabilities ``cbar_j``.
        loglik: ``(N, M)`` per-model log-likelihoods ``log Lambda_j`` (0 on a missed detection).
        model_nis: ``(N, M)`` per-model normalized innovation squared (0 on a missed detection).
        innovation: ``(N, M, m)`` per-model whitened innovations ``L_j^-1 nu_j`` (0 on a missed
            detection).
        nis: ``(N,)`` NIS of the IMM's predicted measurement density (moment-matched mixture of the
            model-conditioned predictions, weights ``cbar``); 0 on a missed detection.
        detected: ``(N,)`` whether a measurement was used.
        failed: ``(N,)`` trackers whose cycle failed: an innovation covariance not positive
            definite, or mode probabilities, combined estimate or its variances not finite
            (outputs NaN); only with ``IMM.step(..., allow_failure=True)``, else an error.
        z_pred: ``(N, m)`` mean of the predicted measurement mixture (weights ``cbar``), the
            one-step prediction whose error the tuner's objective measures, where the tracker
            computes it (:class:`~imm_gym.tracking.hetero.HeteroIMM`); else None.
    """

    x: Array
    P: Array
    mode_probs: Array
    cbar: Array
    loglik: Array
    model_nis: Array
    innovation: Array
    nis: Array
    detected: BoolArray
    failed: BoolArray
    z_pred: Array | None = None


@dataclass(frozen=True)
class IMMResult:
    """:func:`run` outputs over K steps (the N axis is dropped for a single sequence).

    Attributes:
        x: ``(N, K, n)`` combined estimates; P: ``(N, K, n, n)``.
        mode_probs: ``(N, K, M)``; loglik: ``(N, K, M)``; model_nis: ``(N, K, M)``; nis: ``(N, K)``.
        failed: ``(N,)`` trackers that failed at some step (``allow_failure=True`` only).
        z_pred: ``(N, K, m)`` predicted measurements, where the tracker computes them; else None.
    """

    x: Array
    P: Array
    mode_probs: Array
    loglik: Array
    model_nis: Array
    nis: Array
    failed: BoolArray
    z_pred: Array | None = None


def _new_state(x: Array, P: Array, mu: Array) -> IMMState:
    """``IMMState(x, P, mu)`` without the frozen dataclass's ``__init__`` (one
    ``object.__setattr__`` per field: a fifth of :meth:`IMM.step`'s Python time at N = 1); the
    same object."""
    state = object.__new__(IMMState)
    fields_ = state.__dict__
    fields_["x"] = x
    fields_["P"] = P
    fields_["mu"] = mu
    return state


def _new_step(
    x: Array,
    P: Array,
    mode_probs: Array,
    cbar: Array,
    loglik: Array,
    model_nis: Array,
    innovation: Array,
    nis: Array,
    detected: BoolArray,
    failed: BoolArray,
) -> IMMStep:
    """``IMMStep(...)`` (``z_pred`` None) without the frozen dataclass's ``__init__``, as
    :func:`_new_state`."""
    step = object.__new__(IMMStep)
    fields_ = step.__dict__
    fields_["x"] = x
    fields_["P"] = P
    fields_["mode_probs"] = mode_probs
    fields_["cbar"] = cbar
    fields_["loglik"] = loglik
    fields_["model_nis"] = model_nis
    fields_["innovation"] = innovation
    fields_["nis"] = nis
    fields_["detected"] = detected
    fields_["failed"] = failed
    fields_["z_pred"] = None
    return step


def cycles_by_tracker(
    state: IMMState,
    detected: BoolArray,
    dim_z: int,
    dim_out: int,
    cycle: Callable[[int, IMMState], tuple[IMMState, IMMStep]],
    z_pred: bool = False,
) -> tuple[IMMState, IMMStep]:
    """A batch's cycle run tracker by tracker, after the batch's raised ``LinAlgError``: tracker
    ``i``'s ``cycle(i, its state)``, or where that raises, its failed cycle — every output NaN,
    ``failed`` set, as the compiled engine flags it — joined along the batch.

    Args:
        state: the batch's posterior at k-1; detected: ``(N,)`` whether each had a measurement.
        dim_z, dim_out: the measurement's and the combined estimate's dimensions.
        z_pred: whether the cycle's step has a predicted measurement (NaN where it failed).
    """
    _, M, n = state.x.shape

    def nan(*shape: int) -> Array:
        return np.full((1, *shape), np.nan)

    rows = []
    for i in range(state.x.shape[0]):
        part = slice(i, i + 1)
        one = IMMState(state.x[part], state.P[part], state.mu[part])
        try:
            rows.append(cycle(i, one))
        except np.linalg.LinAlgError:
            rows.append((IMMState(nan(M, n), nan(M, n, n), nan(M)), IMMStep(
                nan(dim_out), nan(dim_out, dim_out), nan(M), nan(M), nan(M), nan(M),
                nan(M, dim_z), nan(), detected[part].copy(), np.array([True]),
                nan(dim_z) if z_pred else None,
            )))
    states, steps = zip(*rows, strict=True)
    posterior = IMMState(*(np.concatenate([getattr(o, f) for o in states])
                           for f in ("x", "P", "mu")))
    return posterior, IMMStep(*(
        None if getattr(steps[0], f.name) is None
        else np.concatenate([getattr(o, f.name) for o in steps])
        for f in fields(IMMStep)
    ))


def finite_outputs(mu: Array, x_hat: Array, P_hat: Array) -> BoolArray:
    """``(N,)`` trackers whose cycle's mode probabilities, combined estimate and its variances
    are finite (NaN where every model's likelihood underflowed, inf after an overflow): the
    others failed, as the compiled kernel flags them."""
    variances = np.diagonal(P_hat, axis1=-2, axis2=-1)
    return (np.isfinite(mu).all(axis=-1) & np.isfinite(x_hat).all(axis=-1)
            & np.isfinite(variances).all(axis=-1))


def _refuse_extra_axes(tpm: Array, M: int) -> None:
    """Raise :class:`ConfigError` unless ``tpm`` is one ``(M, M)`` TPM or one per tracker
    (``validate_tpm`` accepts any leading axes)."""
    if tpm.ndim > 3:
        raise ConfigError(f"tpm must have shape ({M}, {M}) or (N, {M}, {M}), got {tpm.shape}")


def used_measurements(z: Array, detected: BoolArray | None) -> Array:
    """``z`` ``(..., m)`` after checking that every measurement used is finite.

    A missed detection's measurement (``detected`` False, same leading shape as ``z``) is not
    used by the filters, so it may hold anything, NaN included: a row of ``z`` that is not finite
    there is replaced by zeros (any finite value gives the same outputs). ``z`` is returned as
    given when it is finite.

    Raises:
        ConfigError: a measurement marked detected (or every one, without ``detected``) is not
            finite.
    """
    finite = np.isfinite(z).all(axis=-1)
    if finite.all():
        return z
    if detected is None or not finite[detected].all():
        raise ConfigError(
            "z must be finite where detected (mark missed detections with detected=False)"
        )
    return np.where(finite[..., None], z, 0.0)


def moment_match(w: Array, x: Array, P: Array) -> tuple[Array, Array]:
    """Gaussian mixture moments ``x_j = sum_i w_ji x_i``, ``P_j = sum_i w_ji [P_i + dx dx^T]``.

    Computed about a reference point ``r = x_0`` (deviations ``d_i = x_i - r``) as
    ``P_j = sum_i w_ji (P_i + d_i d_i^T) - (x_j - r)(x_j - r)^T``, which equals the spread form when
    ``sum_i w_ji = 1`` and keeps the products small (no cancellation at kilometre ranges).

    Args:
        w: ``(N, J, I)`` weights, rows summing to 1; x: ``(N, I, n)``; P: ``(N, I, n, n)``.

    Returns:
        ``(N, J, n)`` means and ``(N, J, n, n)`` covariances.
    """
    N, I, n = x.shape
    ref = x[:, :1, :]
    d = x - ref
    second = (P + d[..., :, None] * d[..., None, :]).reshape(N, I, n * n)
    d_bar = w @ d
    P_out = (w @ second).reshape(N, -1, n, n) - d_bar[..., :, None] * d_bar[..., None, :]
    return ref + d_bar, 0.5 * (P_out + np.swapaxes(P_out, -1, -2))


def mix(mu: Array, x: Array, P: Array, tpm: Array) -> tuple[Array, Array, Array]:
    """Interaction step: predicted model probabilities and mixed initial conditions.

    Args:
        mu: ``(N, M)`` model probabilities at k-1.
        x: ``(N, M, n)``; P: ``(N, M, n, n)`` model-conditioned posteriors at k-1.
        tpm: ``(M, M)`` or ``(N, M, M)``.

    Returns:
        ``cbar (N, M)``, ``x0 (N, M, n)``, ``P0 (N, M, n, n)``. If ``cbar_j`` is 0 (model j
        unreachable) its mixing weights fall back to ``mu`` so that ``x0_j`` stays defined.
    """
    joint = tpm * mu[:, :, None]  # (N, i, j): pi_ij mu_i
    cbar = joint.sum(axis=1)
    reachable = cbar > _TINY
    w = np.where(
        reachable[:, None, :], joint / np.where(reachable, cbar, 1.0)[:, None, :], mu[:, :, None]
    )  # mu_{i|j}
    x0, P0 = moment_match(np.swapaxes(w, 1, 2), x, P)
    return cbar, x0, P0


def update_mode_probs(loglik: Array, cbar: Array) -> Array:
    """``mu_j = Lambda_j cbar_j / sum_l Lambda_l cbar_l``, computed as a log-sum-exp.

    Args:
        loglik: ``(N, M)`` log-likelihoods; cbar: ``(N, M)`` predicted model probabilities.
    """
    with np.errstate(divide="ignore"):
        a = loglik + np.log(cbar)
    a = a - a.max(axis=-1, keepdims=True)
    e = np.exp(a)
    return e / e.sum(axis=-1, keepdims=True)


def measurement_loglik(loglik: Array, cbar: Array) -> Array:
    """The IMM's measurement log-likelihood ``log p(z_t | Z^{t-1}) = log sum_j cbar_j Lambda_j``
    (the normalizer of :func:`update_mode_probs`; 0 on a missed detection, where every
    ``Lambda_j = 1``), computed as a log-sum-exp.

    Args:
        loglik: ``(N, M)`` log-likelihoods ``log Lambda_j``; cbar: ``(N, M)`` predicted model
            probabilities.

    Returns:
        ``(N,)``.
    """
    top = loglik.max(axis=-1)
    return top + np.log(np.einsum("nj,nj->n", cbar, np.exp(loglik - top[:, None])))


def combine(mu: Array, x: Array, P: Array) -> tuple[Array, Array]:
    """Output combination with the spread-of-means term.

    Args:
        mu: ``(N, M)``; x: ``(N, M, n)``; P: ``(N, M, n, n)``.

    Returns:
        ``x (N, n)`` and ``P (N, n, n)``.
    """
    x_hat, P_hat = moment_match(mu[:, None, :], x, P)
    return x_hat[:, 0], P_hat[:, 0]


def measurement_mixture(
    sensor: MeasurementModel, cbar: Array, z_pred: Array, S: Array
) -> tuple[Array, Array]:
    """The IMM's predicted measurement density, moment-matched (weights ``cbar``).

    ``z_mix = sum_j cbar_j z_j``, ``S_mix = sum_j cbar_j [S_j + (z_j - z_mix)(z_j - z_mix)^T]``
    (differences through ``sensor.residual``, so bearings are averaged correctly); the density
    whose NIS :class:`IMM` and :class:`imm_gym.tracking.hetero.HeteroIMM` report.

    Args:
        cbar: ``(N, M)``; z_pred: ``(N, M, m)``; S: ``(N, M, m, m)``.
    """
    ref = z_pred[:, :1, :]
    z_mix = ref[:, 0] + np.einsum("nm,nmd->nd", cbar, sensor.residual(z_pred, ref))
    d = sensor.residual(z_pred, z_mix[:, None, :])
    S_mix = np.einsum("nm,nmab->nab", cbar, S + d[..., :, None] * d[..., None, :])
    return sensor.wrap(z_mix), S_mix


class Tracker(Protocol):
    """What runs a bank of models as an IMM over N trackers: :class:`IMM` (one state space,
    the linear CV/CT/CA models) and :class:`imm_gym.tracking.hetero.HeteroIMM` (models in their
    own state spaces). The simulation (:mod:`imm_gym.sim`) needs no more than this.

    Attributes:
        n: dimension of the model-conditioned states (the largest model's).
        T: sampling period (s).
        sensor: the measurement model.
        kernel_args: the constants of the compiled cycle
            (:func:`imm_gym.tracking.kernels.imm.imm_step`), or None where the tracker has none.
    """

    n: int
    T: float
    sensor: MeasurementModel
    kernel_args: tuple | None

    @property
    def n_models(self) -> int: ...

    def init(self, x0: Array, P0: Array, mode_probs: Array | None = None) -> IMMState:
        """The state of N trackers started at ``x0 (N, 4)``, ``P0 (N, 4, 4)``."""
        ...

    def step(
        self,
        state: IMMState,
        tpm: Array,
        z: Array,
        detected: BoolArray | None = None,
        check: bool = True,
        allow_failure: bool = False,
    ) -> tuple[IMMState, IMMStep]:
        """One IMM cycle with ``tpm`` ``(M, M)`` or ``(N, M, M)`` and measurements ``z (N, m)``."""
        ...

    def combine(self, mu: Array, x: Array, P: Array) -> tuple[Array, Array]:
        """The combined estimate ``(N, 4+)`` and covariance of model posteriors ``x``, ``P`` with
        probabilities ``mu (N, M)`` (SPEC §1 step 4)."""
        ...


class IMM:
    """A bank of model-matched filters run as an IMM, batched over N trackers (a
    :class:`Tracker`).

    Args:
        models: the M motion models (:mod:`imm_gym.tracking.models`).
        sensor: the measurement model (:mod:`imm_gym.tracking.sensors`).
        filter: ``"ukf"`` (SVD-UKF, default), ``"ukf-cholesky"`` (its sigma points from the
            Cholesky factor), ``"ekf"`` or ``"kf"`` (linear sensors only), or a
            filter instance.
        T: sampling period (s).
        engine: ``"auto"`` (default), ``"compiled"`` (the fused numba cycle of
            :mod:`imm_gym.tracking.kernels.imm`, built-in sensors and filters) or ``"numpy"``
            (vectorized reference, any measurement model). Both compute the same equations; the
            tests hold them equal.

    Example:
        >>> from imm_gym import IMM, Sonar, paper_bank, stay_tpm
        >>> imm = IMM(paper_bank(), Sonar())
        >>> result = imm.run(z, stay_tpm(3, 0.995), x0, P0)  # z: (K, 2) recorded measurements
    """

    def __init__(
        self,
        models: Sequence[MotionModel],
        sensor: MeasurementModel,
        filter: str | Filter = "ukf",
        T: float = 1.0,
        engine: str = "auto",
    ) -> None:
        if len(models) == 0:
            raise ConfigError("models must contain at least one motion model")
        self.models = tuple(models)
        self.sensor = sensor
        self.filter = make_filter(filter) if isinstance(filter, str) else filter
        if self.filter.name == "kf" and sensor.linear_matrix(4) is None:
            raise ConfigError("filter 'kf' needs a linear sensor; use 'ekf' or 'ukf' for the sonar")
        self.T = check_range("T", T, 0.0, lo_open=True)
        self.n = bank_dim(self.models)
        self.F = np.stack([m.transition_matrix(self.T, self.n) for m in self.models])
        self.Q = np.stack([m.noise_covariance(self.n, self.T) for m in self.models])
        self._Ft = np.ascontiguousarray(np.swapaxes(self.F, -1, -2))
        self._FFt = np.stack([np.kron(F, F).T for F in self.F])
        #: the engine that runs :meth:`step`: ``"compiled"`` or ``"numpy"``
        self.engine = self._choose_engine(engine)
        #: the compiled kernel's bank constants ``(F, Q, R, sensor kind, sensor params, filter
        #: kind, wm, wc, gamma)`` (:func:`imm_gym.tracking.kernels.imm.imm_step`; ``F``, ``Q``,
        #: ``R`` with a leading axis of 1: one bank for all trackers); None with the numpy engine
        self.kernel_args: tuple | None = None
        if self.engine == "compiled":
            kind, params = kernels.sensor_spec(sensor)  # type: ignore[misc]
            if isinstance(self.filter, UnscentedKalmanFilter):
                wm, wc, gamma = self.filter.weights(self.n)
                fkind = kernels.UKF if self.filter.square_root == "svd" else kernels.UKF_CHOLESKY
            else:
                wm = wc = np.zeros(1)
                gamma, fkind = 0.0, kernels.EKF
            R = np.ascontiguousarray(sensor.R, dtype=np.float64)
            self.kernel_args = (
                self.F[None], self.Q[None], R[None], kind, params, fkind, wm, wc, gamma
            )
        self._dim_z = sensor.dim_z
        #: the bank's constants packed for the kernel's single-tracker cycle
        #: (:func:`~imm_gym.tracking.kernels.imm.pack_one`), where one tracker of this bank fits it
        self._bank_one: Array | None = None
        if self.kernel_args is not None and kernels.fits_one(
            1, len(self.models), self.n, sensor.dim_z
        ):
            self._bank_one = kernels.pack_one(*self.kernel_args)

    def _choose_engine(self, engine: str) -> str:
        if engine not in ENGINES:
            raise ConfigError(f"engine must be one of {list(ENGINES)}, got {engine!r}")
        compiled = kernels.sensor_spec(self.sensor) is not None and isinstance(
            self.filter, (UnscentedKalmanFilter, ExtendedKalmanFilter, KalmanFilter)
        )
        if engine == "compiled" and not compiled:
            raise ConfigError(
                "engine 'compiled' supports the built-in sensors (Sonar, PositionSensor) and "
                "filters only; use engine='numpy' for a custom measurement model"
            )
        if engine == "auto":
            return "compiled" if compiled else "numpy"
        return engine

    @property
    def n_models(self) -> int:
        return len(self.models)

    def predict(self, x: Array, P: Array) -> tuple[Array, Array]:
        """Model-matched prediction ``x_j = F_j x0_j``, ``P_j = F_j P0_j F_j^T + Q_j``.

        Same result as :func:`imm_gym.tracking.filters.predict`, computed as one matrix product per
        model over all N trackers with ``vec(F P F^T) = (F ⊗ F) vec(P)`` (far faster than N small
        products when N is large).

        Args:
            x: ``(N, M, n)``; P: ``(N, M, n, n)``.
        """
        N, M, n = x.shape
        x_pred = np.empty_like(x)
        P_pred = np.empty_like(P)
        for j in range(M):
            x_pred[:, j] = x[:, j] @ self._Ft[j]
            P_pred[:, j] = (P[:, j].reshape(N, n * n) @ self._FFt[j]).reshape(N, n, n) + self.Q[j]
        return x_pred, P_pred

    def init(self, x0: Array, P0: Array, mode_probs: Array | None = None) -> IMMState:
        """Initial posterior: every model starts at ``(x0, P0)``.

        Args:
            x0: ``(n,)`` or ``(N, n)``; a 4-dimensional ``x0`` in a 6-dimensional bank gets zero
                acceleration. P0: ``(n, n)`` or ``(N, n, n)``, symmetric positive definite.
            mode_probs: ``(M,)`` or ``(N, M)``; uniform by default.
        """
        x0 = np.atleast_2d(np.asarray(x0, dtype=np.float64))
        P0 = np.asarray(P0, dtype=np.float64)
        if P0.ndim == 2:
            P0 = P0[None]
        N, n0 = x0.shape
        if P0.shape[-2:] != (n0, n0) or P0.shape[0] not in (1, N):
            raise ConfigError(
                f"P0 must have shape ({n0}, {n0}) or ({N}, {n0}, {n0}), got {P0.shape}"
            )
        if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(P0))):
            raise ConfigError("x0 and P0 must be finite")
        scale = np.abs(P0).max(axis=(-2, -1), keepdims=True)
        if np.any(np.abs(P0 - np.swapaxes(P0, -1, -2)) > 1e-9 * scale):
            raise ConfigError("P0 must be symmetric (to 1e-9 of its largest entry)")
        try:
            np.linalg.cholesky(P0)
        except np.linalg.LinAlgError:
            raise ConfigError("P0 must be positive definite") from None
        if n0 not in (4, self.n):
            raise ConfigError(f"x0 must have 4 or {self.n} entries, got {n0}")
        x = np.zeros((N, self.n))
        x[:, :n0] = x0
        P = np.zeros((N, self.n, self.n))
        P[:, :n0, :n0] = P0
        for i in range(n0, self.n):
            P[:, i, i] = max(m.q_acc for m in self.models) * 100.0
        M = self.n_models
        if mode_probs is None:
            mu = np.full((N, M), 1.0 / M)
        else:
            mu = np.broadcast_to(np.asarray(mode_probs, dtype=np.float64), (N, M)).copy()
            if np.any(mu < 0) or not np.allclose(mu.sum(-1), 1.0):
                raise ConfigError("mode_probs must be non-negative and sum to 1")
        return IMMState(
            x=np.repeat(x[:, None], M, axis=1),
            P=np.repeat(P[:, None], M, axis=1),
            mu=mu,
        )

    def step(
        self,
        state: IMMState,
        tpm: Array,
        z: Array,
        detected: BoolArray | None = None,
        check: bool = True,
        allow_failure: bool = False,
    ) -> tuple[IMMState, IMMStep]:
        """One IMM cycle for N trackers.

        Args:
            state: posterior at k-1.
            tpm: ``(M, M)`` or ``(N, M, M)`` TPM used for this step's mixing.
            z: ``(N, m)`` measurements at k.
            detected: ``(N,)``; where False the filters only predict and ``mu = cbar``.
            check: validate ``tpm`` and ``z`` (disable only for inputs already validated).
            allow_failure: flag diverged trackers in ``IMMStep.failed`` (NaN outputs) instead of
                raising ``numpy.linalg.LinAlgError``; the other trackers are unaffected (the
                numpy reference then reruns the cycle tracker by tracker to find them).

        Returns:
            The posterior at k and the step outputs.
        """
        N, M, _ = state.x.shape
        if detected is not None:
            detected = np.asarray(detected, dtype=bool)
            if detected.shape != (N,):
                raise ConfigError(f"detected must have shape ({N},), got {detected.shape}")
        if N == 1 and self._bank_one is not None:
            return self._step_one(state, tpm, z, detected, check, allow_failure)
        if check:
            tpm, z = self._checked(tpm, z, detected, N, M)
        if self.engine == "compiled":
            return self._step_compiled(state, tpm, z, detected, allow_failure)
        if not allow_failure:
            return self._step_numpy(state, tpm, z, detected)
        # failures are flagged, not warned about (as the compiled engine)
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            try:
                return self._step_numpy(state, tpm, z, detected)
            except np.linalg.LinAlgError:
                return self._step_numpy_rows(state, tpm, z, detected)

    def _step_numpy(
        self, state: IMMState, tpm: Array, z: Array, detected: BoolArray | None
    ) -> tuple[IMMState, IMMStep]:
        """The cycle composed of the tracker's own operations (the reference engine): mix,
        predict, update, the mode probabilities' update, combine."""
        N = state.x.shape[0]
        cbar, x0, P0 = mix(state.mu, state.x, state.P, tpm)
        x_pred, P_pred = self.predict(x0, P0)
        upd = self.filter.update(x_pred, P_pred, z[:, None, :], self.sensor)
        if detected is None:
            x, P, loglik, model_nis = upd.x, upd.P, upd.loglik, upd.nis
            innovation = upd.innovation
            det = np.ones(N, dtype=bool)
        else:
            det = detected
            x = np.where(det[:, None, None], upd.x, x_pred)
            P = np.where(det[:, None, None, None], upd.P, P_pred)
            loglik = np.where(det[:, None], upd.loglik, 0.0)
            model_nis = np.where(det[:, None], upd.nis, 0.0)
            innovation = np.where(det[:, None, None], upd.innovation, 0.0)
        mu = update_mode_probs(loglik, cbar)
        x_hat, P_hat = combine(mu, x, P)
        if not finite_outputs(mu, x_hat, P_hat).all():
            raise np.linalg.LinAlgError("mode probabilities or combined estimate not finite")
        nis = np.where(det, self._mixture_nis(cbar, upd, z), 0.0)
        out = IMMStep(
            x_hat, P_hat, mu, cbar, loglik, model_nis, innovation, nis, det, np.zeros(N, dtype=bool)
        )
        return IMMState(x, P, mu), out

    def _step_numpy_rows(
        self, state: IMMState, tpm: Array, z: Array, detected: BoolArray | None
    ) -> tuple[IMMState, IMMStep]:
        """:meth:`_step_numpy` tracker by tracker, after the batch raised
        (:func:`cycles_by_tracker`)."""

        def cycle(i: int, one: IMMState) -> tuple[IMMState, IMMStep]:
            part = slice(i, i + 1)
            tpm_i = tpm if np.ndim(tpm) == 2 else tpm[part]
            det_i = None if detected is None else detected[part]
            return self._step_numpy(one, tpm_i, z[part], det_i)

        seen = np.ones(state.x.shape[0], dtype=bool) if detected is None else detected
        return cycles_by_tracker(state, seen, self.sensor.dim_z, state.x.shape[-1], cycle)

    def _checked(
        self, tpm: Array, z: Array, detected: BoolArray | None, N: int, M: int
    ) -> tuple[Array, Array]:
        """``tpm`` and ``z`` checked as :func:`imm_gym.tracking.tpm.validate_tpm` and
        :func:`used_measurements` do (same errors, same repair of a missed detection's ``z``).

        A C-contiguous float64 ``tpm`` and ``z`` are first checked together by the compiled
        :func:`~imm_gym.tracking.kernels.imm.unclear_inputs` (a few hundred ns instead of
        several µs of numpy reductions); the reference validators run where it says no.
        """
        z = np.asarray(z, dtype=np.float64)
        if z.shape != (N, self.sensor.dim_z):
            raise ConfigError(f"z must have shape ({N}, {self.sensor.dim_z}), got {z.shape}")
        if (
            isinstance(tpm, np.ndarray)
            and tpm.dtype == np.float64
            and tpm.ndim in (2, 3)
            and tpm.shape[-2:] == (M, M)
            and tpm.flags.c_contiguous
        ):
            unclear = kernels.unclear_inputs(tpm, z, _FAST_ROW_SUM_TOL)
        else:
            unclear = kernels.TPM_UNCLEAR | (0 if kernels.all_finite(z) else kernels.Z_UNCLEAR)
        if unclear & kernels.TPM_UNCLEAR:
            tpm = validate_tpm(tpm, M)
        _refuse_extra_axes(tpm, M)
        if tpm.ndim == 3 and tpm.shape[0] != N:
            raise ConfigError(f"tpm has {tpm.shape[0]} matrices for {N} trackers")
        if unclear & kernels.Z_UNCLEAR:
            z = used_measurements(z, detected)
        return tpm, z

    def _step_one(
        self,
        state: IMMState,
        tpm: Array,
        z: Array,
        detected: BoolArray | None,
        check: bool,
        allow_failure: bool,
    ) -> tuple[IMMState, IMMStep]:
        """:meth:`step` for one tracker of the kernel's single-tracker shape, through
        :func:`~imm_gym.tracking.kernels.imm.checked_step_one`: the inputs checked in the same
        compiled call as the cycle. Where that call flags them (or ``tpm`` is not of a shape it
        reads), the reference checks of :meth:`_checked` run (their errors, their repair of a
        missed detection's ``z``) and the cycle runs on what they return."""
        z = np.ascontiguousarray(z, dtype=np.float64)
        if z.shape != _ONE_Z:
            raise ConfigError(f"z must have shape {_ONE_Z}, got {z.shape}")
        if type(tpm) is not np.ndarray or tpm.dtype != np.float64:
            tpm = np.asarray(tpm, dtype=np.float64)
        if tpm.shape == _ONE_TPM[1:]:
            tpm = tpm[None]
        if not tpm.flags.c_contiguous:
            tpm = np.ascontiguousarray(tpm)
        if tpm.shape != _ONE_TPM:
            tpm, z = self._checked(tpm, z, detected, 1, _ONE_TPM[1])
            return self._step_one(state, tpm, z, detected, False, allow_failure)
        if detected is None:
            detected = _ONE_DETECTED.copy()
        empty = np.empty
        x, P, mu, cbar = empty(_ONE_X), empty(_ONE_P), empty(_ONE_MU), empty(_ONE_MU)
        loglik, model_nis, innovation = empty(_ONE_MU), empty(_ONE_MU), empty(_ONE_INNOVATION)
        nis, x_hat, P_hat = empty(1), empty(_ONE_XHAT), empty(_ONE_PHAT)
        failed = empty(1, dtype=bool)
        failures = kernels.checked_step_one(
            state.x, state.P, state.mu, tpm, z, detected, self._bank_one,
            _FAST_ROW_SUM_TOL if check else -1.0,
            x, P, mu, cbar, loglik, model_nis, innovation, nis, x_hat, P_hat, failed,
        )  # fmt: skip
        if failures < 0:
            tpm, z = self._checked(tpm, z, detected, 1, _ONE_TPM[1])
            return self._step_one(state, tpm, z, detected, False, allow_failure)
        if failures and not allow_failure:
            raise np.linalg.LinAlgError(
                "IMM cycle failed for 1 tracker(s): innovation covariance not positive "
                "definite, or outputs not finite"
            )
        return _new_state(x, P, mu), _new_step(
            x_hat, P_hat, mu, cbar, loglik, model_nis, innovation, nis, detected, failed
        )

    def _step_compiled(
        self, state: IMMState, tpm: Array, z: Array, detected: BoolArray | None, allow_failure: bool
    ) -> tuple[IMMState, IMMStep]:
        """The same cycle of N trackers through the fused kernel
        (:func:`~imm_gym.tracking.kernels.imm.imm_step`)."""
        N, M, n = state.x.shape
        if detected is None:
            detected = np.empty(N, dtype=bool)
            detected.fill(True)
        x, P = np.empty((N, M, n)), np.empty((N, M, n, n))
        NM = (N, M)
        mu, cbar, loglik, model_nis = np.empty(NM), np.empty(NM), np.empty(NM), np.empty(NM)
        nis, x_hat, P_hat = np.empty(N), np.empty((N, n)), np.empty((N, n, n))
        innovation = np.empty((N, M, self._dim_z))
        failed = np.empty(N, dtype=bool)
        outs = (x, P, mu, cbar, loglik, model_nis, innovation, nis, x_hat, P_hat, failed)
        tpm = np.asarray(tpm, dtype=np.float64)
        _refuse_extra_axes(tpm, M)
        if tpm.ndim == 2:  # one TPM for all trackers: the kernel reads one per tracker
            tpm = tpm[None] if N == 1 else np.ascontiguousarray(np.broadcast_to(tpm, (N, M, M)))
        failures = kernels.imm_step(
            np.ascontiguousarray(state.x),
            np.ascontiguousarray(state.P),
            np.ascontiguousarray(state.mu),
            tpm,
            np.ascontiguousarray(z, dtype=np.float64),
            np.ascontiguousarray(detected),
            *self.kernel_args,
            True,  # the mixture NIS
            *outs,
        )
        if failures and not allow_failure:
            raise np.linalg.LinAlgError(
                f"IMM cycle failed for {failures} tracker(s): innovation covariance not "
                "positive definite, or outputs not finite"
            )
        return _new_state(x, P, mu), _new_step(
            x_hat, P_hat, mu, cbar, loglik, model_nis, innovation, nis, detected, failed
        )

    def _mixture_nis(self, cbar: Array, upd: Update, z: Array) -> Array:
        """NIS of ``z`` under the IMM's predicted measurement density
        (:func:`measurement_mixture`)."""
        z_mix, S = measurement_mixture(self.sensor, cbar, upd.z_pred, upd.S)
        S_inv, _ = inv_logdet(S)
        return mahalanobis(self.sensor.residual(z, z_mix), S_inv)

    def combine(self, mu: Array, x: Array, P: Array) -> tuple[Array, Array]:
        """Output combination of model posteriors ``x (N, M, n)``, ``P`` with ``mu (N, M)``
        (:func:`combine`)."""
        return combine(mu, x, P)

    def run(
        self,
        z: Array,
        tpm: Array,
        x0: Array,
        P0: Array,
        mode_probs: Array | None = None,
        detected: BoolArray | None = None,
    ) -> IMMResult:
        """Run the IMM over recorded measurements with a fixed TPM (:func:`run`)."""
        return run(self, z, tpm, x0, P0, mode_probs, detected)


def run(
    tracker: Tracker,
    z: Array,
    tpm: Array,
    x0: Array,
    P0: Array,
    mode_probs: Array | None = None,
    detected: BoolArray | None = None,
    allow_failure: bool = False,
    **step_options: Array | None,
) -> IMMResult:
    """Run a tracker over recorded measurements with a fixed TPM: ``init`` then K ``step`` s.

    Args:
        tracker: an :class:`IMM`, a :class:`~imm_gym.tracking.hetero.HeteroIMM`...
        z: ``(K, m)`` one sequence or ``(N, K, m)`` N sequences (measurements at steps 1..K;
            ``x0, P0`` is the prior at step 0).
        tpm: ``(M, M)`` or ``(N, M, M)``.
        x0, P0, mode_probs: the tracker's ``init`` arguments.
        detected: ``(K,)`` or ``(N, K)`` detection flags; all True by default.
        allow_failure: flag failed trackers in ``IMMResult.failed`` instead of raising.
        step_options: further ``step`` arguments (``HeteroIMM``'s ``q_scale``, ``r_scale``).

    Returns:
        An :class:`IMMResult`; for a single ``(K, m)`` sequence the N axis is dropped.
    """
    z = np.asarray(z, dtype=np.float64)
    dim_z = tracker.sensor.dim_z
    single = z.ndim == 2
    if single:
        z = z[None]
        detected = None if detected is None else np.asarray(detected)[None]
    if z.ndim != 3 or z.shape[-1] != dim_z:
        raise ConfigError(f"z must have shape (K, m) or (N, K, m) with m = {dim_z}, got {z.shape}")
    N, K, _ = z.shape
    if detected is not None and np.shape(detected) != (N, K):
        raise ConfigError(
            f"detected must have shape {(N, K)[1 if single else 0 :]}, got {np.shape(detected)}"
        )
    z = used_measurements(z, None if detected is None else np.asarray(detected, dtype=bool))
    tpm = validate_tpm(tpm, tracker.n_models)
    state = tracker.init(x0, P0, mode_probs)
    if state.x.shape[0] == 1 and N > 1:
        state = IMMState(*(np.repeat(a, N, axis=0) for a in (state.x, state.P, state.mu)))
    if K == 0:
        raise ConfigError("z must hold at least one step")
    steps = []
    for k in range(K):
        det = None if detected is None else np.asarray(detected[:, k], dtype=bool)
        state, out = tracker.step(
            state, tpm, z[:, k], det, check=k == 0, allow_failure=allow_failure, **step_options
        )
        steps.append(out)

    def stack(name: str) -> Array:
        return np.stack([getattr(o, name) for o in steps], axis=1)

    result = IMMResult(
        stack("x"), stack("P"), stack("mode_probs"), stack("loglik"), stack("model_nis"),
        stack("nis"), np.logical_or.reduce([o.failed for o in steps]),
        None if steps[0].z_pred is None else stack("z_pred"),
    )
    if single:
        parts = (getattr(result, f.name) for f in fields(result))
        return IMMResult(*(None if a is None else a[0] for a in parts))
    return result
