r"""State spaces of the heterogeneous bank (seed 002) and the conversions between them.

Spaces (``SPACES``), all with position ``(p_x, p_y)`` first:

* ``ncv``  — ``[p_x, p_y, v_x, v_y]``, the common Cartesian state (also the output of the IMM);
* ``ct``   — ``[p_x, p_y, v, \psi, \omega]`` (speed, heading = yaw under zero sideslip, turn rate);
* ``ctra`` — ``[p_x, p_y, v, \psi, \omega, a]`` (plus tangential acceleration);
* ``cart6`` — ``[x, y, v_x, v_y, a_x, a_y]``, the state of the linear CV/CT(ω known)/CA banks
  (:mod:`imm_gym.tracking.models`), so that those banks run through the same engine.

Conversions go through CTRA, as seed 002 writes them:

.. math::
    \text{NCV}\to\text{CTRA (8, 9)}:\ [p_x, p_y, \sqrt{v_x^2+v_y^2}, \operatorname{atan2}(v_y, v_x),
    0, 0],\quad
    J = \begin{bmatrix}I_2 & 0\\ 0 & \begin{smallmatrix} v_x/v & v_y/v\\ -v_y/v^2 & v_x/v^2
    \end{smallmatrix}\\ 0 & 0\end{bmatrix}

    \text{CT}\to\text{CTRA (10, 11)}:\ [x_{CT}; 0],\ J = [I_5; 0_{1\times5}] \qquad
    \text{CTRA}\to\text{CT (14, 15)}:\ x_{1:5},\ J = [I_5\ 0_{5\times1}]

    \text{CTRA}\to\text{NCV (12, 13)}:\ [p_x, p_y, v\cos\psi, v\sin\psi],\
    J = \begin{bmatrix} I_2 & 0 & 0\\ 0 & \begin{smallmatrix}\cos\psi & -v\sin\psi\\
    \sin\psi & v\cos\psi\end{smallmatrix} & 0_{2\times2}\end{bmatrix}

and ``cart6`` through NCV (``[x_{NCV}; 0, 0]`` and its first four components). A composite
conversion's Jacobian is the product of the steps' Jacobians, and covariances map as
``P' = J P J^T`` (first order, seed 002). At zero speed the heading is undefined: the conversion
gives heading 0 and uses ``max(v, V_MIN)`` in the heading row of the Jacobian; the speed row stays
the unit velocity direction. Where the speed is within 3 standard deviations of 0 the converted
heading variance is capped at a uniform heading's, ``\pi^2/3``, and its cross-covariances set to 0
(:func:`cap_heading`).

The CT and CTRA transitions (seed 002 eqs. 5-6 and the CTRA update) are written in one closed form
valid at ``\omega = 0``: with ``\theta = \omega T`` and
``G_n(\theta) = \int_0^1 \tau^n e^{i\theta\tau} d\tau``,

.. math::
    (p_x + i p_y)_k = (p_x + i p_y)_{k-1} + e^{i\psi}\,(v T\, G_0(\theta) + a T^2 G_1(\theta)),
    \quad v_k = v + aT,\ \psi_k = \psi + \omega T,

which is the exact integral of ``\dot p = (v + a t) e^{i(\psi + \omega t)}`` (``G_0 = (e^{i\theta}
- 1) / (i\theta)`` gives eqs. 5-6 for CT, ``a = 0``). ``G_n`` is evaluated by its power series
``\sum_k (i\theta)^k / (k! (n + k + 1))`` for ``|\theta| < 0.5`` — no division by ``\omega``
— and by the recursion ``G_n = (e^{i\theta} - n G_{n-1}) / (i\theta)`` otherwise; the Jacobian uses
``dG_n/d\theta = i G_{n+1}``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from imm_gym.validation import ConfigError

Array = NDArray[np.float64]

#: State dimension of each space.
SPACES: dict[str, int] = {"ncv": 4, "ct": 5, "ctra": 6, "cart6": 6}

#: Index of the heading ``psi`` in each space (``None``: no angle component).
HEADING: dict[str, int | None] = {"ncv": None, "ct": 3, "ctra": 3, "cart6": None}

#: Speed floor of the Jacobian of NCV -> CT/CTRA (m/s).
V_MIN = 1e-6

_SERIES_TERMS = 14
_SERIES_RADIUS = 0.5


def check_space(name: str, x: Array, space: str) -> None:
    """Raise :class:`ConfigError` unless ``space`` is known and ``x`` has its dimension."""
    if space not in SPACES:
        raise ConfigError(f"{name}: unknown state space {space!r}; known: {sorted(SPACES)}")
    if x.shape[-1] != SPACES[space]:
        raise ConfigError(
            f"{name}: a {space!r} state has {SPACES[space]} components, got an array of shape "
            f"{x.shape} (incompatible state space)"
        )


def _ncv_to_ctra(x: Array) -> tuple[Array, Array]:
    """Eqs. (8), (9). With ``u = (v_x, v_y) / v`` (``(1, 0)`` at ``v = 0``, heading 0) the
    Jacobian's speed row is ``u`` and its heading row ``(-u_y, u_x) / max(v, V_MIN)``."""
    vx, vy = x[..., 2], x[..., 3]
    v = np.hypot(vx, vy)
    moving = v > 0
    safe = np.where(moving, v, 1.0)
    ux, uy = np.where(moving, vx / safe, 1.0), np.where(moving, vy / safe, 0.0)
    vs = np.maximum(v, V_MIN)
    out = np.zeros((*x.shape[:-1], 6))
    out[..., :2] = x[..., :2]
    out[..., 2] = v
    out[..., 3] = np.where(moving, np.arctan2(vy, vx), 0.0)  # a -0 vx would read heading pi
    J = np.zeros((*x.shape[:-1], 6, 4))
    J[..., 0, 0] = J[..., 1, 1] = 1.0
    J[..., 2, 2], J[..., 2, 3] = ux, uy
    J[..., 3, 2], J[..., 3, 3] = -uy / vs, ux / vs
    return out, J


