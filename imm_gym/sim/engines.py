"""The two engines of one step of all banks (bank A with the action's TPM, bank B, the shadow IMM),
both returning a :class:`~imm_gym.sim.bank_step.BankStep`:

* ``"numpy"`` — :func:`numpy_step`, the reference: :func:`imm_gym.sim.actions.tpm_from_action`,
  the tracker's ``step`` per bank, :func:`imm_gym.tracking.fusion.fuse` and the output
  combination. Runs any tracker (a custom sensor, the heterogeneous bank).
* ``"compiled"`` — :func:`compiled_step`, one call of :func:`imm_gym.sim.kernels.env_step` for
  trackers with a compiled kernel (``kernel_args``: built-in sensor and filter).

``EnvConfig.engine = "auto"`` takes the compiled engine where the tracker has one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.actions import tpm_from_action
from imm_gym.sim.bank_step import BankStep
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.kernels import ACTION_MODE_CODES, env_step, env_step_one
from imm_gym.tracking.fusion import fuse
from imm_gym.tracking.imm import IMMState, Tracker
from imm_gym.tracking.kernels.imm import fits_one
from imm_gym.validation import ConfigError

Array = NDArray[np.float64]


class Banks(Protocol):
    """What an engine reads of the core (:class:`imm_gym.sim.core.TrackingCore`): the
    configuration, the tracker and the banks' state before the step (N slots, M models)."""

    config: EnvConfig
    imm: Tracker
    tpm: Array  # (N, M, M) bank A's current TPMs
    state_a: IMMState  # bank A's posterior
    state_b: IMMState  # bank B's (parallel)
    state_s: IMMState  # the shadow IMM's
    mu_b: Array  # (N, M) bank B's last probabilities before the fusion
    kernel_args: tuple | None  # the compiled bank constants (F, Q, R per slot or shared)
    fixed_tpms: Array  # (N, M, M) bank B's TPM
    shadow_tpms: Array  # (N, M, M) the shadow's TPM
    stay_base_tpms: Array  # (N, M, M) the TPMs the stay mode moves from


Engine = Callable[[Banks, Array, Array, NDArray[np.bool_], Array], BankStep]


def compiled_step(
    banks: Banks, action: Array, z: Array, detected: NDArray[np.bool_], truth: Array
) -> BankStep:
    """All banks' step as one call of the compiled :func:`imm_gym.sim.kernels.env_step`.

    Args:
        action: ``(N, M*M)`` finite actions; z: ``(N, m)``; detected: ``(N,)``; truth:
            ``(N, 4)`` the slots' true states (for the errors).
    """
    cfg = banks.config
    gain = cfg.max_factor if cfg.action_mode == "scale" else cfg.logit_scale
    a, b, s = banks.state_a, banks.state_b, banks.state_s
    N, M, n = a.x.shape
    step = env_step_one if fits_one(N, M, n, z.shape[1]) else env_step
    return step(
        action, banks.tpm, ACTION_MODE_CODES[cfg.action_mode], gain, cfg.p_min,
        a.x, a.P, a.mu, b.x, b.P, b.mu, s.x, s.P, s.mu, banks.fixed_tpms, banks.shadow_tpms,
        banks.stay_base_tpms, z, detected, truth, banks.kernel_args, cfg.parallel,
        cfg.shadow == "fixed", cfg.divergence_error, cfg.divergence_cov,
    )


def _capped_error(x: Array, truth: Array, cap: float) -> tuple[Array, Array]:
    """``(e, min(e, cap))``, ``e = |p_hat - p|`` (a NaN error becomes the cap)."""
    d = x[:, :2] - truth[:, :2]
    error = np.sqrt(np.sum(d * d, axis=-1))
    return error, np.where(error <= cap, error, cap)


def numpy_step(
    banks: Banks, action: Array, z: Array, detected: NDArray[np.bool_], truth: Array
) -> BankStep:
    """All banks' step composed of the tracker's own operations (any tracker)."""
    cfg, imm = banks.config, banks.imm
    tpm = tpm_from_action(action, banks.tpm, cfg, banks.stay_base_tpms)
    state_a, out_a = imm.step(banks.state_a, tpm, z, detected, check=False, allow_failure=True)
    failed = out_a.failed
    state_b, mu_b = banks.state_b, banks.mu_b
    if cfg.parallel:
        state_b, out_b = imm.step(
            banks.state_b, banks.fixed_tpms, z, detected, check=False, allow_failure=True
        )
        failed = failed | out_b.failed
        mu_b = out_b.mode_probs
        U = fuse(out_a.mode_probs, mu_b)
        x_hat, P_hat = imm.combine(U, state_a.x, state_a.P)
    else:
        U, x_hat, P_hat = out_a.mode_probs, out_a.x, out_a.P
    error, capped = _capped_error(x_hat, truth, cfg.divergence_error)
    N = action.shape[0]
    state_s, velocity_s, shadow_error = banks.state_s, np.zeros((N, 2)), np.zeros(N)
    cbar_s, loglik_s = np.zeros_like(out_a.cbar), np.zeros_like(out_a.loglik)
    if cfg.shadow == "fixed":
        state_s, out_s = imm.step(
            banks.state_s, banks.shadow_tpms, z, detected, check=False, allow_failure=True
        )
        shadow_error = _capped_error(out_s.x, truth, cfg.divergence_error)[1]
        velocity_s = out_s.x[:, 2:4].copy()
        cbar_s, loglik_s = out_s.cbar, out_s.loglik
    diverged = (
        failed
        | ~(error <= cfg.divergence_error)
        | ~(P_hat[:, 0, 0] + P_hat[:, 1, 1] <= cfg.divergence_cov)
    )
    return BankStep(
        tpm=tpm, x_a=state_a.x, P_a=state_a.P, mode_probs=U,
        x_b=state_b.x, P_b=state_b.P, mu_b=mu_b, x_s=state_s.x, P_s=state_s.P, mu_s=state_s.mu,
        estimate=x_hat, covariance=P_hat, cbar=out_a.cbar, loglik=out_a.loglik,
        model_nis=out_a.model_nis, innovation=out_a.innovation, cbar_s=cbar_s, loglik_s=loglik_s,
        nis=out_a.nis, velocity=x_hat[:, 2:4].copy(),
        velocity_s=velocity_s, position_error=capped, shadow_position_error=shadow_error,
        diverged=diverged,
    )


ENGINES: dict[str, Engine] = {"compiled": compiled_step, "numpy": numpy_step}


def choose_engine(name: str, kernel_args: tuple | None) -> Engine:
    """The engine called ``name`` (``auto``: compiled where the tracker has a kernel)."""
    if name == "auto":
        name = "numpy" if kernel_args is None else "compiled"
    if name == "compiled" and kernel_args is None:
        raise ConfigError(
            "engine 'compiled' needs a tracker with a compiled kernel (built-in sensor and filter, "
            "linear bank); use engine 'auto' or 'numpy'"
        )
    return ENGINES[name]
