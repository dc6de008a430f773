r"""Running a policy on recorded measurements: the environment's step without its truth.

:func:`run_policy` feeds measurements ``z (N, K+1, m)`` of N recorded sequences through a policy's
whole observation pipeline, as :class:`~imm_gym.sim.core.TrackingCore` does in an episode: bank A
with the TPM the policy's action produces, bank B and the fused probabilities (``parallel``), the
shadow IMM, the features' memories and the observation — by the same engine
(:mod:`imm_gym.sim.engines`), so a simulated episode's measurements handed to :func:`run_policy`
give the environment's estimates, mode probabilities and TPMs bit for bit. No truth is drawn or
read: the replay core has no truth arrays, and the engine's truth-based outputs (errors, the
divergence flag) are computed against a NaN stand-in and discarded.

The track starts as the environment's does (SPEC §6): the position from ``z[:, 0]``, the velocity
given (``velocity``); ``P0 = blockdiag(J R Jᵀ, σ_v² I)``
(:func:`imm_gym.tracking.initiation.initiate`) with ``σ_v`` the configuration's
``velocity_std`` when the velocity is known, :data:`UNKNOWN_VELOCITY_STD` around a zero velocity
when it is not. ``z[:, 1:]`` are filtered: step ``k`` uses ``z[:, k]``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.bank_step import BankStep
from imm_gym.sim.conditions import Variation
from imm_gym.sim.config_file import EVALUATED_FIELDS
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.model_order import for_bank
from imm_gym.tracking.initiation import initiate
from imm_gym.validation import ConfigError

Array = NDArray[np.float64]

#: Standard deviation (m/s) of the initial velocity when none is given (zero velocity assumed):
#: a target of up to about 2σ = 60 m/s starts inside the covariance.
UNKNOWN_VELOCITY_STD = 30.0


@dataclass(frozen=True)
class TrackResult:
    """The per-step outputs of :func:`run_policy` (N sequences, K filtered steps, M models).

    Attributes:
        estimate: ``(N, K, 4)`` combined estimates ``[x, y, vx, vy]`` after step ``k = 1..K``.
        covariance: ``(N, K, 4, 4)`` their covariances.
        mode_probs: ``(N, K, M)`` the mode probabilities (the fused ``U`` with ``parallel``).
        tpm: ``(N, K, M, M)`` the TPM bank A used at each step (the policy's).
        x0, P0: ``(N, 4)``, ``(N, 4, 4)`` the initial estimate from ``z[:, 0]``.
        diverged_at: ``(N,)`` the first step index ``k`` (0-based, of the K) at which the
            estimate is not finite or the position variance ``P_xx + P_yy`` exceeds the
            configuration's ``divergence_cov``; ``K`` where there is none.
    """

    estimate: Array
    covariance: Array
    mode_probs: Array
    tpm: Array
    x0: Array
    P0: Array
    diverged_at: NDArray[np.int64]

    @property
    def diverged(self) -> NDArray[np.bool_]:
        """``(N,)`` the sequences that diverged at some step."""
        return self.diverged_at < self.estimate.shape[1]


class ReplayCore(TrackingCore):
    """A :class:`~imm_gym.sim.core.TrackingCore` fed measurements instead of drawing episodes.

    It keeps the core's banks, features and observation and drops its truth, measurement and
    random-stream arrays: :meth:`start` initiates the slots from given estimates and
    :meth:`advance` takes each step's measurements.

    Args:
        config: the environment configuration (its source is never drawn from; its horizon is
            the ``K`` of the ``time`` feature and its ``T`` the sampling period; ``vary`` is
            ignored: the measurements were taken at the configured sensor and ``T``).
        n_envs: number of sequences N.
    """

    def __init__(self, config: EnvConfig, n_envs: int = 1) -> None:
        super().__init__(config.replace(vary=Variation()) if config.vary.active else config, n_envs)
        del self.truth, self.z, self.detected, self.outlier, self.true_model, self._rngs

    def start(self, x0: Array, P0: Array) -> None:
        """Initiate every slot from ``x0 (N, 4)`` and ``P0 (N, 4, 4)`` as the core's reset does."""
        self._start(np.arange(self.n_envs), x0, P0)

    def advance(self, action: NDArray[Any], z: Array, detected: NDArray[np.bool_]) -> BankStep:
        """One step of every slot with the policy's ``action (N, M*M)``, the measurements
        ``z (N, m)`` and their flags ``detected (N,)``, recorded as :meth:`TrackingCore.step`
        records it. Returns the engine's :class:`~imm_gym.sim.bank_step.BankStep` (its error and
        divergence fields are meaningless: no truth)."""
        no_truth = np.full((self.n_envs, self.n), np.nan)
        out = self._advance_banks(self.validate_action(action), z, detected, no_truth)
        self._record(out, self.k + 1)
        return out


def _floats(name: str, value: Any) -> Array:
    """``value`` as a float array, or raise :class:`ConfigError` naming ``name`` where it is not
    an array of numbers (text, rows of different lengths)."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{name} must be an array of numbers ({err})") from None


def _as_batch(name: str, value: Any, ndim: int, single: bool) -> Array:
    """``value`` as a float array with a leading sequence axis (added for a single sequence)."""
    array = _floats(name, value)
    if single:
        array = array[None]
    if array.ndim != ndim:
        raise ConfigError(f"{name} must have {ndim - 1 if single else ndim} dimensions, "
                          f"got shape {np.shape(value)}")
    return array


def _detections(z: Array, detected: Any, single: bool) -> NDArray[np.bool_]:
    """The ``(N, K+1)`` detection flags of ``z (N, K+1, m)``: ``detected`` checked (booleans,
    or numbers 0 and 1; a detection's ``z`` finite), or without it the rows of ``z`` without
    NaN (a row all NaN a missed detection). Infinite ``z`` and rows only partly NaN are
    refused."""
    N, K1, _ = z.shape
    if np.isinf(z).any():
        n, k = (int(i) for i in np.argwhere(np.isinf(z))[0][:2])
        raise ConfigError(f"z[{n}, {k}] is infinite (NaN is a missed detection)")
    finite = np.all(np.isfinite(z), axis=-1)
    if detected is None:
        partial = ~finite & ~np.all(np.isnan(z), axis=-1)
        if partial.any():
            n, k = (int(i) for i in np.argwhere(partial)[0])
            raise ConfigError(f"z[{n}, {k}] is partly NaN: a missed detection is a row of NaN "
                              "(or give detected)")
        return finite
    flags = np.asarray(detected)
    flags = flags[None] if single else flags
    if flags.shape != (N, K1):
        raise ConfigError(f"detected must have shape {(N, K1)[1 if single else 0:]}, "
                          f"got {np.shape(detected)}")
    if flags.dtype != bool and not (
        flags.dtype.kind in "iuf" and np.all((flags == 0) | (flags == 1))
    ):
        raise ConfigError("detected must be booleans or the numbers 0 and 1")
    det = flags.astype(bool)
    if not np.all(finite | ~det):
        raise ConfigError("a detected measurement is not finite")
    return det


def start_problem(x0: Array, P0: Array) -> str | None:
    """What is wrong with initial estimates ``x0 (N, 4)`` and covariances ``P0 (N, 4, 4)``
    (not finite, ``P0`` not symmetric positive definite), naming the first sequence; None if
    nothing is."""
    for n in range(x0.shape[0]):
        if not (np.all(np.isfinite(x0[n])) and np.all(np.isfinite(P0[n]))):
            return f"sequence {n}: x0 and P0 must be finite"
        if not np.allclose(P0[n], P0[n].T, rtol=1e-9, atol=0.0):
            return f"sequence {n}: P0 must be symmetric"
        try:
            np.linalg.cholesky(P0[n])
        except np.linalg.LinAlgError:
            return f"sequence {n}: P0 must be positive definite"
    return None


def run_policy(
    z: Any,
    policy: Any,
    config: EnvConfig | None = None,
    detected: Any = None,
    x0: Any = None,
    P0: Any = None,
    velocity: Any = None,
    overrides: Mapping[str, Any] | None = None,
) -> TrackResult:
    r"""Run ``policy`` on recorded measurements (see the module docstring).

    Args:
        z: ``(N, K+1, m)`` measurements of N sequences (or ``(K+1, m)`` for one) in the sensor's
            components (the sonar's range and bearing); ``z[:, 0]`` initiates the track. A NaN
            row is a missed detection when ``detected`` is not given.
        policy: anything with SB3's ``predict(obs, state, episode_start, deterministic)``; a
            policy shared by the models is rebuilt for the bank's size
            (:func:`~imm_gym.sim.model_order.for_bank`).
        config: the tracker's configuration (default :class:`EnvConfig`): sensor, bank, filter,
            TPM settings; its scenario gives the sampling period ``T``.
        detected: ``(N, K+1)`` detection flags (default: the rows of ``z`` without NaN); an
            undetected step is a prediction only.
        x0, P0: ``(N, 4)`` and ``(N, 4, 4)`` initial estimate and covariance (default: from
            ``z[:, 0]`` and ``velocity``).
        velocity: ``(N, 2)`` or ``(2,)`` initial velocity (m/s) with standard deviation
            ``config.velocity_std`` of the start made from ``z[:, 0]`` (not with ``x0``);
            default zero with :data:`UNKNOWN_VELOCITY_STD`.
        overrides: the EnvConfig fields the policy needs, applied to ``config`` (default: its
            ``env_overrides``, if any: action mode, observation features, a tuned bank...; for
            a trained agent, ensemble or selector, without the tracker, targets and evaluation
            settings it recorded, :data:`~imm_gym.sim.config_file.EVALUATED_FIELDS`: it tracks
            with ``config``'s, as ``python -m imm_gym.track`` does).

    Returns:
        The :class:`TrackResult`, batched (``N = 1`` for a single sequence).

    Raises:
        ConfigError: inconsistent shapes; ``z``, ``x0``, ``P0`` or ``velocity`` not an array
            of numbers (text, rows of different lengths); an infinite ``z``, a row only partly
            NaN without ``detected``, a detected non-finite measurement; ``detected`` not
            booleans or 0/1; a velocity, ``x0`` or ``P0`` not finite, ``P0`` not symmetric
            positive definite, ``P0`` without ``x0``, or ``velocity`` with ``x0``.
    """
    base = EnvConfig() if config is None else config
    if overrides is None:
        overrides = getattr(policy, "env_overrides", {})
        if hasattr(policy, "trained_across"):  # a trained policy: it tracks with config's
            overrides = {k: v for k, v in overrides.items() if k not in EVALUATED_FIELDS}
    cfg = base.replace(**overrides)
    policy = for_bank(policy, len(cfg.bank))
    z_in = _floats("z", z)
    single = z_in.ndim == 2
    z_all = _as_batch("z", z_in, 3, single)
    N, K1, m = z_all.shape
    if m != cfg.sensor.dim_z or K1 < 2:
        raise ConfigError(f"z must be (N, K+1, {cfg.sensor.dim_z}) with K >= 1, got {z_in.shape}")
    det = _detections(z_all, detected, single)
    if not det[:, 0].all():
        raise ConfigError("z[:, 0] initiates the track: it must be a finite detection")
    # step-major and contiguous: each step's (N, m) slice is what the engine takes
    z_steps = np.ascontiguousarray(np.where(det[..., None], z_all, 0.0).transpose(1, 0, 2))
    det_steps = np.ascontiguousarray(det.T)
    if x0 is None:
        if P0 is not None:
            raise ConfigError("P0 needs x0")
        if velocity is None:
            start, cov = initiate(cfg.sensor, z_steps[0], np.zeros(2), UNKNOWN_VELOCITY_STD)
        else:
            v = _floats("velocity", velocity)
            if v.shape not in ((2,), (N, 2)) or not np.all(np.isfinite(v)):
                raise ConfigError(f"velocity must be finite, of shape (2,) or ({N}, 2), got "
                                  f"{v.tolist()} of shape {v.shape}")
            start, cov = initiate(cfg.sensor, z_steps[0], v, cfg.velocity_std)
    else:
        if velocity is not None:
            raise ConfigError("velocity and x0 both given: velocity is for the start made from "
                              "z[:, 0], which x0 and P0 replace; give one of them")
        start = _as_batch("x0", x0, 2, single)
        cov = _as_batch("P0", P0, 3, single) if P0 is not None else None
        if cov is None:
            raise ConfigError("x0 needs P0")
        if start.shape != (N, 4) or cov.shape != (N, 4, 4):
            raise ConfigError(f"x0 and P0 must be ({N}, 4) and ({N}, 4, 4)")
        problem = start_problem(start, cov)
        if problem is not None:
            raise ConfigError(problem)
    core = ReplayCore(cfg, n_envs=N)
    core.start(start, cov)
    K, M = K1 - 1, core.M
    estimate, covariance = np.empty((N, K, 4)), np.empty((N, K, 4, 4))
    probs, tpms = np.empty((N, K, M)), np.empty((N, K, M, M))
    obs, state = core.observe(), None
    episode_start = np.ones(N, dtype=bool)
    for k in range(K):
        actions, state = policy.predict(
            obs, state=state, episode_start=episode_start, deterministic=True
        )
        episode_start = np.zeros(N, dtype=bool)
        out = core.advance(actions, z_steps[k + 1], det_steps[k + 1])
        estimate[:, k] = out.estimate[:, :4]
        covariance[:, k] = out.covariance[:, :4, :4]
        probs[:, k] = out.mode_probs
        tpms[:, k] = out.tpm
        obs = core.observe()
    position_var = covariance[..., 0, 0] + covariance[..., 1, 1]
    bad = ~np.all(np.isfinite(estimate), axis=2) | ~(position_var <= cfg.divergence_cov)
    diverged_at = np.where(bad.any(axis=1), bad.argmax(axis=1), K).astype(np.int64)
    return TrackResult(estimate, covariance, probs, tpms, start, cov, diverged_at)
