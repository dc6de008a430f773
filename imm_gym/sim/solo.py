r"""The scalar env's step as one compiled call on state that stays in a few arrays.

:class:`~imm_gym.sim.core.TrackingCore` is built for N slots: each step it hands the compiled
banks' results (:func:`imm_gym.sim.kernels.env_step`) back to Python as fresh arrays and
computes the reward, the episode ends, the records and the observation with numpy. At N = 1
those small-array operations, not the arithmetic, are the step's cost. :class:`SoloStep` keeps
one slot's state — the three banks, the TPM, the step counter and every quantity the core
records — in eight arrays that :func:`solo_step` advances in place, and returns the observation
and the info from two buffers that the call fills:

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
:func:`~imm_gym.tracking.kernels.imm.imm_step_one`'s shape, no observation feature, no stay
bank, the built-in reward terms only and none of the reward's TPM or mode terms
(``tpm_cost``, ``tpm_change_cost``, ``mode_reward``: their ``log`` is numpy's vectorized one in the
core, which rounds differently from the scalar ``log`` compiled code calls) —
:meth:`SoloStep.fits`; the scalar env runs every other configuration through the core.
"""

from __future__ import annotations

import operator
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.actions import ActionError
from imm_gym.sim.core import INFINITY_STAND_IN, TrackingCore
from imm_gym.sim.kernels import ACTION_MODE_CODES, env_step_body, step_inputs
from imm_gym.sim.rewards import REWARD_TERMS
from imm_gym.tracking.imm import IMMState
from imm_gym.tracking.kernels.imm import fits_one

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

#: The info entries, in the core's order: name and kind (``"vector"``, ``"matrix"``, ``"float"``,
#: ``"int"``, ``"bool"``); their offsets in the info buffer are :func:`info_offsets`'.
INFO_ENTRIES = (
    ("true_state", "vector"), ("true_model", "int"), ("estimate", "vector"),
    ("covariance", "matrix"), ("position_error", "float"), ("mode_probs", "vector"),
    ("loglik", "vector"), ("model_nis", "vector"), ("nis", "float"), ("detected", "bool"),
    ("tpm", "matrix"), ("step", "int"), ("reward_error", "float"),
    ("reward_advantage", "float"), ("reward_squared_advantage", "float"),
    ("shadow_position_error", "float"), ("diverged", "bool"),
)
(TRUE_STATE, TRUE_MODEL, ESTIMATE, COVARIANCE, POSITION_ERROR, MODE_PROBS, LOGLIK_INFO,
 MODEL_NIS_INFO, NIS, DETECTED, TPM, STEP, REWARD_ERROR, REWARD_ADVANTAGE,
 REWARD_SQUARED_ADVANTAGE, SHADOW_POSITION_ERROR, DIVERGED) = range(len(INFO_ENTRIES))

