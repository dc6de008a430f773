r"""Model-matched filters, batched over any leading axes: Kalman, extended Kalman, UKF.

All models of the bank are linear in the state (:mod:`imm_gym.tracking.models`), so every filter
predicts with the same closed form ``x = F x``, ``P = F P F^T + Q``; they differ in the measurement
update:

* :class:`KalmanFilter` — a linear sensor ``z = H x + v``;
* :class:`ExtendedKalmanFilter` — ``h`` linearized at the predicted state (seed 002);
* :class:`UnscentedKalmanFilter` — scaled unscented transform whose sigma points are the columns of
  the symmetric square root ``U sqrt(|S|) U^T`` from the SVD ``P = U S U^T`` (SPEC §2, the
  "SVD-UKF"), defined even when ``P`` has lost definiteness. The sigma points are drawn from the
  *predicted* covariance (``Q`` included).
  ``"ukf-cholesky"`` is the same filter with the columns of the Cholesky factor ``P = L L^T``
  instead (:func:`~imm_gym.tracking.linalg.cholesky_psd`): the same sigma-point moments for a
  linear sensor, differences of a higher order for the sonar, and no eigendecomposition.

Shapes: ``x (..., n)``, ``P (..., n, n)``, ``z (..., m)``; the leading axes broadcast.
Residuals go through ``sensor.residual`` (bearing wrapped to (-pi, pi]); covariances are
symmetrized after every update (Joseph form for KF/EKF).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.linalg import LOG_2PI, cholesky_psd, inv_logdet, sym_eig, symmetrize
from imm_gym.validation import ConfigError, check_range, store

Array = NDArray[np.float64]

FILTERS = ("ukf", "ukf-cholesky", "ekf", "kf")
#: the UKF's matrix square roots for its sigma points
SQUARE_ROOTS = ("svd", "cholesky")


class MeasurementModel(Protocol):
    """What a filter needs from a sensor (see :mod:`imm_gym.tracking.sensors`)."""

    dim_z: int

    @property
    def R(self) -> Array: ...

    def h(self, x: Array) -> Array: ...

    def jacobian(self, x: Array) -> Array: ...

    def residual(self, a: Array, b: Array) -> Array: ...

    def linear_matrix(self, n: int) -> Array | None: ...

    def wrap(self, z: Array) -> Array: ...


@dataclass(frozen=True)
class Update:
    """Result of a measurement update.

    Attributes:
        x: ``(..., n)`` updated state.
        P: ``(..., n, n)`` updated covariance.
        z_pred: ``(..., m)`` predicted measurement.
        nu: ``(..., m)`` innovation ``z - z_pred`` (bearing wrapped).
        S: ``(..., m, m)`` innovation covariance.
        loglik: ``(...)`` ``log N(nu; 0, S)``.
        nis: ``(...)`` normalized innovation squared ``nu^T S^-1 nu``.
        innovation: ``(...)`` whitened innovation ``L^-1 nu`` with ``S = L L^T`` (Cholesky):
            signed, unit covariance for a consistent filter, squared norm = NIS.
    """

    x: Array
    P: Array
    z_pred: Array
    nu: Array
    S: Array
    loglik: Array
    nis: Array
    innovation: Array


def predict(x: Array, P: Array, F: Array, Q: Array) -> tuple[Array, Array]:
    """Linear prediction ``x = F x``, ``P = F P F^T + Q`` (exact for the UKF too: F is linear).

    Args:
        x: ``(..., n)``; P: ``(..., n, n)``; F, Q: ``(..., n, n)`` broadcastable against P.
    """
    x_pred = (F @ x[..., None])[..., 0]
    P_pred = F @ P @ np.swapaxes(F, -1, -2) + Q
    return x_pred, P_pred


def _finish(
    x: Array, z_pred: Array, nu: Array, S: Array, C: Array, P_minus: Callable[[Array], Array]
) -> Update:
    """Shared tail of every update, from the cross covariance ``C = P H^T`` (or its UT estimate).

    ``K = C S^-1``, ``x += K nu``, ``P = P_minus`` (the filter's updated covariance, symmetrized),
    ``NIS = nu^T S^-1 nu``, ``log N(nu; 0, S) = -(NIS + log det S + m log 2 pi) / 2``.
    """
    S_inv, logdet = inv_logdet(S)
    S_inv_nu = (S_inv @ nu[..., None])[..., 0]
    nis = np.sum(nu * S_inv_nu, axis=-1)
    L = np.linalg.cholesky(S)
    return Update(
        x=x + (C @ S_inv_nu[..., None])[..., 0],
        P=symmetrize(P_minus(C @ S_inv)),
        z_pred=z_pred,
        nu=nu,
        S=S,
        loglik=-0.5 * (nis + logdet + nu.shape[-1] * LOG_2PI),
        nis=nis,
        innovation=np.linalg.solve(L, nu[..., None])[..., 0],
    )


class KalmanFilter:
    """Kalman update for a linear sensor ``z = H x + v`` (Joseph-form covariance)."""

    name = "kf"

    def update(self, x: Array, P: Array, z: Array, sensor: MeasurementModel) -> Update:
        """``K = P H^T S^-1``, ``S = H P H^T + R``, ``P = (I-KH) P (I-KH)^T + K R K^T``."""
        H = sensor.linear_matrix(x.shape[-1])
        if H is None:
            raise ConfigError("filter 'kf' needs a linear sensor; use 'ekf' or 'ukf' for the sonar")
        return _linearized_update(x, P, z, sensor, np.broadcast_to(H, (*x.shape[:-1], *H.shape)))


class ExtendedKalmanFilter:
    """EKF update: the sensor linearized at the predicted state, ``H = dh/dx (x)``."""

    name = "ekf"

    def update(self, x: Array, P: Array, z: Array, sensor: MeasurementModel) -> Update:
        return _linearized_update(x, P, z, sensor, sensor.jacobian(x))


def _linearized_update(x: Array, P: Array, z: Array, sensor: MeasurementModel, H: Array) -> Update:
    z_pred = sensor.h(x)
    nu = sensor.residual(np.broadcast_to(z, z_pred.shape), z_pred)
    C = P @ np.swapaxes(H, -1, -2)
    S = symmetrize(H @ C + sensor.R)
    eye = np.eye(x.shape[-1])

    def joseph(K: Array) -> Array:
        IKH = eye - K @ H
        return IKH @ P @ np.swapaxes(IKH, -1, -2) + K @ sensor.R @ np.swapaxes(K, -1, -2)

    return _finish(x, z_pred, nu, S, C, joseph)


@dataclass(frozen=True)
class UnscentedKalmanFilter:
    r"""SVD-UKF update with scaled sigma points (Julier 2002; Wan & van der Merwe 2000).

    With ``lambda = alpha^2 (n + kappa) - n`` and ``P = U S U^T`` (SVD), the ``2n+1`` sigma points
    are ``x`` and ``x ± sqrt(n + lambda) (U sqrt(|S|) U^T)_i`` (:meth:`sigma_offsets`); weights
    ``W0m = lambda / (n + lambda)``, ``W0c = W0m + 1 - alpha^2 + beta``,
    ``Wi = 1 / (2 (n + lambda))``. Then
    ``z_pred = sum W_m Z_i`` (bearings averaged as residuals about the centre point),
    ``S = sum W_c (Z_i - z_pred)(Z_i - z_pred)^T + R``, ``C = sum W_c (X_i - x)(Z_i - z_pred)^T``,
    ``K = C S^-1``, ``x += K nu``, ``P -= K S K^T``.

    Attributes:
        alpha, beta, kappa: sigma-point scaling (SPEC §6 default ``(1, 2, 0)``).
        square_root: ``"svd"`` (the paper's, default) or ``"cholesky"``: the ``a_i`` are the
            columns of the Cholesky factor ``L`` of ``P = L L^T`` (filter ``"ukf-cholesky"``).
    """

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    square_root: str = "svd"

    def __post_init__(self) -> None:
        store(self, "alpha", check_range("ukf.alpha", self.alpha, 0.0, 1.0, lo_open=True))
        store(self, "beta", check_range("ukf.beta", self.beta, 0.0))
        store(self, "kappa", check_range("ukf.kappa", self.kappa, 0.0))
        if self.square_root not in SQUARE_ROOTS:
            raise ConfigError(
                f"ukf.square_root must be one of {list(SQUARE_ROOTS)}, got {self.square_root!r}"
            )

    @property
    def name(self) -> str:
        """``"ukf"`` (SVD sigma points) or ``"ukf-cholesky"``."""
        return "ukf" if self.square_root == "svd" else "ukf-cholesky"

    def weights(self, n: int) -> tuple[Array, Array, float]:
        """Mean and covariance weights ``(2n+1,)`` and ``gamma = sqrt(n + lambda)``."""
        lam = self.alpha**2 * (n + self.kappa) - n
        c = n + lam
        wm = np.full(2 * n + 1, 0.5 / c)
        wc = wm.copy()
        wm[0] = lam / c
        wc[0] = lam / c + 1.0 - self.alpha**2 + self.beta
        return wm, wc, float(np.sqrt(c))

    def sigma_offsets(self, P: Array) -> Array:
        """``(..., 2n+1, n)`` offsets ``0, +gamma a_i, -gamma a_i``; the sigma points are ``x``
        plus these. ``a_i``: the columns of the symmetric square root ``U sqrt(|S|) U^T`` from the
        SVD ``P = U S U^T`` (``"svd"``), or of ``L`` with ``(P + P^T) / 2 = L L^T``
        (``"cholesky"``).

        The symmetric root is unique and continuous in ``P``; the columns of ``U sqrt(|S|)`` are
        not where eigenvalues repeat (the start's velocity block ``25 I``): there ``U`` is any
        basis of the eigenspace, a rounding of ``P`` turned the sigma points within it, and on a
        target near the sonar one IMM step's estimate moved by metres."""
        n = P.shape[-1]
        _, _, gamma = self.weights(n)
        if self.square_root == "cholesky":
            D = np.swapaxes(cholesky_psd(symmetrize(P)) * gamma, -1, -2)  # rows = a_i
        else:
            s, U = sym_eig(P)
            D = (U * (gamma * np.sqrt(np.abs(s)))[..., None, :]) @ np.swapaxes(U, -1, -2)
        O = np.empty((*P.shape[:-2], 2 * n + 1, n))
        O[..., 0, :] = 0.0
        O[..., 1 : n + 1, :] = D
        O[..., n + 1 :, :] = -D
        return O

    def sigma_points(self, x: Array, P: Array) -> Array:
        """``(..., 2n+1, n)`` sigma points ``x, x + gamma a_i, x - gamma a_i``."""
        return x[..., None, :] + self.sigma_offsets(P)

    def update(self, x: Array, P: Array, z: Array, sensor: MeasurementModel) -> Update:
        wm, wc, _ = self.weights(x.shape[-1])
        O = self.sigma_offsets(P)
        Z = sensor.h(x[..., None, :] + O)  # (..., 2n+1, m)
        dZ = sensor.residual(Z, Z[..., :1, :])  # about the centre point: bearings stay unwrapped
        mean = wm @ dZ
        z_pred = sensor.wrap(Z[..., 0, :] + mean)
        dZ -= mean[..., None, :]
        dZw = dZ * wc[:, None]
        S = symmetrize(np.swapaxes(dZw, -1, -2) @ dZ + sensor.R)
        C = np.swapaxes(O, -1, -2) @ dZw
        nu = sensor.residual(np.broadcast_to(z, z_pred.shape), z_pred)
        return _finish(x, z_pred, nu, S, C, lambda K: P - K @ np.swapaxes(C, -1, -2))


Filter = KalmanFilter | ExtendedKalmanFilter | UnscentedKalmanFilter


def make_filter(name: str, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0) -> Filter:
    """The filter called ``name`` (:data:`FILTERS`: ``"ukf"``, ``"ukf-cholesky"``, ``"ekf"``,
    ``"kf"``)."""
    if name in ("ukf", "ukf-cholesky"):
        return UnscentedKalmanFilter(alpha, beta, kappa, "svd" if name == "ukf" else "cholesky")
    if name == "ekf":
        return ExtendedKalmanFilter()
    if name == "kf":
        return KalmanFilter()
    raise ConfigError(f"filter must be one of {list(FILTERS)}, got {name!r}")
