r"""Motion models of the filter bank: constant velocity (CV), coordinated turn with a known rate
(CT) and constant acceleration (CA).

The state is Cartesian, ``[x, y, vx, vy]`` (m, m/s), extended by ``[ax, ay]`` (m/s²) when a bank
contains a CA model. All three models are linear in that state, so the model-matched prediction is
the Kalman prediction ``x = F x``, ``P = F P F^T + Q`` (for a linear map the unscented transform is
exact, so the SVD-UKF's prediction is this same formula).

In a 6-dimensional bank, CV and CT carry the acceleration components as white noise: their ``F``
zeroes them and their ``Q`` gives them the variance ``q_acc`` (the usual way to mix CV/CT with CA in
one state space, seed 003).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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


@dataclass(frozen=True)
class MotionModel:
    """One model of the bank.

    Attributes:
        kind: ``"cv"``, ``"ct"`` or ``"ca"``.
        turn_rate_deg: turn rate of a CT model in °/s (> 0 counter-clockwise); 0 for CV/CA.
        q: diagonal of the discrete-time process noise on ``[x, y, vx, vy]`` (CV/CT) or
            ``[x, y, vx, vy, ax, ay]`` (CA).
        q_acc: variance of the acceleration components when a CV/CT model sits in a 6-dimensional
            (CA) bank.
    """

    kind: str = "cv"
    turn_rate_deg: float = 0.0
    q: tuple[float, ...] = PAPER_Q
    q_acc: float = 1e-2

    def __post_init__(self) -> None:
        check_choice("model.kind", self.kind, MODEL_KINDS)
        turn = store(self, "turn_rate_deg", check_finite("model.turn_rate_deg", self.turn_rate_deg))
        if self.kind == "ct" and turn == 0.0:
            raise ConfigError("model.turn_rate_deg must be non-zero for a 'ct' model (use 'cv')")
        if self.kind != "ct" and turn != 0.0:
            raise ConfigError(f"model.turn_rate_deg must be 0 for a {self.kind!r} model")
        q = check_sequence(
            f"model.q (a {self.kind!r} model)", self.q, 6 if self.kind == "ca" else 4
        )
        store(self, "q", tuple(check_range("model.q", v, 0.0) for v in q))
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

    def noise_covariance(self, dim: int) -> Array:
        """``Q = diag(q)`` (plus ``q_acc`` on the acceleration components of a 6-dim bank)."""
        q = list(self.q)
        if dim == 6 and self.kind != "ca":
            q += [self.q_acc, self.q_acc]
        if len(q) != dim:
            raise ConfigError(f"model {self.label} does not fit a {dim}-dimensional state")
        return np.diag(q)


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
