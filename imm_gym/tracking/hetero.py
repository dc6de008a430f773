r"""The heterogeneous IMM-EKF of seed 002: NCV, CT and CTRA models in their own state spaces.

Models (:class:`HeteroModel`; state spaces and conversions in :mod:`imm_gym.tracking.conversions`):

* NCV on ``[p_x, p_y, v_x, v_y]``: ``F`` of SPEC §2 (CV), continuous white-noise acceleration
  ``Q = \sigma_a^2 \begin{bmatrix} T^3/3 & T^2/2\\ T^2/2 & T\end{bmatrix} \otimes I_2``,
  ``\sigma_a = 0.6`` (Table I prints m/s²; here ``\sigma_a^2`` is the noise's power spectral
  density, m²/s³). Seed 002 names its ``Q_{NCV}`` "the discrete white noise acceleration model"
  but prints the terms ``Δt³/3`` and ``Δt²/2``, which are those of the continuous model (the
  discrete one has ``T⁴/4, T³/2, T²``); we follow the printed terms.
* CT on ``[p_x, p_y, v, \psi, \omega]`` (turn rate estimated, nonlinear, eqs. 5-6), driven by a
  speed noise ``\sigma_v = 2.4`` m/s² and a yaw acceleration ``\sigma_{\dot\omega} = 0.6`` rad/s²:
  ``Q = G \operatorname{diag}(\sigma_v^2, \sigma_{\dot\omega}^2) G^T``,
  ``G = \begin{bmatrix} \tfrac{T^2}{2}\cos\psi & \tfrac{T^2}{2}\sin\psi & T & 0 & 0\\
  0 & 0 & 0 & \tfrac{T^2}{2} & T\end{bmatrix}^T``.
* CTRA on ``[p_x, p_y, v, \psi, \omega, a]`` driven by a jerk ``\sigma_j = 20`` m/s³ and a yaw
  acceleration ``\sigma_{\dot\omega} = 3`` rad/s²:
  ``G = \begin{bmatrix} \tfrac{T^3}{6}\cos\psi & \tfrac{T^3}{6}\sin\psi & \tfrac{T^2}{2} & 0 & 0
  & T\\ 0 & 0 & 0 & \tfrac{T^2}{2} & T & 0\end{bmatrix}^T``.

(noise values of seed 002 Table I). Each model's ``Q`` is multiplied by its ``q_scale`` (the knob
the BBSCA tuner turns, :mod:`imm_gym.papers.tuning`).

One IMM-EKF cycle (:class:`HeteroIMM`), with ``g_{i\to j}`` the conversion of model i's space to
model j's and ``J_{i\to j}`` its Jacobian (seed 002: "before being mixed, the state vectors ... must
be transformed into the state space of the target model j"):

1. mixing in each target space: ``x_{i\to j} = g_{i\to j}(x_i)``,
   ``P_{i\to j} = J P_i J^T``, then :func:`imm_gym.tracking.imm.mix` (headings averaged as residuals
   about the heading of the model that weighs most in the mix into j, the largest
   ``\pi_{ij} \mu_i``; :meth:`HeteroIMM.mix`);
2. EKF per model: ``x^- = f_j(x_0)``, ``P^- = F_j P_0 F_j^T + Q_j`` (``F_j`` the Jacobian at
   ``x_0``), update with ``h_j = h \circ g_{j\to ncv}`` and ``H_j = H(g(x^-)) J_{j\to ncv}``;
3. :func:`imm_gym.tracking.imm.update_mode_probs`;
4. combination in the common Cartesian space NCV: every model's posterior converted by
   ``g_{j\to ncv}`` and combined by :func:`imm_gym.tracking.imm.combine` (spread term included).

For the linear banks of :mod:`imm_gym.tracking.models` (:class:`LinearModel`, space ``cart6`` or
``ncv``) the conversions are identities and the engine is the classical IMM with a Kalman filter; it
also runs a batch of trackers with *per-tracker* ``Q`` and ``R`` scales (``q_scale (N, M)``,
``r_scale (N,)``), which is how the tuner evaluates all particles at once.

States of models with different dimensions are stored zero-padded in one ``(N, M, n_max)`` array
(and ``(N, M, n_max, n_max)`` covariances): model j uses the first ``dim_j`` components.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.conversions import (
    SPACES,
    conversion,
    convert,
    ct_transition_nl,
    ctra_transition,
    wrap_heading,
)
from imm_gym.tracking.filters import ExtendedKalmanFilter, MeasurementModel, Update
from imm_gym.tracking.imm import (
    IMM,
    IMMResult,
    IMMState,
    IMMStep,
    Tracker,
    combine,
    cycles_by_tracker,
    finite_outputs,
    measurement_mixture,
    mix,
    run,
    update_mode_probs,
    used_measurements,
)
from imm_gym.tracking.linalg import inv_logdet, mahalanobis
from imm_gym.tracking.models import MotionModel, bank_dim
from imm_gym.tracking.tpm import validate_tpm
from imm_gym.validation import (
    ConfigError,
    check_choice,
    check_int,
    check_range,
    check_sequence,
    store,
)

Array = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

HETERO_KINDS = ("ncv", "ct", "ctra")
#: Seed 002's start probability of each kind (a bank of the three kinds, in any order).
SEED_PROBS = {"ncv": 0.90, "ct": 0.08, "ctra": 0.02}


@dataclass(frozen=True)
class HeteroModel:
    """One model of seed 002's bank.

    Attributes:
        kind: ``"ncv"``, ``"ct"`` or ``"ctra"``.
        sigma: the noise standard deviations: ``(sigma_a,)`` for NCV (m/s²), ``(sigma_v,
            sigma_omega_dot)`` for CT (m/s², rad/s²), ``(sigma_jerk, sigma_omega_dot)`` for CTRA
            (m/s³, rad/s²).
        q_scale: factor on ``Q`` (> 0).
    """

    kind: str
    sigma: tuple[float, ...]
    q_scale: float = 1.0

    def __post_init__(self) -> None:
        check_choice("model.kind", self.kind, HETERO_KINDS)
        want = 1 if self.kind == "ncv" else 2
        sigma = check_sequence(f"model.sigma (a {self.kind!r} model)", self.sigma, want)
        store(self, "sigma", tuple(check_range("model.sigma", s, 0.0) for s in sigma))
        store(self, "q_scale", check_range("model.q_scale", self.q_scale, 0.0, lo_open=True))

    @property
    def space(self) -> str:
        """The state space (:data:`imm_gym.tracking.conversions.SPACES`): the kind itself."""
        return self.kind

    @property
    def dim(self) -> int:
        """State dimension: 4 (NCV), 5 (CT) or 6 (CTRA)."""
        return SPACES[self.kind]

    @property
    def label(self) -> str:
        """Display name: ``NCV``, ``CT``, ``CTRA``."""
        return self.kind.upper()

    def transition(self, x: Array, T: float) -> tuple[Array, Array]:
        """``f(x)`` and its Jacobian ``F`` (``(..., n)``, ``(..., n, n)``)."""
        if self.kind == "ct":
            return ct_transition_nl(x, T)
        if self.kind == "ctra":
            return ctra_transition(x, T)
        F = np.eye(4)
        F[0, 2] = F[1, 3] = T
        return x @ F.T, np.broadcast_to(F, (*x.shape, 4))

    def noise(self, x: Array, T: float) -> Array:
        """``Q`` at ``x`` (before ``q_scale``), ``(..., n, n)``; see the module docstring."""
        if self.kind == "ncv":
            s2 = self.sigma[0] ** 2
            Q = np.zeros((4, 4))
            for i in range(2):
                Q[i, i] = s2 * T**3 / 3
                Q[i, i + 2] = Q[i + 2, i] = s2 * T**2 / 2
                Q[i + 2, i + 2] = s2 * T
            return np.broadcast_to(Q, (*x.shape[:-1], 4, 4))
        psi = x[..., 3]
        n = self.dim
        G = np.zeros((*x.shape[:-1], n, 2))
        lin = T**2 / 2 if self.kind == "ct" else T**3 / 6
        G[..., 0, 0] = lin * np.cos(psi)
        G[..., 1, 0] = lin * np.sin(psi)
        G[..., 2, 0] = T if self.kind == "ct" else T**2 / 2
        G[..., 3, 1] = T**2 / 2
        G[..., 4, 1] = T
        if self.kind == "ctra":
            G[..., 5, 0] = T
        s = np.array(self.sigma)
        Gs = G * s
        return Gs @ np.swapaxes(Gs, -1, -2)


@dataclass(frozen=True)
class LinearModel:
    """A linear model of :mod:`imm_gym.tracking.models` (CV, CT(ω known), CA) in the engine's
    interface.

    Attributes:
        model: the motion model; dim: the bank's state dimension (4 or 6).
        q_scale: factor on ``Q`` (> 0).
    """

    model: MotionModel
    dim: int = 4
    q_scale: float = 1.0

    def __post_init__(self) -> None:
        dim = check_int("model.dim (the bank's state: 4 or 6)", self.dim, 4, 6)
        if dim == 5:
            raise ConfigError(f"model.dim must be 4 or 6 (the bank's state), got {self.dim!r}")
        store(self, "dim", dim)
        store(self, "q_scale", check_range("model.q_scale", self.q_scale, 0.0, lo_open=True))

    @property
    def space(self) -> str:
        """``ncv`` for a 4-dimensional bank, ``cart6`` for a 6-dimensional one."""
        return "ncv" if self.dim == 4 else "cart6"

    @property
    def label(self) -> str:
        """The motion model's label."""
        return self.model.label

    def transition(self, x: Array, T: float) -> tuple[Array, Array]:
        """``F x`` and ``F`` (``(..., n)``, ``(..., n, n)``)."""
        F = self.model.transition_matrix(T, self.dim)
        return x @ F.T, np.broadcast_to(F, (*x.shape, self.dim))

    def noise(self, x: Array, T: float) -> Array:
        """The model's ``Q`` (before ``q_scale``), ``(..., n, n)``."""
        return np.broadcast_to(self.model.noise_covariance(self.dim, T), (*x.shape, self.dim))