def info_offsets(d: int, n: int, M: int) -> NDArray[np.int64]:
    """Where each entry of :data:`INFO_ENTRIES` starts in the info buffer (the last: its
    length), for a ``d``-dimensional true state, ``n`` states and ``M`` models."""
    sizes = {"true_state": d, "estimate": n, "covariance": n * n, "mode_probs": M, "loglik": M,
             "model_nis": M, "tpm": M * M}
    return np.cumsum([0] + [sizes.get(name, 1) for name, _ in INFO_ENTRIES]).astype(np.int64)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def solo_step(
    action: Array, x: Array, P: Array, per_model: Array, velocities: Array, innovation: Array,
    tpm: Array, k: NDArray[np.int64], done: NDArray[np.bool_], z: Array,
    detected: NDArray[np.bool_], truth: Array, true_model: NDArray[np.int64], fixed_tpm: Array,
    shadow_tpm: Array, bank: tuple,
    settings: Array, at: NDArray[np.int64], obs_low: NDArray[np.float32],
    obs_high: NDArray[np.float32], obs: NDArray[np.float32], info: Array,
) -> tuple[float, bool, bool, bool]:  # pragma: no cover
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
        bank: the tracker's kernel constants; settings: the configuration (:data:`MODE` ...).
        at: :func:`info_offsets`; obs_low, obs_high: the observation's box.
        obs, info: filled with the observation and the info entries.

    Returns:
        ``(reward, terminated, truncated, finite)``; ``finite`` False (a NaN or inf in the
        action) leaves everything untouched.
    """
    for value in action:
        if not np.isfinite(value):
            return 0.0, False, False, False
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
        fixed_tpm, shadow_tpm, fixed_tpm, z_k, det, truth_k, bank, parallel, shadow,
        settings[DIVERGENCE_ERROR], settings[DIVERGENCE_COV], True)
    # the reward (rewards.Reward)
    s = settings[SCALE]
    e = out.position_error[0]
    e_s = out.shadow_position_error[0]
    terms = (e / -s, (e_s - e) / s, (e_s * e_s - e * e) / settings[SCALE2])
    reward = terms[int(settings[REWARD])]
    diverged = out.diverged[0]
    truncated = k1 >= K and not diverged
    # the info
    for i in range(truth_k.shape[1]):
        info[at[TRUE_STATE] + i] = truth_k[0, i]
    info[at[TRUE_MODEL]] = j_star
    n = out.estimate.shape[1]
    for i in range(n):
        info[at[ESTIMATE] + i] = out.estimate[0, i]
        for c in range(n):
            info[at[COVARIANCE] + i * n + c] = out.covariance[0, i, c]
    info[at[POSITION_ERROR]] = e
    for i in range(M):
        info[at[MODE_PROBS] + i] = out.mode_probs[0, i]
        info[at[LOGLIK_INFO] + i] = out.loglik[0, i]
        info[at[MODEL_NIS_INFO] + i] = out.model_nis[0, i]
        for c in range(M):
            info[at[TPM] + i * M + c] = out.tpm[0, i, c]
    info[at[NIS]] = out.nis[0]
    info[at[DETECTED]] = det[0]
    info[at[STEP]] = k1
    info[at[REWARD_ERROR]] = terms[0]
    info[at[REWARD_ADVANTAGE]] = terms[1]
    info[at[REWARD_SQUARED_ADVANTAGE]] = terms[2]
    info[at[SHADOW_POSITION_ERROR]] = e_s
    info[at[DIVERGED]] = diverged
    if diverged:  # core._finite: the API's stand-ins for non-finite floats
        for i in range(info.size):
            if np.isnan(info[i]):
                info[i] = 0.0
            elif np.isinf(info[i]):
                info[i] = INFINITY_STAND_IN if info[i] > 0.0 else -INFINITY_STAND_IN
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
    return reward, diverged, truncated, True

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
        self._at = info_offsets(d, n, M)
        self._obs = np.zeros(core.obs_dim, dtype=np.float32)
        self._info = np.zeros(int(self._at[-1]))
        self._action_shape = (core.action_dim,)
        keys = [name for name, _ in INFO_ENTRIES[:REWARD_ERROR]]
        keys += [f"reward_{t}" for t in REWARD_CODES if cfg.shadow == "fixed" or t == "error"]
        if cfg.shadow == "fixed":
            keys.append("shadow_position_error")
        keys.append("diverged")
        index = {name: (i, kind) for i, (name, kind) in enumerate(INFO_ENTRIES)}
        starts = [int(self._at[index[key][0]]) for key in keys]
        #: the info's keys in the core's order, each read first as the float at its start
        self._keys = tuple(keys)
        self._pick = operator.itemgetter(*starts)
        shapes = {"covariance": (n, n), "tpm": (M, M)}
        #: then the array entries as views of the step's buffer, the integer and boolean ones
        spans = {key: (start, int(self._at[index[key][0] + 1])) for key, start in zip(
            keys, starts, strict=True)}
        self._vectors = tuple((key, *spans[key]) for key in keys if index[key][1] == "vector")
        self._matrices = tuple(
            (key, *spans[key], shapes[key]) for key in keys if index[key][1] == "matrix"
        )
        self._ints = tuple(key for key in keys if index[key][1] == "int")
        self._bools = tuple(key for key in keys if index[key][1] == "bool")
        self._args: tuple = ()

    @staticmethod
    def fits(core: TrackingCore) -> bool:
        """Whether the core's whole step is :func:`solo_step`'s: one slot, the compiled engine
        on a tracker of ``imm_step_one``'s shape, no observation feature, no stay bank, and the
        reward registry holding the built-in terms only."""
        cfg = core.config
        return (
            core.n_envs == 1
            and cfg.engine != "numpy"
            and core.imm.kernel_args is not None
            and fits_one(1, core.M, core.n, cfg.sensor.dim_z)
            and not cfg.obs_features
            and core.stay_bank is None
            and tuple(REWARD_TERMS) == tuple(REWARD_CODES)
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
        scale = core.reward_scale
        self._settings[SCALE] = np.asarray(scale).reshape(-1)[0]
        self._settings[SCALE2] = np.asarray(scale**2).reshape(-1)[0]  # as the core squares it
        self._args = (
            self._x, self._P, self._per_model, self._velocities, self._innovation, self._tpm,
            self._k, self._done, core.z, core.detected, core.truth, core.true_model,
            core.fixed_tpms, core.shadow_tpms, core.kernel_args, self._settings, self._at,
            core.obs_low, core.obs_high, self._obs, self._info,
        )

    def step(
        self, action: NDArray[Any]
    ) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """One step: ``(obs, reward, terminated, truncated, info)``, fresh objects, the info's
        numbers as Python scalars and its arrays views of one fresh buffer."""
        a = np.array(action, dtype=np.float64)  # a fresh C-contiguous copy: one compiled variant
        if a.shape != self._action_shape:
            raise ActionError(f"action must have shape {self._action_shape}, got {a.shape}")
        if self._core.k is not self._k:  # the core was reset or stepped by itself
            self.load(self._core)
        if self._done[0]:
            raise RuntimeError("episodes in slots [0] have ended; call reset before step")
        reward, terminated, truncated, finite = solo_step(a, *self._args)
        if not finite:
            raise ActionError("action must be finite (got NaN or inf)")
        values = self._info.copy()
        info: dict[str, Any] = dict(zip(self._keys, self._pick(values.tolist()), strict=True))
        for key, start, end in self._vectors:
            info[key] = values[start:end]
        for key, start, end, shape in self._matrices:
            info[key] = values[start:end].reshape(shape)
        for key in self._ints:
            info[key] = int(info[key])
        for key in self._bools:
            info[key] = info[key] != 0.0
        return self._obs.copy(), reward, terminated, truncated, info