def _ctra_to_ncv(x: Array) -> tuple[Array, Array]:
    v, psi = x[..., 2], x[..., 3]
    c, s = np.cos(psi), np.sin(psi)
    out = np.empty((*x.shape[:-1], 4))
    out[..., :2] = x[..., :2]
    out[..., 2] = v * c
    out[..., 3] = v * s
    J = np.zeros((*x.shape[:-1], 4, 6))
    J[..., 0, 0] = J[..., 1, 1] = 1.0
    J[..., 2, 2], J[..., 2, 3] = c, -v * s
    J[..., 3, 2], J[..., 3, 3] = s, v * c
    return out, J


def _selection(rows: int, cols: int, batch: tuple[int, ...]) -> Array:
    return np.broadcast_to(np.eye(rows, cols), (*batch, rows, cols))


def _to_hub(x: Array, space: str) -> tuple[Array, Array]:
    """To the hub space (CTRA for ncv/ct/ctra; NCV for cart6) with the Jacobian."""
    batch = x.shape[:-1]
    if space == "ctra":
        return x.copy(), _selection(6, 6, batch)
    if space == "ct":  # eq. (10), (11)
        out = np.zeros((*batch, 6))
        out[..., :5] = x
        return out, _selection(6, 5, batch)
    if space == "ncv":  # eq. (8), (9)
        return _ncv_to_ctra(x)
    raise AssertionError(space)  # pragma: no cover


def _from_ctra(x: Array, space: str) -> tuple[Array, Array]:
    batch = x.shape[:-1]
    if space == "ctra":
        return x.copy(), _selection(6, 6, batch)
    if space == "ct":  # eq. (14), (15)
        return x[..., :5].copy(), _selection(5, 6, batch)
    if space == "ncv":  # eq. (12), (13)
        return _ctra_to_ncv(x)
    raise AssertionError(space)  # pragma: no cover


