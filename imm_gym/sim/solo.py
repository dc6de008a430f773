r"""The scalar env's step as one compiled call on state that stays in a few arrays.

:class:`~imm_gym.sim.core.TrackingCore` is built for N slots: each step it hands the compiled
banks' results (:func:`imm_gym.sim.kernels.env_step`) back to Python as fresh arrays and
computes the reward, the episode ends, the records and the observation with numpy. At N = 1
those small-array operations, not the arithmetic, are the step's cost. :class:`SoloStep` keeps
one slot's state — the three banks, the TPM, the step counter and every quantity the core
records — in eight arrays that :func:`solo_step` advances in place; the call fills the
observation's buffer and a row of the episode's info record, whose columns the info's arrays
are views of (a fresh record per episode: a row is written once):

1. the slot's inputs at ``k_1 = min(k + 1, K)`` (:func:`imm_gym.sim.kernels.step_inputs`);
2. the banks' step (:func:`imm_gym.sim.kernels.env_step_body`, the body of ``env_step`` and
   ``env_step_one``: the action's TPM, bank A, bank B and the fusion, the shadow IMM, the capped
   errors and the divergence flag);
3. the reward terms of :mod:`imm_gym.sim.rewards` — ``error`` :math:`-e/s`, ``advantage``
   :math:`(e_s - e)/s`, ``squared_advantage`` :math:`(e_s^2 - e^2)/s^2` (``s`` the reward
   scale, ``e`` and ``e_s`` the capped errors of the combined estimate and the shadow's);
4. the ends (truncation at the horizon, termination on divergence), the records of
   :meth:`~imm_gym.sim.core.TrackingCore._record` and the observation ``[μ(t), μ(t−1)]``
   clipped to its box.

The core keeps the episode (its reset draws it) and stays current: its state attributes are views
of :class:`SoloStep`'s arrays. The numbers are the core's bit for bit (``tests/sim/test_solo.py``
holds every info entry, the observation, the reward and the core's state after each step equal
to the core's own step).
It covers the configurations whose whole step is compiled: the compiled engine on a tracker of
:func:`~imm_gym.tracking.kernels.imm.imm_step_one`'s shape, no observation feature, the
``stay`` mode from the tracker's own TPM (no other base, no stay bank), the built-in reward
terms only and none of the reward's TPM or mode terms (``tpm_cost``, ``tpm_change_cost``,
``mode_reward``: their ``log`` is numpy's vectorized one in the core, which rounds differently
from the scalar ``log`` compiled code calls) —
:meth:`SoloStep.fits`; the scalar env runs every other configuration through the core.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.actions import ActionError, real_numbers
from imm_gym.sim.core import INFINITY_STAND_IN, TrackingCore
from imm_gym.sim.kernels import ACTION_MODE_CODES, env_step_body, step_inputs
from imm_gym.sim.rewards import REWARD_TERMS
from imm_gym.tracking.imm import IMMState
from imm_gym.tracking.kernels.imm import fits_one, pack_one, unpack_one

Array = NDArray[np.float64]

# fmt: off

#: rows of the ``(3, 1, M, n)`` posteriors and ``(3, 1, M, n, n)`` covariances: the banks
BANK_A, BANK_B, SHADOW = 0, 1, 2
#: rows of the ``(R, 1, M)`` per-model records, named as the core's attributes
MU_ROWS = ("mu", "mu_prev", "mu_b", "mu_s", "mu_s_prev", "cbar", "loglik", "cbar_s", "loglik_s",
           "model_nis")
MU, MU_PREV, MU_B, MU_S, MU_S_PREV, CBAR, LOGLIK, CBAR_S, LOGLIK_S, MODEL_NIS = range(10)
#: rows of the ``(4, 1, 2)`` velocity records
VELOCITY_ROWS = ("velocity", "velocity_prev", "velocity_s", "velocity_s_prev")
VELOCITY, VELOCITY_PREV, VELOCITY_S, VELOCITY_S_PREV = range(4)

#: entries of the ``settings`` vector of :func:`solo_step`
(MODE, GAIN, P_MIN, PARALLEL, SHADOW_ON, DIVERGENCE_ERROR, DIVERGENCE_COV, REWARD, SCALE,
 SCALE2) = range(10)
#: the rewarded term's code in ``settings[REWARD]``
REWARD_CODES = {"error": 0, "advantage": 1, "squared_advantage": 2}

#: The info's float entries: the first columns of a row of the episode's info record
FLOAT_INFO = ("position_error", "nis", "reward_error", "reward_advantage",
              "reward_squared_advantage", "shadow_position_error")
(POSITION_ERROR, NIS, REWARD_ERROR, REWARD_ADVANTAGE, REWARD_SQUARED_ADVANTAGE,
 SHADOW_POSITION_ERROR) = range(len(FLOAT_INFO))
#: then its array entries, from the columns :func:`info_columns` gives
ARRAY_INFO = ("true_state", "estimate", "covariance", "mode_probs", "loglik", "model_nis", "tpm")
TRUE_STATE, ESTIMATE, COVARIANCE, MODE_PROBS, LOGLIK_INFO, MODEL_NIS_INFO, TPM = range(
    len(ARRAY_INFO))

def info_columns(d: int, n: int, M: int) -> NDArray[np.int64]:
    """Where each entry of :data:`ARRAY_INFO` starts in a row of the info record (the last: the
    row's length), after the :data:`FLOAT_INFO` columns, for a ``d``-dimensional true state,
    ``n`` states and ``M`` models."""
    sizes = (d, n, n * n, M, M, M, M * M)
    return np.cumsum((len(FLOAT_INFO), *sizes)).astype(np.int64)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def solo_step(
    action: Array, x: Array, P: Array, per_model: Array, velocities: Array, innovation: Array,
    tpm: Array, k: NDArray[np.int64], done: NDArray[np.bool_], z: Array,
    detected: NDArray[np.bool_], truth: Array, true_model: NDArray[np.int64], fixed_tpm: Array,
    shadow_tpm: Array, bank: Array,
    settings: Array, at: NDArray[np.int64], obs_low: NDArray[np.float32],
    obs_high: NDArray[np.float32], obs: NDArray[np.float32], record: Array,
) -> tuple[float, bool, bool, bool, int, bool, int]:  # pragma: no cover
    """One step of one slot (the module docstring's steps 1-4), its state advanced in place.

    Args:
        action: ``(action_dim,)`` float64, clipped here.
        x, P: ``(3, 1, M, n)``, ``(3, 1, M, n, n)`` the posteriors of bank A, bank B and the
            shadow; per_model: ``(10, 1, M)`` the records :data:`MU_ROWS`; velocities:
            ``(4, 1, 2)`` the records :data:`VELOCITY_ROWS`; innovation: ``(1, M, m)``; tpm:
            ``(1, M, M)`` bank A's TPM; k, done: ``(1,)`` the step counter and the episode's
            end.
        z, detected, truth, true_model: the episode, ``(1, K+1, m)``, ``(1, K+1)``,
            ``(1, K+1, d)``, ``(1, K)``.
        fixed_tpm, shadow_tpm: ``(1, M, M)`` bank B's and the shadow's TPM.
        bank: the tracker's kernel constants packed
            (:func:`~imm_gym.tracking.kernels.imm.pack_one`); settings: the configuration
            (:data:`MODE` ...).
        at: :func:`info_columns`; obs_low, obs_high: the observation's box.
        obs: filled with the observation; record: ``(K+1, at[-1])`` the episode's info record,
            its row ``k + 1`` filled with this step's float and array info entries.

    Returns:
        ``(reward, terminated, truncated, finite, true_model, detected, step)`` (``terminated``
        is the info's ``diverged``); ``finite`` False (a NaN or inf in the action) leaves
        everything untouched.
    """
    for value in action:
        if not np.isfinite(value):
            return 0.0, False, False, False, 0, False, 0
    M = tpm.shape[1]
    K = true_model.shape[1]
    _, step, z_k, det, truth_k, model = step_inputs(k, K, z, detected, truth, true_model)
    k1, j_star = step[0], model[0]
    parallel = settings[PARALLEL] != 0.0
    shadow = settings[SHADOW_ON] != 0.0
    out = env_step_body(
        action.reshape((1, action.size)), tpm, int(settings[MODE]), settings[GAIN],
        settings[P_MIN], x[BANK_A], P[BANK_A], per_model[MU], x[BANK_B], P[BANK_B],
        per_model[MU] if parallel else per_model[MU_B], x[SHADOW], P[SHADOW], per_model[MU_S],
        fixed_tpm, shadow_tpm, fixed_tpm, z_k, det, truth_k, unpack_one(bank), parallel, shadow,
        settings[DIVERGENCE_ERROR], settings[DIVERGENCE_COV], True)
    # the reward (rewards.Reward)
    s = settings[SCALE]
    e = out.position_error[0]
    e_s = out.shadow_position_error[0]
    terms = (e / -s, (e_s - e) / s, (e_s * e_s - e * e) / settings[SCALE2])
    reward = terms[int(settings[REWARD])]
    diverged = out.diverged[0]
    truncated = k1 >= K and not diverged
    # the info's entries other than true_model, detected, step and diverged (returned)
    row = record[k1]
    row[POSITION_ERROR] = e
    row[NIS] = out.nis[0]
    row[REWARD_ERROR] = terms[0]
    row[REWARD_ADVANTAGE] = terms[1]
    row[REWARD_SQUARED_ADVANTAGE] = terms[2]
    row[SHADOW_POSITION_ERROR] = e_s
    for i in range(truth_k.shape[1]):
        row[at[TRUE_STATE] + i] = truth_k[0, i]
    n = out.estimate.shape[1]
    for i in range(n):
        row[at[ESTIMATE] + i] = out.estimate[0, i]
        for c in range(n):
            row[at[COVARIANCE] + i * n + c] = out.covariance[0, i, c]
    for i in range(M):
        row[at[MODE_PROBS] + i] = out.mode_probs[0, i]
        row[at[LOGLIK_INFO] + i] = out.loglik[0, i]
        row[at[MODEL_NIS_INFO] + i] = out.model_nis[0, i]
        for c in range(M):
            row[at[TPM] + i * M + c] = out.tpm[0, i, c]
    if diverged:  # core._finite: the API's stand-ins for non-finite floats
        for i in range(row.size):
            if np.isnan(row[i]):
                row[i] = 0.0
            elif np.isinf(row[i]):
                row[i] = INFINITY_STAND_IN if row[i] > 0.0 else -INFINITY_STAND_IN
    # the records (core._record)
    x[BANK_A] = out.x_a
    P[BANK_A] = out.P_a
    if parallel:
        x[BANK_B] = out.x_b
        P[BANK_B] = out.P_b
        per_model[MU_B] = out.mu_b
    if shadow:
        x[SHADOW] = out.x_s
        P[SHADOW] = out.P_s
        per_model[MU_S_PREV] = per_model[MU_S]
        per_model[MU_S] = out.mu_s
        per_model[CBAR_S] = out.cbar_s
        per_model[LOGLIK_S] = out.loglik_s
        velocities[VELOCITY_S_PREV] = velocities[VELOCITY_S]
        velocities[VELOCITY_S] = out.velocity_s
    k[0] = k1
    done[0] = diverged or truncated
    tpm[...] = out.tpm
    per_model[MU_PREV] = per_model[MU]
    per_model[MU] = out.mode_probs
    per_model[CBAR] = out.cbar
    per_model[LOGLIK] = out.loglik
    per_model[MODEL_NIS] = out.model_nis
    innovation[...] = out.innovation
    velocities[VELOCITY_PREV] = velocities[VELOCITY]
    velocities[VELOCITY] = out.velocity
    # the observation (core.observe): [mu(t), mu(t-1)], non-finite entries replaced, the box
    finite = True
    for i in range(M):
        finite = finite and np.isfinite(per_model[MU, 0, i]) and np.isfinite(
            per_model[MU_PREV, 0, i])
    for i in range(2 * M):
        value = per_model[MU if i < M else MU_PREV, 0, i % M]
        if not finite:
            value = 0.0 if np.isnan(value) else (1.0 if value > 0.0 else -1.0) if np.isinf(
                value) else value
        o = np.float32(value)
        o = max(o, obs_low[i])
        obs[i] = min(o, obs_high[i])
    return reward, diverged, truncated, True, j_star, det[0], k1

# fmt: on


class SoloStep:
    """The scalar env's step on a :class:`~imm_gym.sim.core.TrackingCore` with N = 1 (the module
    docstring). :meth:`load` takes the core's state after a reset and makes the core's state
    attributes views of the arrays :func:`solo_step` advances in place: the core stays current
    (``core.mu``, ``core.state_a``, ``core.k`` ... are the last step's), at the price of those
    arrays changing between steps. A core that was reset or stepped by itself since (its
    ``k`` is no longer the view) is loaded again at the next :meth:`step`.
    """

    def __init__(self, core: TrackingCore) -> None:
        if not self.fits(core):
            raise ValueError("SoloStep needs a core that fits (SoloStep.fits)")
        cfg = core.config
        M, n, d = core.M, core.n, core.truth.shape[2]
        self._core = core
        self._x = np.zeros((3, 1, M, n))
        self._P = np.zeros((3, 1, M, n, n))
        self._per_model = np.zeros((len(MU_ROWS), 1, M))
        self._velocities = np.zeros((len(VELOCITY_ROWS), 1, 2))
        self._innovation = np.zeros_like(core.innovation)
        self._tpm = np.zeros((1, M, M))
        self._k = np.zeros(1, dtype=np.int64)
        self._done = np.ones(1, dtype=bool)
        self._settings = np.zeros(SCALE2 + 1)
        self._settings[:SCALE] = [
            ACTION_MODE_CODES[cfg.action_mode],
            cfg.max_factor if cfg.action_mode == "scale" else cfg.logit_scale,
            cfg.p_min, cfg.parallel, cfg.shadow == "fixed", cfg.divergence_error,
            cfg.divergence_cov, REWARD_CODES[cfg.reward],
        ]
        self._at = info_columns(d, n, M)
        self._obs = np.zeros(core.obs_dim, dtype=np.float32)
        self._action_shape = (core.action_dim,)
        self._shadow = cfg.shadow == "fixed"
        #: the episode's info record, its float columns and its array columns (:meth:`load`)
        self._floats: Array = np.zeros((0, len(FLOAT_INFO)))
        self._columns: tuple[Array, ...] = ()
        self._args: tuple = ()

    def __reduce__(self) -> tuple[Any, tuple[TrackingCore]]:
        """Pickled (and deep-copied) as its core only: the arrays whose views the core and the
        info's columns hold would be pickled as separate copies. A copy loads the core's state
        again at its first step; where the core no longer fits (:func:`restore`) it is None and
        the env steps through the core."""
        return restore, (self._core,)

    @staticmethod
    def fits(core: TrackingCore) -> bool:
        """Whether the core's whole step is :func:`solo_step`'s: one slot, the compiled engine
        on a tracker of ``imm_step_one``'s shape, no observation feature, the models in the
        bank's order, the ``stay`` mode (if any) moving from the tracker's own TPM (the base
        :func:`solo_step` passes; no stay bank, no detector), and the reward registry holding
        the built-in terms only (a stay bank's terms apart: without the stay bank they are not
        computed)."""
        cfg = core.config
        return (
            core.n_envs == 1
            and cfg.engine != "numpy"
            and core.imm.kernel_args is not None
            and fits_one(1, core.M, core.n, cfg.sensor.dim_z)
            and not cfg.obs_features
            and core.model_order is None
            and cfg.stay_base == "tracker"
            and cfg.detector_share == 0.0
            and core.stay_bank is None
            and core.learned_detector is None
            and tuple(k for k, t in REWARD_TERMS.items() if not t.needs_stay_bank)
            == tuple(REWARD_CODES)
            and cfg.tpm_cost == cfg.tpm_change_cost == cfg.mode_reward == 0.0
        )

    def load(self, core: TrackingCore) -> None:
        """Take the core's state (after its reset) as the state the steps advance, and make the
        core's state attributes views of it."""
        self._x[:] = [core.state_a.x, core.state_b.x, core.state_s.x]
        self._P[:] = [core.state_a.P, core.state_b.P, core.state_s.P]
        self._per_model[:] = [getattr(core, name) for name in MU_ROWS]
        self._velocities[:] = [getattr(core, name) for name in VELOCITY_ROWS]
        self._innovation[:] = core.innovation
        self._tpm[:] = core.tpm
        self._k[:] = core.k
        self._done[:] = core.done
        for row, name in enumerate(MU_ROWS):
            setattr(core, name, self._per_model[row])
        for row, name in enumerate(VELOCITY_ROWS):
            setattr(core, name, self._velocities[row])
        core.innovation, core.tpm, core.k, core.done = (
            self._innovation, self._tpm, self._k, self._done
        )
        # bank B's probabilities are the fused ones when it runs, else its untouched start
        b_row = MU if core.config.parallel else MU_B
        core.state_a = IMMState(self._x[BANK_A], self._P[BANK_A], self._per_model[MU])
        core.state_b = IMMState(self._x[BANK_B], self._P[BANK_B], self._per_model[b_row])
        core.state_s = IMMState(self._x[SHADOW], self._P[SHADOW], self._per_model[MU_S])
        # the episode's info record (a fresh one per episode: the rows handed out stay as they
        # were) and its columns, each a (K+1, ...) array whose row k is step k's entry
        K, n, M = core.horizon, core.n, core.M
        at = self._at
        record = np.zeros((K + 1, int(at[-1])))
        self._floats = record[:, : len(FLOAT_INFO)]
        shapes = {COVARIANCE: (n, n), TPM: (M, M)}
        self._columns = tuple(
            record[:, at[j] : at[j + 1]].reshape((K + 1, *shapes.get(j, (-1,))))
            for j in range(len(ARRAY_INFO))
        )
        scale = core.reward_scale
        self._settings[SCALE] = np.asarray(scale).reshape(-1)[0]
        self._settings[SCALE2] = np.asarray(scale**2).reshape(-1)[0]  # as the core squares it
        self._args = (
            self._x, self._P, self._per_model, self._velocities, self._innovation, self._tpm,
            self._k, self._done, core.z, core.detected, core.truth, core.true_model,
            core.fixed_tpms, core.shadow_tpms, pack_one(*core.kernel_args), self._settings,
            self._at, core.obs_low, core.obs_high, self._obs, record,
        )

    def step(
        self, action: NDArray[Any]
    ) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """One step: ``(obs, reward, terminated, truncated, info)``, fresh objects, the info's
        numbers as Python scalars and its arrays views of this step's row of the episode's info
        record (written once: they never change)."""
        # a fresh C-contiguous copy: one compiled variant
        a = np.array(real_numbers(action), dtype=np.float64)
        if a.shape != self._action_shape:
            raise ActionError(f"action must have shape {self._action_shape}, got {a.shape}")
        if self._core.k is not self._k:  # the core was reset or stepped by itself
            self.load(self._core)
        if self._done[0]:
            raise RuntimeError("episodes in slots [0] have ended; call reset before step")
        reward, terminated, truncated, finite, true_model, detected, k = solo_step(
            a, *self._args
        )
        if not finite:
            raise ActionError("action must be finite (got NaN or inf)")
        error, nis, reward_error, reward_advantage, reward_squared, shadow_error = self._floats[
            k
        ].tolist()
        true_state, estimate, covariance, mode_probs, loglik, model_nis, tpm = self._columns
        info: dict[str, Any] = {  # in the core's order
            "true_state": true_state[k],
            "true_model": true_model,
            "estimate": estimate[k],
            "covariance": covariance[k],
            "position_error": error,
            "mode_probs": mode_probs[k],
            "loglik": loglik[k],
            "model_nis": model_nis[k],
            "nis": nis,
            "detected": detected,
            "tpm": tpm[k],
            "step": k,
            "reward_error": reward_error,
            "reward_advantage": reward_advantage,
            "reward_squared_advantage": reward_squared,
            "shadow_position_error": shadow_error,
            "diverged": terminated,
        }
        if not self._shadow:  # the terms and entries that need the shadow tracker
            del info["reward_advantage"], info["reward_squared_advantage"]
            del info["shadow_position_error"]
        return self._obs.copy(), reward, terminated, truncated, info


def restore(core: TrackingCore) -> SoloStep | None:
    """A :class:`SoloStep` of ``core`` where it fits (:meth:`SoloStep.fits`), else None: what an
    unpickled scalar env steps with (a process that registered another reward term steps it
    through the core, with the same numbers)."""
    return SoloStep(core) if SoloStep.fits(core) else None