AnyModel = HeteroModel | LinearModel


def linear_models(models: Sequence[MotionModel]) -> tuple[LinearModel, ...]:
    """Wrap a linear bank of :mod:`imm_gym.tracking.models` for :class:`HeteroIMM`."""
    n = bank_dim(models)
    return tuple(LinearModel(m, n) for m in models)


@dataclass(frozen=True)
class HeteroBank:
    """Configuration of seed 002's NCV/CT/CTRA bank (defaults: seed 002 Table I).

    Attributes:
        models: kinds in bank order, from ``ncv``, ``ct``, ``ctra``.
        sigma_ncv: NCV acceleration noise (m/s²).
        sigma_ct: CT speed noise (m/s²) and yaw-acceleration noise (rad/s²).
        sigma_ctra: CTRA jerk noise (m/s³) and yaw-acceleration noise (rad/s²).
        q_scale: one ``Q`` factor per model (> 0; the BBSCA tuner's output).
        initial_probs: model probabilities at the start; ``None``: seed 002's (0.90, 0.08, 0.02)
            for the bank ``ncv, ct, ctra`` (by kind, :data:`SEED_PROBS`, in any order), uniform
            for any other.
        turn_rate_var, accel_var: variances given to ``omega`` (rad²/s²) and ``a`` (m²/s⁴) when a
            track is initiated from a Cartesian estimate (seed 002's ``P_0``: 0.2 and 1.0).
    """

    models: tuple[str, ...] = ("ncv", "ct", "ctra")
    sigma_ncv: float = 0.6
    sigma_ct: tuple[float, float] = (2.4, 0.6)
    sigma_ctra: tuple[float, float] = (20.0, 3.0)
    q_scale: tuple[float, ...] | None = None
    initial_probs: tuple[float, ...] | None = None
    turn_rate_var: float = 0.2
    accel_var: float = 1.0

    def __post_init__(self) -> None:
        models = check_sequence("bank.models", self.models)
        if len(models) < 2:
            raise ConfigError(f"bank.models must hold at least 2 models, got {models!r}")
        for i, k in enumerate(models):
            check_choice(f"bank.models[{i}]", k, HETERO_KINDS)
        store(self, "models", models)
        M = len(models)
        if self.q_scale is None:
            scale = (1.0,) * M
        else:
            scale = check_sequence("bank.q_scale (one entry per model)", self.q_scale, M)
        store(
            self,
            "q_scale",
            tuple(
                check_range(f"bank.q_scale[{i}]", s, 0.0, lo_open=True) for i, s in enumerate(scale)
            ),
        )
        store(self, "sigma_ncv", check_range("bank.sigma_ncv", self.sigma_ncv, 0.0))
        for name in ("sigma_ct", "sigma_ctra"):
            value = check_sequence(f"bank.{name}", getattr(self, name), 2)
            store(
                self,
                name,
                tuple(check_range(f"bank.{name}[{i}]", s, 0.0) for i, s in enumerate(value)),
            )
        if self.initial_probs is not None:
            p = tuple(
                check_range(f"bank.initial_probs[{i}]", v, 0.0, 1.0)
                for i, v in enumerate(check_sequence("bank.initial_probs", self.initial_probs, M))
            )
            if abs(sum(p) - 1.0) > 1e-9:
                raise ConfigError(
                    f"bank.initial_probs must have {M} non-negative entries summing to 1, got {p!r}"
                )
            store(self, "initial_probs", p)
        for name in ("turn_rate_var", "accel_var"):
            store(self, name, check_range(f"bank.{name}", getattr(self, name), 0.0, lo_open=True))

    def __len__(self) -> int:
        return len(self.models)

    @property
    def probs(self) -> tuple[float, ...]:
        """The initial model probabilities (see ``initial_probs``)."""
        if self.initial_probs is not None:
            return self.initial_probs
        if sorted(self.models) == sorted(HETERO_KINDS):
            return tuple(SEED_PROBS[kind] for kind in self.models)
        return (1.0 / len(self.models),) * len(self.models)

    def build(self) -> tuple[HeteroModel, ...]:
        """The :class:`HeteroModel` objects."""
        sig = {"ncv": (self.sigma_ncv,), "ct": self.sigma_ct, "ctra": self.sigma_ctra}
        return tuple(
            HeteroModel(k, sig[k], s) for k, s in zip(self.models, self.q_scale, strict=True)
        )