def conversion(x: Array, src: str, dst: str) -> tuple[Array, Array]:
    """The state ``x`` of space ``src`` in space ``dst`` and the Jacobian ``d x' / d x``.

    Args:
        x: ``(..., n_src)`` states.
        src, dst: names in :data:`SPACES`.

    Returns:
        ``x' (..., n_dst)`` and ``J (..., n_dst, n_src)``.

    Raises:
        ConfigError: unknown space, or ``x`` not of ``src``'s dimension.
    """
    x = np.asarray(x, dtype=np.float64)
    check_space("conversion source", x, src)
    if dst not in SPACES:
        raise ConfigError(
            f"conversion target: unknown state space {dst!r}; known: {sorted(SPACES)}"
        )
    batch = x.shape[:-1]
    if src == dst:
        return x.copy(), _selection(SPACES[src], SPACES[src], batch)
    if src == "cart6":
        x4 = x[..., :4]
        J = _selection(4, 6, batch)
        if dst == "ncv":
            return x4.copy(), J
        out, J2 = conversion(x4, "ncv", dst)
        return out, J2 @ J
    if dst == "cart6":
        x4, J = conversion(x, src, "ncv")
        out = np.zeros((*batch, 6))
        out[..., :4] = x4
        return out, _selection(6, 4, batch) @ J
    hub, J1 = _to_hub(x, src)
    out, J2 = _from_ctra(hub, dst)
    return out, J2 @ J1


def convert(x: Array, P: Array, src: str, dst: str) -> tuple[Array, Array]:
    """``(x, P)`` of space ``src`` in space ``dst``: ``x' = g(x)``, ``P' = J P J^T``.

    Args:
        x: ``(..., n_src)``; P: ``(..., n_src, n_src)``.

    Raises:
        ConfigError: unknown space, or ``x`` / ``P`` not of ``src``'s dimension.
    """
    out, J = conversion(x, src, dst)
    P = np.asarray(P, dtype=np.float64)
    n = SPACES[src]
    if P.shape[-2:] != (n, n):
        raise ConfigError(
            f"conversion source: a {src!r} covariance is {n} x {n}, got an array of shape "
            f"{P.shape} (incompatible state space)"
        )
    P_out = J @ P @ np.swapaxes(J, -1, -2)
    if src in ("ncv", "cart6") and HEADING[dst] is not None:
        P_out = cap_heading(out, P_out, P[..., 2:4, 2:4])
    return out, P_out


#: Variance of a heading uniform on ``(-pi, pi]``: ``pi^2 / 3`` (rad²).
UNIFORM_HEADING_VAR = math.pi**2 / 3.0


def cap_heading(x: Array, P: Array, P_v: Array, k: float = 3.0) -> Array:
    r"""A CT/CTRA covariance converted from a Cartesian velocity, its heading capped where the
    speed says nothing about the heading.

    The first-order conversion gives ``P_{\psi\psi} = u_\perp^T P_v u_\perp / \max(v,
    V_{MIN})^2``, unbounded as ``v \to 0`` (``2 \cdot 10^{11}`` m²/s² of velocity variance one
    step after a start at rest). Where ``v < k \sqrt{\lambda_{max}(P_v)}`` (the speed within
    ``k`` standard deviations of 0), ``P_{\psi\psi} \leftarrow \min(P_{\psi\psi}, \pi^2/3)``
    (the variance of a heading uniform on the circle) and the heading's cross-covariances are set
    to 0; elsewhere ``P`` is unchanged.

    Args:
        x: ``(..., n)`` converted states (speed at index 2, heading at 3); P: ``(..., n, n)``;
        P_v: ``(..., 2, 2)`` the source's Cartesian velocity covariance; k: the threshold in
            standard deviations.
    """
    lam = np.linalg.eigvalsh(P_v)[..., -1]
    slow = x[..., 2] < k * np.sqrt(np.maximum(lam, 0.0))
    if not np.any(slow):
        return P
    var = np.minimum(P[..., 3, 3], UNIFORM_HEADING_VAR)
    capped = P.copy()
    capped[..., 3, :] = 0.0
    capped[..., :, 3] = 0.0
    capped[..., 3, 3] = var
    return np.where(slow[..., None, None], capped, P)


