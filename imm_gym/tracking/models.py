r"""Motion models of the filter bank: constant velocity (CV), coordinated turn with a known rate
(CT) and constant acceleration (CA).

The state is Cartesian, ``[x, y, vx, vy]`` (m, m/s), extended by ``[ax, ay]`` (m/s²) when a bank
contains a CA model. All three models are linear in that state, so the model-matched prediction is
the Kalman prediction ``x = F x``, ``P = F P F^T + Q`` (for a linear map the unscented transform is
exact, so the SVD-UKF's prediction is this same formula).

In a 6-dimensional bank, CV and CT carry the acceleration components as white noise: their ``F``
zeroes them and their ``Q`` gives them the variance ``q_acc`` (the usual way to mix CV/CT with CA in
one state space, seed 003).

The process noise ``Q`` is given one of two ways (:attr:`MotionModel.noise`):

* ``"discrete"`` (the default, the TIP-IMM paper's): a per-step covariance ``Q = diag(q)``, the
  same whatever the sampling period, so it is right only at the ``T`` it was tuned for;
* ``"continuous"``: a continuous-time white noise of power spectral density ``q``
  (:attr:`MotionModel.intensity`) per axis — on the acceleration for CV and CT (m²/s³), on the
  jerk for CA (m²/s⁵) — discretized exactly for the sampling period,
  :math:`Q = \int_0^T F(\tau) G\, q I_2\, G^T F(\tau)^T d\tau` (Bar-Shalom, Li and Kirubarajan
  2001, §6.2.2 and §6.2.3; :func:`white_acceleration_noise`, :func:`white_jerk_noise`), so one
  bank definition is right at any ``T``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from imm_gym.validation import (
    ConfigError,
    check_choice,
    check_finite,
    check_range,
    check_sequence,
    store,
)

Array = NDArray[np.float64]

#: Process noise printed in the TIP-IMM paper, a discrete-time covariance on ``[x, y, vx, vy]``.
PAPER_Q = (0.1, 0.1, 0.12, 0.12)

MODEL_KINDS = ("cv", "ct", "ca")
#: How a model's process noise is given (:attr:`MotionModel.noise`).
NOISE_KINDS = ("discrete", "continuous")

#: Below this ``|omega T|`` the turn-noise ratios use their Taylor series (see
#: :func:`turn_noise_ratios`).
TURN_NOISE_SERIES_BELOW = 0.1


def ct_ratios(omega: Array, T: float) -> tuple[Array, Array]:
    r"""The position-increment entries of :func:`ct_transition`: :math:`\sin(\omega T)/\omega`
    and :math:`(1 - \cos\omega T)/\omega`, by their Taylor series for ``|omega T| < 1e-6``
    (``T`` and ``0`` in the limit).

    Args:
        omega: float turn rates (rad/s), any shape; T: sampling period (s).
    """
    wt = omega * T
    small = np.abs(wt) < 1e-6
    safe_w = np.where(small, 1.0, omega)
    sin_ratio = np.where(small, T * (1.0 - wt * wt / 6.0), np.sin(wt) / safe_w)
    cos_ratio = np.where(small, T * wt / 2.0, (1.0 - np.cos(wt)) / safe_w)
    return sin_ratio, cos_ratio


def ct_transition(omega: Array | float, T: float) -> Array:
    r"""Coordinated-turn transition matrices on ``[x, y, vx, vy]`` for turn rates ``omega``.

    .. math::
        F = \begin{bmatrix} 1 & 0 & \frac{\sin\omega T}{\omega} & -\frac{1-\cos\omega T}{\omega}\\
        0 & 1 & \frac{1-\cos\omega T}{\omega} & \frac{\sin\omega T}{\omega}\\
        0 & 0 & \cos\omega T & -\sin\omega T\\ 0 & 0 & \sin\omega T & \cos\omega T\end{bmatrix}

    ``omega > 0`` turns counter-clockwise. As ``omega -> 0`` the matrix tends to the CV matrix; the
    ratios use their Taylor series for ``|omega T| < 1e-6`` so the limit is exact and finite.

    Args:
        omega: turn rates (rad/s), any shape ``(...)``.
        T: sampling period (s).

    Returns:
        ``(..., 4, 4)`` transition matrices.
    """
    w = np.asarray(omega, dtype=np.float64)
    wt = w * T
    sin_ratio, cos_ratio = ct_ratios(w, T)
    c, s = np.cos(wt), np.sin(wt)
    F = np.zeros((*w.shape, 4, 4))
    F[..., 0, 0] = F[..., 1, 1] = 1.0
    F[..., 0, 2] = sin_ratio
    F[..., 0, 3] = -cos_ratio
    F[..., 1, 2] = cos_ratio
    F[..., 1, 3] = sin_ratio
    F[..., 2, 2] = c
    F[..., 2, 3] = -s
    F[..., 3, 2] = s
    F[..., 3, 3] = c
    return F


def turn_noise_ratios(u: Array | float) -> tuple[Array, Array]:
    r"""The ratios of the coordinated turn's noise integral, for ``u = omega T``:

    .. math::
        S_1(u) = \frac{1 - \cos u}{u^2} = \frac{2\sin^2(u/2)}{u^2}, \qquad
        S_2(u) = \frac{u - \sin u}{u^3},

    ``1/2`` and ``1/6`` at ``u = 0``. ``u - \sin u`` loses about ``-2\log_{10}|u|`` digits to
    cancellation, so below ``|u| <`` :data:`TURN_NOISE_SERIES_BELOW` both use their Taylor series
    to the ``u^8`` term (truncation below ``1e-18`` relative there; the closed form beyond it loses
    at most ``6\varepsilon/u^2 \approx 1.3e-13``).

    Args:
        u: ``omega T`` (rad), any shape.

    Returns:
        ``(S_1, S_2)`` of the shape of ``u``.
    """
    u = np.asarray(u, dtype=np.float64)
    small = np.abs(u) < TURN_NOISE_SERIES_BELOW
    safe = np.where(small, 1.0, u)
    v = u * u
    s1_series = 1 / 2 - v * (1 / 24 - v * (1 / 720 - v * (1 / 40320 - v / 3628800)))
    s2_series = 1 / 6 - v * (1 / 120 - v * (1 / 5040 - v * (1 / 362880 - v / 39916800)))
    s1 = np.where(small, s1_series, 2.0 * np.sin(0.5 * safe) ** 2 / (safe * safe))
    s2 = np.where(small, s2_series, (safe - np.sin(safe)) / safe**3)
    return s1, s2


def white_acceleration_noise(omega: Array | float, T: float, intensity: float) -> Array:
    r"""Exact discretization of continuous white-noise acceleration (power spectral density
    ``q = intensity``, m²/s³, per axis) for the CV (``omega = 0``) and CT models on
    ``[x, y, vx, vy]``:
    :math:`Q = \int_0^T F(\tau) G\, q I_2\, G^T F(\tau)^T d\tau`, ``G = [0; I_2]``,
    ``F(τ)`` of :func:`ct_transition`. With ``u = \omega T`` and ``S_1``, ``S_2`` of
    :func:`turn_noise_ratios`,

    .. math::
        Q = q \begin{bmatrix}
        \frac{2(\omega T - \sin\omega T)}{\omega^3} & 0 &
            \frac{1 - \cos\omega T}{\omega^2} & \frac{\omega T - \sin\omega T}{\omega^2}\\
        0 & \frac{2(\omega T - \sin\omega T)}{\omega^3} &
            -\frac{\omega T - \sin\omega T}{\omega^2} & \frac{1 - \cos\omega T}{\omega^2}\\
        \frac{1 - \cos\omega T}{\omega^2} & -\frac{\omega T - \sin\omega T}{\omega^2} & T & 0\\
        \frac{\omega T - \sin\omega T}{\omega^2} & \frac{1 - \cos\omega T}{\omega^2} & 0 & T
        \end{bmatrix}
        = q \begin{bmatrix}
        2T^3 S_2 & 0 & T^2 S_1 & T^2 u S_2\\ 0 & 2T^3 S_2 & -T^2 u S_2 & T^2 S_1\\
        T^2 S_1 & -T^2 u S_2 & T & 0\\ T^2 u S_2 & T^2 S_1 & 0 & T\end{bmatrix},

    which at ``omega = 0`` is the CV model's (Bar-Shalom et al. 2001, §6.2.2)
    :math:`Q = q \begin{bmatrix} T^3/3 & T^2/2\\ T^2/2 & T\end{bmatrix} \otimes I_2` on
    ``(position, velocity)``, and tends to it as ``omega -> 0``.

    Args:
        omega: turn rates (rad/s), any shape ``(...)``; ``> 0`` counter-clockwise.
        T: sampling period (s).
        intensity: ``q`` (m²/s³).

    Returns:
        ``(..., 4, 4)`` covariances.
    """
    w = np.asarray(omega, dtype=np.float64)
    u = w * T
    s1, s2 = turn_noise_ratios(u)
    pos = 2.0 * T**3 * s2
    same = T * T * s1  # x with vx, y with vy
    cross = T * T * u * s2  # x with vy; y with vx is its negative
    Q = np.zeros((*w.shape, 4, 4))
    Q[..., 0, 0] = Q[..., 1, 1] = pos
    Q[..., 0, 2] = Q[..., 2, 0] = Q[..., 1, 3] = Q[..., 3, 1] = same
    Q[..., 0, 3] = Q[..., 3, 0] = cross
    Q[..., 1, 2] = Q[..., 2, 1] = -cross
    Q[..., 2, 2] = Q[..., 3, 3] = T
    return intensity * Q


def white_jerk_noise(T: float, intensity: float) -> Array:
    r"""Exact discretization of continuous white-noise jerk (the Wiener-process acceleration
    model, power spectral density ``q = intensity``, m²/s⁵, per axis) for the CA model on
    ``[x, y, vx, vy, ax, ay]`` (Bar-Shalom et al. 2001, §6.2.3):

    .. math::
        Q = q \begin{bmatrix} T^5/20 & T^4/8 & T^3/6\\ T^4/8 & T^3/3 & T^2/2\\
        T^3/6 & T^2/2 & T\end{bmatrix} \otimes I_2
        \quad\text{on (position, velocity, acceleration)}.

    Args:
        T: sampling period (s).
        intensity: ``q`` (m²/s⁵).

    Returns:
        ``(6, 6)`` covariance.
    """
    axis = np.array(
        [
            [T**5 / 20, T**4 / 8, T**3 / 6],
            [T**4 / 8, T**3 / 3, T**2 / 2],
            [T**3 / 6, T**2 / 2, T],
        ]
    )
    return intensity * np.kron(axis, np.eye(2))


@dataclass(frozen=True)
class MotionModel:
    """One model of the bank.

    Attributes:
        kind: ``"cv"``, ``"ct"`` or ``"ca"``.
        turn_rate_deg: turn rate of a CT model in °/s (> 0 counter-clockwise); 0 for CV/CA.
        q: with ``noise="discrete"``, the diagonal of the per-step process noise on
            ``[x, y, vx, vy]`` (CV/CT; ``None``: the paper's :data:`PAPER_Q`) or
            ``[x, y, vx, vy, ax, ay]`` (CA, 6 entries required); ``None`` (unused) with
            ``noise="continuous"``.
        q_acc: variance of the acceleration components when a CV/CT model sits in a 6-dimensional
            (CA) bank (per step, either noise kind).
        noise: ``"discrete"`` (``Q = diag(q)`` per step, the default: the paper bank) or
            ``"continuous"`` (white noise of power spectral density ``intensity`` discretized for
            the sampling period: :func:`white_acceleration_noise`, :func:`white_jerk_noise`).
        intensity: with ``noise="continuous"``, the power spectral density ``q`` per axis
            (> 0): of the acceleration for CV/CT (m²/s³), of the jerk for CA (m²/s⁵).
    """

    kind: str = "cv"
    turn_rate_deg: float = 0.0
    q: tuple[float, ...] | None = None
    q_acc: float = 1e-2
    noise: str = "discrete"
    intensity: float | None = None

    def __post_init__(self) -> None:
        check_choice("model.kind", self.kind, MODEL_KINDS)
        turn = store(self, "turn_rate_deg", check_finite("model.turn_rate_deg", self.turn_rate_deg))
        if self.kind == "ct" and turn == 0.0:
            raise ConfigError("model.turn_rate_deg must be non-zero for a 'ct' model (use 'cv')")
        if self.kind != "ct" and turn != 0.0:
            raise ConfigError(f"model.turn_rate_deg must be 0 for a {self.kind!r} model")
        check_choice("model.noise", self.noise, NOISE_KINDS)
        if self.noise == "discrete":
            if self.intensity is not None:
                raise ConfigError(
                    "model.intensity is the continuous-time noise density: it needs "
                    "model.noise 'continuous' (the per-step noise of 'discrete' is model.q)"
                )
            q = check_sequence(
                f"model.q (a {self.kind!r} model)",
                PAPER_Q if self.q is None else self.q,
                6 if self.kind == "ca" else 4,
            )
            store(self, "q", tuple(check_range("model.q", v, 0.0) for v in q))
        else:
            if self.q is not None:
                raise ConfigError(
                    "model.q is the per-step noise of model.noise 'discrete'; a 'continuous' "
                    "model takes model.intensity instead"
                )
            if self.intensity is None:
                raise ConfigError(
                    "model.intensity (the noise's power spectral density, "
                    f"{'m²/s⁵' if self.kind == 'ca' else 'm²/s³'}) is required with "
                    "model.noise 'continuous'"
                )
            store(
                self,
                "intensity",
                check_range("model.intensity", self.intensity, 0.0, lo_open=True),
            )
        store(self, "q_acc", check_range("model.q_acc", self.q_acc, 0.0, lo_open=True))

    @property
    def dim(self) -> int:
        """Native state dimension: 6 for CA, 4 otherwise."""
        return 6 if self.kind == "ca" else 4

    @property
    def omega(self) -> float:
        """Turn rate in rad/s."""
        return math.radians(self.turn_rate_deg)

    @property
    def label(self) -> str:
        """Short name, e.g. ``CV``, ``CT(+4°/s)``."""
        if self.kind == "ct":
            return f"CT({self.turn_rate_deg:+g}°/s)"
        return self.kind.upper()

    def transition_matrix(self, T: float, dim: int) -> Array:
        r"""``F`` on a state of dimension ``dim`` (4, or 6 in a bank with a CA model).

        CA (2x2 blocks):
        :math:`F = \begin{bmatrix} I & T I & \tfrac{T^2}{2} I\\ 0 & I & T I\\ 0&0&I\end{bmatrix}`
        CV is CT's limit ``omega = 0``.
        """
        F = np.zeros((dim, dim))
        if self.kind == "ca":
            if dim != 6:
                raise ConfigError("a 'ca' model needs a 6-dimensional state")
            eye = np.eye(2)
            F[:2, :2] = F[2:4, 2:4] = F[4:, 4:] = eye
            F[:2, 2:4] = F[2:4, 4:] = T * eye
            F[:2, 4:] = 0.5 * T * T * eye
            return F
        F[:4, :4] = ct_transition(self.omega, T)
        return F

    def noise_covariance(self, dim: int, T: float | None = None) -> Array:
        r"""``Q`` on a state of dimension ``dim`` (4, or 6 in a bank with a CA model).

        ``noise="discrete"``: ``Q = diag(q)`` (plus ``q_acc`` on the acceleration components of a
        6-dimensional bank), whatever ``T``. ``noise="continuous"``: CV/CT
        :func:`white_acceleration_noise` at the model's turn rate (plus ``q_acc`` on the
        acceleration components of a 6-dimensional bank), CA :func:`white_jerk_noise`.

        Args:
            dim: the bank's state dimension.
            T: sampling period (s); required with ``noise="continuous"``.
        """
        if self.q is not None:  # noise 'discrete'
            q = [*self.q]
            if dim == 6 and self.kind != "ca":
                q += [self.q_acc, self.q_acc]
            if len(q) != dim:
                raise ConfigError(f"model {self.label} does not fit a {dim}-dimensional state")
            return np.diag(q)
        assert self.intensity is not None  # a validated 'continuous' model
        if T is None:
            raise ConfigError(f"model {self.label}: noise 'continuous' needs the sampling period T")
        T = check_range("T", T, 0.0, lo_open=True)
        if dim != 6 and (self.kind == "ca" or dim != 4):
            raise ConfigError(f"model {self.label} does not fit a {dim}-dimensional state")
        if self.kind == "ca":
            return white_jerk_noise(T, self.intensity)
        Q = np.zeros((dim, dim))
        Q[:4, :4] = white_acceleration_noise(self.omega, T, self.intensity)
        Q[4:, 4:] = self.q_acc * np.eye(dim - 4)
        return Q

    def scaled(self, factor: float) -> MotionModel:
        """The same model with ``factor`` times its ``Q``: ``q`` (or ``intensity``) and
        ``q_acc`` scaled (the BBSCA tuner's knob, :mod:`imm_gym.papers.tuning`).

        Args:
            factor: > 0.
        """
        s = check_range("factor", factor, 0.0, lo_open=True)
        if self.q is not None:
            return replace(self, q=tuple(s * v for v in self.q), q_acc=s * self.q_acc)
        assert self.intensity is not None  # a validated 'continuous' model
        return replace(self, intensity=s * self.intensity, q_acc=s * self.q_acc)


def paper_bank(turn_rate_deg: float = 4.0, ct_q_scale: float = 0.5) -> tuple[MotionModel, ...]:
    """The bank of SPEC §6: CV, CT(+4°/s), CT(-4°/s), with ``Q_ct = 0.5 Q_cv``."""
    q_ct = tuple(ct_q_scale * v for v in PAPER_Q)
    return (
        MotionModel("cv"),
        MotionModel("ct", turn_rate_deg, q_ct),
        MotionModel("ct", -turn_rate_deg, q_ct),
    )


def bank_dim(models: tuple[MotionModel, ...] | list[MotionModel]) -> int:
    """State dimension of a bank: 6 if any model is CA, else 4."""
    return max(m.dim for m in models)


def velocity_noise(Q: Array) -> Array:
    r"""RMS velocity process noise per step of ``Q (..., n, n)`` (m/s):
    :math:`\sqrt{(Q_{v_x v_x} + Q_{v_y v_y}) / 2}` (``sqrt(q T)`` for white-noise acceleration
    of intensity ``q``)."""
    return np.sqrt(0.5 * (Q[..., 2, 2] + Q[..., 3, 3]))