#: Noise of the NCV/CT/CTRA bank for the sonar scenarios of SPEC §3/§6 (T = 1 s, speeds
#: 5-25 m/s, turns of 0.5-3 °/s): seed 002's vehicle-scale values would let the turn rate wander by
#: 0.6 rad/s per step.
SONAR_HETERO_BANK = {
    "models": ("ncv", "ct", "ctra"),
    "sigma_ncv": 0.3,
    "sigma_ct": (0.1, 0.005),
    "sigma_ctra": (0.1, 0.01),
    "initial_probs": (1 / 3, 1 / 3, 1 / 3),
    "turn_rate_var": 1e-3,
    "accel_var": 0.1,
}


class _ModelSensor:
    """The sensor seen from model space: ``h_j = h(g(x))``, ``H_j = H(g(x)) J``; ``R`` is the
    sensor's ``(m, m)`` or a per-tracker ``(N, m, m)`` array (``r_scale``)."""

    def __init__(self, sensor: MeasurementModel, space: str, R: Array) -> None:
        self.sensor = sensor
        self.space = space
        self.dim_z = sensor.dim_z
        self._R = R

    @property
    def R(self) -> Array:
        return self._R

    def h(self, x: Array) -> Array:
        return self.sensor.h(conversion(x, self.space, "ncv")[0])

    def jacobian(self, x: Array) -> Array:
        cart, J = conversion(x, self.space, "ncv")
        return self.sensor.jacobian(cart) @ J

    def residual(self, a: Array, b: Array) -> Array:
        return self.sensor.residual(a, b)

    def wrap(self, z: Array) -> Array:
        return self.sensor.wrap(z)

    def linear_matrix(self, n: int) -> None:
        return None