def _g_series(theta: Array, n: int) -> Array:
    it = 1j * theta
    total = np.zeros(theta.shape, dtype=np.complex128)
    term = np.ones(theta.shape, dtype=np.complex128)  # (i theta)^k / k!
    for k in range(_SERIES_TERMS):
        total += term / (n + k + 1)
        term = term * it / (k + 1)
    return total


def g_integrals(theta: Array) -> tuple[Array, Array, Array]:
    r"""``G_0, G_1, G_2`` with ``G_n(\theta) = \int_0^1 \tau^n e^{i\theta\tau} d\tau`` (complex)."""
    theta = np.asarray(theta, dtype=np.float64)
    small = np.abs(theta) < _SERIES_RADIUS
    th = np.where(small, 1.0, theta)
    e = np.exp(1j * th)
    g0 = (e - 1.0) / (1j * th)
    g1 = (e - g0) / (1j * th)
    g2 = (e - 2.0 * g1) / (1j * th)
    return tuple(  # type: ignore[return-value]
        np.where(small, _g_series(theta, n), g) for n, g in enumerate((g0, g1, g2))
    )


def ctra_transition(x: Array, T: float) -> tuple[Array, Array]:
    r"""CTRA prediction ``f(x)`` on ``[p_x, p_y, v, \psi, \omega, a]`` and its Jacobian ``F``.

    See the module docstring for the closed form. ``F`` has
    ``\partial p/\partial v = T e^{i\psi} G_0``, ``\partial p/\partial a = T^2 e^{i\psi} G_1``,
    ``\partial p/\partial\psi = i\,\Delta p``,
    ``\partial p/\partial\omega = i T^2 e^{i\psi}(v G_1 + a T G_2)`` (real part: x row, imaginary
    part: y row), ``\partial v_k/\partial a = T``, ``\partial\psi_k/\partial\omega = T``.

    Args:
        x: ``(..., 6)`` states; T: sampling period (s).

    Returns:
        ``x_k (..., 6)`` and ``F (..., 6, 6)``.
    """
    v, psi, w, a = x[..., 2], x[..., 3], x[..., 4], x[..., 5]
    g0, g1, g2 = g_integrals(w * T)
    rot = np.exp(1j * psi)
    dp_dv = T * rot * g0
    dp_da = T * T * rot * g1
    dp = v * dp_dv + a * dp_da
    dp_dw = 1j * T * T * rot * (v * g1 + a * T * g2)
    out = x.copy()
    out[..., 0] += dp.real
    out[..., 1] += dp.imag
    out[..., 2] = v + a * T
    out[..., 3] = psi + w * T
    F = np.zeros((*x.shape, 6))
    for r, part in ((0, np.real), (1, np.imag)):
        F[..., r, r] = 1.0
        F[..., r, 2] = part(dp_dv)
        F[..., r, 3] = part(1j * dp)
        F[..., r, 4] = part(dp_dw)
        F[..., r, 5] = part(dp_da)
    F[..., 2, 2] = F[..., 3, 3] = F[..., 4, 4] = F[..., 5, 5] = 1.0
    F[..., 2, 5] = F[..., 3, 4] = T
    return out, F


def ct_transition_nl(x: Array, T: float) -> tuple[Array, Array]:
    r"""CT prediction on ``[p_x, p_y, v, \psi, \omega]`` (seed 002 eqs. 5-6): CTRA with ``a = 0``.

    Returns:
        ``x_k (..., 5)`` and ``F (..., 5, 5)``.
    """
    full = np.concatenate([x, np.zeros((*x.shape[:-1], 1))], axis=-1)
    out, F = ctra_transition(full, T)
    return out[..., :5], F[..., :5, :5]


def wrap_heading(x: Array, space: str, ref: Array | None = None) -> Array:
    """``x`` with its heading wrapped to [-pi, pi), or to within pi of ``ref``'s heading."""
    i = HEADING[space]
    if i is None:
        return x
    out = x.copy()
    base = 0.0 if ref is None else ref[..., i]
    out[..., i] = base + (np.mod(x[..., i] - base + math.pi, 2 * math.pi) - math.pi)
    return out