class HeteroIMM:
    """IMM-EKF over models with different state spaces, batched over N trackers (a
    :class:`~imm_gym.tracking.imm.Tracker` without a compiled kernel).

    The interface of :class:`imm_gym.tracking.imm.IMM` (``init``, ``step``, ``combine``,
    ``run``): the combined output ``IMMStep.x`` is Cartesian ``[x, y, vx, vy]`` with its
    ``4 x 4`` covariance.

    Args:
        models: :class:`HeteroModel` / :class:`LinearModel` objects, or a :class:`HeteroBank`.
        sensor: measurement model on the Cartesian state (:mod:`imm_gym.tracking.sensors`).
        T: sampling period (s).
        filter: only ``"ekf"`` (a linear model's EKF is its Kalman filter).
    """

    def __init__(
        self,
        models: Sequence[AnyModel] | HeteroBank,
        sensor: MeasurementModel,
        T: float = 1.0,
        filter: str = "ekf",
    ) -> None:
        self.bank = models if isinstance(models, HeteroBank) else None
        self.kernel_args: tuple | None = None  # no compiled cycle: the numpy engine runs it
        self.models: tuple[AnyModel, ...] = (
            models.build() if isinstance(models, HeteroBank) else tuple(models)
        )
        if len(self.models) == 0:
            raise ConfigError("models must contain at least one motion model")
        if filter != "ekf":
            raise ConfigError(
                f"the heterogeneous bank runs an EKF only (filter 'ekf'), got {filter!r}"
            )
        self.sensor = sensor
        self.T = check_range("T", T, 0.0, lo_open=True)
        self.dims = tuple(m.dim for m in self.models)
        self.n = max(self.dims)
        self.filter = ExtendedKalmanFilter()

    @property
    def n_models(self) -> int:
        return len(self.models)

    def init(self, x0: Array, P0: Array, mode_probs: Array | None = None) -> IMMState:
        """Every model starts at the Cartesian ``(x0, P0)`` converted into its space.

        Components the Cartesian state lacks (``omega``, ``a``, CA's acceleration) start at 0 with
        the bank's ``turn_rate_var`` / ``accel_var`` (defaults 0.2 and 1.0, seed 002's ``P_0``).
        A start speed within 3 standard deviations of 0 leaves the heading undetermined: its
        variance is capped at a uniform heading's, ``pi^2 / 3``
        (:func:`imm_gym.tracking.conversions.cap_heading`).

        Args:
            x0: ``(4,)`` or ``(N, 4)``; P0: ``(4, 4)`` or ``(N, 4, 4)``, symmetric PD.
            mode_probs: ``(M,)`` or ``(N, M)``; the bank's ``initial_probs`` or uniform by default.
        """
        x0 = np.atleast_2d(np.asarray(x0, dtype=np.float64))
        P0 = np.asarray(P0, dtype=np.float64)
        if P0.shape == (4, 4):  # one covariance for every run
            P0 = np.broadcast_to(P0, (x0.shape[0], 4, 4))
        if x0.shape[-1] != 4 or P0.shape != (x0.shape[0], 4, 4):
            raise ConfigError(
                f"x0 must be (N, 4) Cartesian and P0 (N, 4, 4), got {x0.shape} and {P0.shape}"
            )
        if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(P0))):
            raise ConfigError("x0 and P0 must be finite")
        try:
            np.linalg.cholesky(P0)
        except np.linalg.LinAlgError:
            raise ConfigError("P0 must be positive definite") from None
        N, M = x0.shape[0], self.n_models
        turn_var = self.bank.turn_rate_var if self.bank else 0.2
        accel_var = self.bank.accel_var if self.bank else 1.0
        x = np.zeros((N, M, self.n))
        P = np.zeros((N, M, self.n, self.n))
        for j, m in enumerate(self.models):
            xj, Pj = convert(x0, P0, "ncv", m.space)
            if m.space in ("ct", "ctra"):
                Pj[:, 4, 4] += turn_var
            if m.space == "ctra":
                Pj[:, 5, 5] += accel_var
            if m.space == "cart6":
                Pj[:, 4, 4] += accel_var
                Pj[:, 5, 5] += accel_var
            x[:, j, : m.dim], P[:, j, : m.dim, : m.dim] = xj, Pj
        if mode_probs is None:
            mode_probs = np.array(self.bank.probs) if self.bank else np.full(M, 1.0 / M)
        mu = np.broadcast_to(np.asarray(mode_probs, dtype=np.float64), (N, M)).copy()
        if np.any(mu < 0) or not np.allclose(mu.sum(-1), 1.0):
            raise ConfigError(
                f"mode_probs must be non-negative and sum to 1, got {np.asarray(mode_probs)!r}"
            )
        return IMMState(x=x, P=P, mu=mu)

    def _model_state(self, state: IMMState, j: int) -> tuple[Array, Array]:
        n = self.dims[j]
        return state.x[:, j, :n], state.P[:, j, :n, :n]

    def mix(self, state: IMMState, tpm: Array) -> tuple[Array, list[Array], list[Array]]:
        """Mixing with conversions: ``cbar (N, M)`` and per model ``x0_j (N, n_j)``, ``P0_j``.

        Headings are averaged unwrapped around the heading of the model that weighs most in the
        mix into ``j`` (the largest ``pi_ij mu_i``), so that a model of little weight on the far
        side of ±pi does not pull the mean across."""
        N = state.x.shape[0]
        parts = [self._model_state(state, i) for i in range(self.n_models)]
        into = np.broadcast_to(tpm, (N, self.n_models, self.n_models)) * state.mu[:, :, None]
        cbar = None
        x0s, P0s = [], []
        for j, mj in enumerate(self.models):
            conv = [convert(x, P, self.models[i].space, mj.space) for i, (x, P) in enumerate(parts)]
            states = np.stack([c[0] for c in conv], axis=1)
            lead = states[np.arange(N), into[:, :, j].argmax(axis=1)]
            xs = np.stack([wrap_heading(c[0], mj.space, lead) for c in conv], axis=1)
            Ps = np.stack([c[1] for c in conv], axis=1)
            cbar, x0, P0 = mix(state.mu, xs, Ps, tpm)
            x0s.append(wrap_heading(x0[:, j], mj.space))
            P0s.append(P0[:, j])
        return cbar, x0s, P0s  # type: ignore[return-value]

    def step(
        self,
        state: IMMState,
        tpm: Array,
        z: Array,
        detected: BoolArray | None = None,
        check: bool = True,
        allow_failure: bool = False,
        q_scale: Array | None = None,
        r_scale: Array | None = None,
    ) -> tuple[IMMState, IMMStep]:
        """One IMM-EKF cycle for N trackers (see the module docstring).

        Args:
            state: posterior at k-1 (zero-padded model states).
            tpm: ``(M, M)`` or ``(N, M, M)``.
            z: ``(N, m)`` measurements; detected: ``(N,)``, predict only where False.
            check: validate ``tpm`` and ``z``.
            allow_failure: flag trackers whose innovation covariance is not positive definite in
                ``IMMStep.failed`` (NaN outputs, and at every later step) instead of raising; the
                other trackers get the numbers they get alone.
            q_scale: ``(N, M)`` per-tracker factors on the models' ``Q`` (times each model's own
                ``q_scale``); r_scale: ``(N,)`` per-tracker factors on ``R``.

        Returns:
            The posterior at k and the step outputs (combined ``x (N, 4)``, ``P (N, 4, 4)``).
        """
        N, M, _ = state.x.shape
        det = np.ones(N, dtype=bool) if detected is None else np.asarray(detected, dtype=bool)
        if det.shape != (N,):
            raise ConfigError(f"detected must have shape ({N},), got {det.shape}")
        if check:
            tpm = validate_tpm(tpm, M)
            z = np.asarray(z, dtype=np.float64)
            if z.shape != (N, self.sensor.dim_z):
                raise ConfigError(f"z must have shape ({N}, {self.sensor.dim_z}), got {z.shape}")
            z = used_measurements(z, det)
            _check_scales("q_scale", q_scale, (N, M))
            _check_scales("r_scale", r_scale, (N,))
        if not allow_failure:
            return self._cycle(state, tpm, z, det, False, q_scale, r_scale)
        # failures are flagged, not warned about: a failed tracker's NaN numbers pass through
        # the arithmetic of the steps after it
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            try:
                return self._cycle(state, tpm, z, det, True, q_scale, r_scale)
            except np.linalg.LinAlgError:
                return self._cycle_rows(state, tpm, z, det, q_scale, r_scale)

    def _cycle_rows(
        self, state: IMMState, tpm: Array, z: Array, det: BoolArray,
        q_scale: Array | None, r_scale: Array | None,
    ) -> tuple[IMMState, IMMStep]:
        """:meth:`_cycle` tracker by tracker, after a factorization failed that the pre-checks
        had passed (:func:`~imm_gym.tracking.imm.cycles_by_tracker`)."""

        def cycle(i: int, one: IMMState) -> tuple[IMMState, IMMStep]:
            part = slice(i, i + 1)
            return self._cycle(
                one, tpm if np.ndim(tpm) == 2 else tpm[part], z[part], det[part], True,
                None if q_scale is None else np.asarray(q_scale)[part],
                None if r_scale is None else np.asarray(r_scale)[part],
            )

        return cycles_by_tracker(state, det, self.sensor.dim_z, 4, cycle, z_pred=True)

    def _cycle(
        self, state: IMMState, tpm: Array, z: Array, det: BoolArray, allow_failure: bool,
        q_scale: Array | None, r_scale: Array | None,
    ) -> tuple[IMMState, IMMStep]:
        """:meth:`step` on checked inputs (``det`` an ``(N,)`` array)."""
        N, M, _ = state.x.shape
        R = self.sensor.R if r_scale is None else np.asarray(r_scale)[:, None, None] * self.sensor.R
        cbar, x0s, P0s = self.mix(state, tpm)
        x_new = np.zeros_like(state.x)
        P_new = np.zeros_like(state.P)
        m = self.sensor.dim_z
        loglik, model_nis = np.zeros((N, M)), np.zeros((N, M))
        innovation = np.zeros((N, M, m))
        z_pred, S = np.zeros((N, M, m)), np.tile(np.eye(m), (N, M, 1, 1))
        failed = np.zeros(N, dtype=bool)
        for j, model in enumerate(self.models):
            n = self.dims[j]
            x_pred, F = model.transition(x0s[j], self.T)
            Q = model.q_scale * model.noise(x0s[j], self.T)
            if q_scale is not None:
                Q = np.asarray(q_scale)[:, j, None, None] * Q
            P_pred = F @ P0s[j] @ np.swapaxes(F, -1, -2) + Q
            upd, bad = self._update(x_pred, P_pred, z, _ModelSensor(self.sensor, model.space, R))
            failed |= bad
            if bad.any() and not allow_failure:
                raise np.linalg.LinAlgError(
                    f"innovation covariance not positive definite for {int(bad.sum())} tracker(s)"
                )
            use = det & ~bad
            xj = np.where(use[:, None], upd.x, x_pred)
            Pj = np.where(use[:, None, None], upd.P, P_pred)
            xj = wrap_heading(xj, model.space)
            x_new[:, j, :n], P_new[:, j, :n, :n] = xj, Pj
            loglik[:, j] = np.where(use, upd.loglik, 0.0)
            model_nis[:, j] = np.where(use, upd.nis, 0.0)
            innovation[:, j] = np.where(use[:, None], upd.innovation, 0.0)
            z_pred[:, j], S[:, j] = upd.z_pred, upd.S
        mu = update_mode_probs(loglik, cbar)
        posterior = IMMState(x_new, P_new, mu)
        x_hat, P_hat = self.combine(mu, posterior.x, posterior.P)
        z_mix, S_mix = measurement_mixture(self.sensor, cbar, z_pred, S)
        # a tracker that failed before carries NaN probabilities: its mixture is NaN too; every
        # likelihood underflowing (an overflowed NIS) leaves the probabilities 0/0
        lost = ~(np.isfinite(S_mix).all(axis=(-1, -2)) & np.isfinite(z_mix).all(axis=-1)
                 & finite_outputs(mu, x_hat, P_hat))
        if lost.any():
            if not allow_failure:
                raise np.linalg.LinAlgError(
                    "predicted measurement density or outputs not finite for "
                    f"{int(lost.sum())} tracker(s)"
                )
            failed |= lost
            S_mix = np.where(lost[:, None, None], np.eye(m), S_mix)
        S_inv, _ = inv_logdet(S_mix)
        nu = self.sensor.residual(z, z_mix)
        nis = np.where(det & ~failed, mahalanobis(nu, S_inv), 0.0)
        if failed.any():
            for a in (x_hat, P_hat, mu, nis, z_mix):
                a[failed] = np.nan
        out = IMMStep(
            x_hat, P_hat, mu, cbar, loglik, model_nis, innovation, nis, det, failed, z_mix
        )
        return posterior, out

    def run(
        self,
        z: Array,
        tpm: Array,
        x0: Array,
        P0: Array,
        mode_probs: Array | None = None,
        detected: BoolArray | None = None,
    ) -> IMMResult:
        """Run the bank over recorded measurements with a fixed TPM
        (:func:`imm_gym.tracking.imm.run`)."""
        return run(self, z, tpm, x0, P0, mode_probs, detected)

    def combine(self, mu: Array, x: Array, P: Array) -> tuple[Array, Array]:
        """Combination in the common Cartesian space: every model's posterior ``x (N, M, n)``,
        ``P`` converted by ``g_{j->ncv}`` (``P' = J P J^T``), then
        :func:`imm_gym.tracking.imm.combine` with ``mu (N, M)``.

        Returns:
            ``x (N, 4)``, ``P (N, 4, 4)``.
        """
        state = IMMState(x, P, mu)
        parts = [
            convert(*self._model_state(state, j), m.space, "ncv") for j, m in enumerate(self.models)
        ]
        xc = np.stack([c[0] for c in parts], axis=1)
        Pc = np.stack([c[1] for c in parts], axis=1)
        return combine(mu, xc, Pc)

    def _update(
        self, x: Array, P: Array, z: Array, sensor: _ModelSensor
    ) -> tuple[Update, BoolArray]:
        """EKF update; trackers whose ``S`` is not PD (or not finite) are flagged, not raised."""
        H = sensor.jacobian(x)
        S = H @ P @ np.swapaxes(H, -1, -2) + sensor.R
        finite = np.isfinite(S).all(axis=(-1, -2)) & np.isfinite(x).all(axis=-1)
        S_safe = np.where(finite[:, None, None], S, np.eye(S.shape[-1]))
        bad = ~finite | (
            np.linalg.eigvalsh(0.5 * (S_safe + np.swapaxes(S_safe, -1, -2)))[:, 0] <= 0
        )
        if bad.any():
            x = np.where(bad[:, None], 0.0, x)
            P = np.where(bad[:, None, None], np.eye(x.shape[-1]), P)
        return self.filter.update(x, P, z, sensor), bad


def _check_scales(name: str, scale: Array | None, shape: tuple[int, ...]) -> None:
    """Per-tracker noise factors: ``None`` or finite, > 0, of ``shape``."""
    if scale is None:
        return
    a = np.asarray(scale, dtype=np.float64)
    if a.shape != shape:
        raise ConfigError(f"{name} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a) & (a > 0)):
        raise ConfigError(f"{name} must be finite and in (0, inf), got min {a.min()!r}")


def make_tracker(
    bank: Sequence[MotionModel] | HeteroBank,
    sensor: MeasurementModel,
    filter: str,
    T: float,
    engine: str = "auto",
) -> Tracker:
    """The tracker of a bank: :class:`HeteroIMM` (EKF) for a :class:`HeteroBank`, else the
    classical :class:`imm_gym.tracking.imm.IMM` with ``engine`` (``"auto"``, ``"compiled"`` or
    ``"numpy"``; the heterogeneous bank has the numpy engine only)."""
    if isinstance(bank, HeteroBank):
        return HeteroIMM(bank, sensor, T=T, filter=filter)
    return IMM(bank, sensor, filter=filter, T=T, engine=engine)
