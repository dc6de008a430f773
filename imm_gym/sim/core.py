"""The batched simulation behind every environment front (no Gymnasium here).

:class:`TrackingCore` advances N independent episodes in lock-step. Data flows one way:
scenario -> truth -> sonar -> IMM bank(s) (TPM from the action) -> estimate -> reward, observation
and diagnostics. Each episode slot ``i`` owns its two random streams
(:func:`imm_gym.seeding.streams`): slot ``i`` reset with seed ``s`` replays exactly the episode of
a scalar environment reset with seed ``s``, whatever the other slots do — its draws, and on the
compiled engine its numbers bit for bit (a product over the slots is taken row by row where a
batch-wide BLAS call would round by the batch's shape: ``tests/sim/test_batch_independence.py``;
the numpy engine's batched products round by the batch's shape, about 1e-11 m).

The observation is ``[mu(t), mu(t-1)]`` followed by the blocks of ``obs_features``, each
declared once in :mod:`imm_gym.sim.features` (the datasheet table of
:class:`~imm_gym.envs.tpm_adapt.TPMAdaptEnv` is generated from it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.scenarios.segments import true_model_index
from imm_gym.seeding import clone, streams
from imm_gym.sim.actions import action_size, tpm_from_action, validate_action
from imm_gym.sim.bank_step import BankStep
from imm_gym.sim.conditions import Conditions, bank_constants
from imm_gym.sim.detectors import TURN_RATE_FACTOR, TurnRateBelief, model_turn_rates
from imm_gym.sim.engines import choose_engine, compiled_step
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_episodes
from imm_gym.sim.features import FEATURES, bounds, heading_rate
from imm_gym.sim.kernels import step_inputs
from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS, DetectorNetwork, LearnedDetector
from imm_gym.sim.model_order import (
    action_index,
    canonical_order,
    critic_index,
    observation_index,
)
from imm_gym.sim.rewards import REWARD_TERMS, Reward
from imm_gym.sim.stay_bank import StayBank, detector_tpm_rows
from imm_gym.tracking.hetero import make_tracker
from imm_gym.tracking.imm import IMMState
from imm_gym.tracking.models import MotionModel, velocity_noise
from imm_gym.tracking.tpm import stay_tpm_rows, validate_tpm
from imm_gym.validation import ConfigError, check_sequence, store

Array = NDArray[np.float64]


#: What a diverged slot's infinite floats become in the API (NaN becomes 0).
INFINITY_STAND_IN = float(np.finfo(np.float64).max / 4)

#: Bound of every entry of :meth:`TrackingCore.critic_state`.
CRITIC_CLIP = 10.0


def critic_state_size(n_models: int) -> int:
    """Length of :meth:`TrackingCore.critic_state`: two 4-d errors and a one-hot model."""
    return 8 + n_models


@dataclass(frozen=True)
class PairedConfig(EnvConfig):
    """An :class:`EnvConfig` whose tracker runs on another configuration's episodes: a
    randomized family with ``designed_share > 0`` draws its targets for ``design_bank`` (the
    evaluated configuration's bank), not for its own ``bank`` — a policy that brings its own bank
    (``bbsca``'s tuned ``Q``, whose CT models' noise sets the designed turn bands) meets the
    targets every other policy meets, as their pairing assumes
    (:func:`~imm_gym.evaluation.rollout.evaluation_config` builds it).

    It lives in a roll-out only: no file holds one (``design_bank`` is no key of a
    configuration file, so :func:`~imm_gym.sim.config_file.env_config_dict` of it does not build
    again).

    Attributes:
        design_bank: a linear bank, the models the episodes are drawn for; None: ``bank``.
    """

    design_bank: tuple[MotionModel, ...] | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.design_bank is not None:
            bank = check_sequence("design_bank", self.design_bank)
            if not all(isinstance(m, MotionModel) for m in bank):
                raise ConfigError("design_bank must hold MotionModel entries (a linear bank)")
            designed = self.scenario == "random" and self.family.designed_share > 0.0
            if designed and not any(m.kind == "ct" for m in bank):
                raise ConfigError(
                    "family.designed_share needs a design_bank with a CT model (the turns its "
                    "targets are drawn for)"
                )
            store(self, "design_bank", bank)


def design_bank(config: EnvConfig) -> tuple[MotionModel, ...] | None:
    """The models ``config``'s episodes are drawn for (a designed family's turns): a
    :class:`PairedConfig`'s ``design_bank``, else the linear bank (None: a heterogeneous one)."""
    if isinstance(config, PairedConfig) and config.design_bank is not None:
        return config.design_bank
    return config.linear_bank


@dataclass
class StepResult:
    """What one core step returns for all N slots (fresh arrays)."""

    obs: NDArray[np.float32]
    reward: Array
    terminated: NDArray[np.bool_]
    truncated: NDArray[np.bool_]
    info: dict[str, Any]


def checked_reset(
    indices: NDArray[np.int64],
    seeds: list[int | None],
    initial_tpms: Array | None,
    n_envs: int,
    M: int,
) -> tuple[NDArray[np.int64], Array | None]:
    """A reset's slots as an integer array and its ``initial_tpms`` validated, for a core of
    ``n_envs`` slots and ``M`` models (:meth:`TrackingCore.reset`, and the sharded core's before
    any shard resets).

    Raises:
        ConfigError: ``initial_tpms`` not valid TPMs of shape ``(len(indices), M, M)``.
        ValueError: not one seed per slot, or a slot listed twice.
        IndexError: a slot outside ``[0, n_envs - 1]``.
    """
    indices = np.asarray(indices, dtype=np.int64)
    if initial_tpms is not None:
        initial_tpms = validate_tpm(initial_tpms, M, "initial_tpms")
        if initial_tpms.shape != (indices.size, M, M):
            raise ConfigError(
                f"initial_tpms must have shape ({indices.size}, {M}, {M}) (a TPM per slot "
                f"reset), got {initial_tpms.shape}"
            )
    if indices.size == 0:
        return indices, initial_tpms
    if len(seeds) != indices.size:
        raise ValueError(f"{len(seeds)} seeds for {indices.size} slots")
    outside = indices[(indices < 0) | (indices >= n_envs)]
    if outside.size:
        raise IndexError(f"slots must be in [0, {n_envs - 1}], got {outside.tolist()}")
    if np.unique(indices).size != indices.size:
        listed = np.unique(indices, return_counts=True)
        twice = listed[0][listed[1] > 1].tolist()
        raise ValueError(f"slots {twice} listed more than once in one reset: one seed each")
    return indices, initial_tpms


def checked_active(active: NDArray[np.bool_] | None, n_envs: int) -> NDArray[np.bool_] | None:
    """A step's ``active`` as an array after checking it is a boolean mask of the ``n_envs``
    slots (an index array would be read as a mask of other slots), None as given.

    Raises:
        ValueError: naming the shape and dtype received.
    """
    if active is None:
        return None
    active = np.asarray(active)
    if active.dtype != np.bool_ or active.shape != (n_envs,):
        raise ValueError(
            f"active must be a boolean mask of shape ({n_envs},), got {active.dtype} of shape "
            f"{active.shape}"
        )
    return active


class TrackingCore:
    """N TPM-adaptation episodes: truth, sonar, IMM bank A (adapted TPM), optional bank B (fixed
    TPM, entropy fusion with feedback), optional shadow IMM (fixed TPM) for the reward, optional
    stay bank (one classical IMM per stay, :mod:`imm_gym.sim.stay_bank`) for the evidence of
    each switching prior.

    A step: the slots' inputs (:func:`imm_gym.sim.kernels.step_inputs`), all banks advanced by
    the configured engine (:mod:`imm_gym.sim.engines`, a
    :class:`~imm_gym.sim.bank_step.BankStep`), the reward terms (:mod:`imm_gym.sim.rewards`),
    the episode ends, the features' memories and the observation
    (:mod:`imm_gym.sim.features`).

    Args:
        config: the environment configuration.
        n_envs: number of slots N.
    """

    def __init__(self, config: EnvConfig, n_envs: int = 1) -> None:
        if n_envs < 1:
            raise ValueError(f"n_envs must be >= 1, got {n_envs}")
        self.config = config
        self.n_envs = n_envs
        self.models = config.bank
        self.M = M = len(config.bank)
        self.imm = make_tracker(
            config.bank, config.sensor, config.filter, config.source.T, engine=config.engine
        )
        self.n = self.imm.n
        T = config.source.T
        #: ``(N, M, M)`` the slots' initial TPMs (bank B's fixed TPMs) and the shadow IMM's, at
        #: each slot's sampling period (updated in place at a reset with varied conditions)
        self.fixed_tpms = np.repeat(config.initial_tpm(T)[None], n_envs, axis=0)
        self.shadow_tpms = np.repeat(config.shadow_tpm(T)[None], n_envs, axis=0)
        # the configuration's initial TPMs, which a reset's ``initial_tpms`` replace for one
        # episode only
        self._configured_tpms = self.fixed_tpms.copy()
        self._advance = choose_engine(config.engine, self.imm.kernel_args)
        #: the compiled engine's bank constants (``kernel_args`` of the tracker); with
        #: ``config.vary`` one bank per slot, ``F``, ``Q``, ``R`` set at each reset for the
        #: episode's sampling period and sensor (:mod:`imm_gym.sim.conditions`)
        self.kernel_args = self._bank_per_slot() if config.vary.active else self.imm.kernel_args
        needs_bank = (
            config.stay_base in ("evidence", "evidence_best")
            or any(FEATURES[f].needs_stay_bank for f in config.obs_features)
            or REWARD_TERMS[config.reward].needs_stay_bank
        )
        self._reward = Reward(
            config.reward,
            config.shadow == "fixed",
            config.tpm_cost,
            self.shadow_tpms,
            config.mode_reward,
            config.tpm_change_cost,
            stay_bank=needs_bank,
            mode_score=config.mode_score,
        )
        noise = velocity_noise(np.stack(
            [m.noise_covariance(self.n, T) for m in config.bank]
        )) if isinstance(config.bank, tuple) else np.full(M, np.nan)
        #: the stay bank, where the configuration uses its evidence (else None)
        self.stay_bank = StayBank(
            self.imm,
            n_envs,
            self.batch_kernel_args,
            config.detector_share,
            config.stay_grid,
            int(canonical_order(config.bank, noise)[0]),
        ) if needs_bank else None
        #: the ``learned`` detector (:mod:`imm_gym.sim.learned_detector`), else None
        self.learned_detector = LearnedDetector(
            self.imm,
            n_envs,
            self.batch_kernel_args,
            model_turn_rates(config.bank),  # type: ignore[arg-type]
            DetectorNetwork.load(config.detector_weights or DEFAULT_WEIGHTS),
        ) if config.detector == "learned" else None
        self.horizon = config.source.horizon
        #: the models a designed family draws the episodes' targets for (:func:`design_bank`)
        self.design_bank = design_bank(config)
        #: entries of one slot's action: ``M * M``, or ``M`` in the stay modes
        self.action_dim = action_size(config.action_mode, M)
        self.obs_low, self.obs_high = bounds(config.obs_features, M, config.sensor.dim_z)
        self.obs_dim = self.obs_low.size
        #: ``(N,)`` each slot's sampling period (s)
        self.sampling_period = np.full(n_envs, float(config.source.T))
        #: ``(N, M)`` each slot's per-model RMS velocity process noise per step (m/s), from its
        #: ``Q`` (NaN for a heterogeneous bank, whose noise depends on the state)
        self.velocity_noise = np.repeat(noise[None], n_envs, axis=0)
        order = canonical_order(config.bank, noise) if config.model_order == "canonical" else None
        #: the policy's order of the models (:mod:`imm_gym.sim.model_order`): ``order[c]`` is
        #: the bank index of the observation's and the action's model ``c``; None where it is
        #: the bank's own
        self.model_order = None if order is None or (order == np.arange(M)).all() else order
        if self.model_order is not None:
            self._obs_index = observation_index(
                config.obs_features, self.model_order, config.sensor.dim_z
            )
            self._action_index = action_index(self.action_dim, self.model_order)
            self._critic_index = critic_index(critic_state_size(M), self.model_order)
        #: ``(N,)`` RMS position accuracy of each slot's first measurement, ``sqrt(tr P0_pos / 2)``
        self.position_accuracy = np.ones(n_envs)
        N, K, m = n_envs, self.horizon, config.sensor.dim_z
        self._rngs: list[tuple[np.random.Generator, np.random.Generator] | None] = [None] * N
        self.truth = np.zeros((N, K + 1, 4))
        self.z = np.zeros((N, K + 1, m))
        self.detected = np.ones((N, K + 1), dtype=bool)
        self.outlier = np.zeros((N, K + 1), dtype=bool)  # the sensor's inflated draws (pictures)
        self.true_model = np.full((N, K), -1, dtype=np.int64)
        self.k = np.zeros(N, dtype=np.int64)
        self.done = np.ones(N, dtype=bool)
        self.tpm = self.fixed_tpms.copy()
        self.state_a = self._blank_state()
        self.state_b = self._blank_state()
        self.state_s = self._blank_state()
        self.mu = np.full((N, M), 1.0 / M)
        self.mu_prev = self.mu.copy()
        self.mu_b = self.mu.copy()
        self.mu_s = self.mu.copy()
        self.mu_s_prev = self.mu.copy()
        self.cbar = self.mu.copy()
        self.loglik = np.zeros((N, M))
        self.cbar_s = self.mu.copy()
        self.loglik_s = np.zeros((N, M))
        self.model_nis = np.zeros((N, M))
        self.innovation = np.zeros((N, M, m))
        self.velocity = np.zeros((N, 2))  # combined estimates' velocities at t and t-1
        self.velocity_prev = np.zeros((N, 2))
        self.velocity_s = np.zeros((N, 2))  # the same for the shadow IMM
        self.velocity_s_prev = np.zeros((N, 2))
        #: ``(N,)`` the smoothed heading rate of bank A's estimate (rad/s), the ``turn_rate``
        #: detector's (:mod:`imm_gym.sim.detectors`; kept at 0 with another detector)
        self.turn_rate_estimate = np.zeros(N)
        omegas = model_turn_rates(config.bank)
        #: the ``turn_rate`` detector's interpolation between the models' turn rates (None: a
        #: heterogeneous bank, which has no fixed turn rates)
        self._turn_rate_belief = None if omegas is None else TurnRateBelief(omegas)
        #: the observed features' memories (:class:`imm_gym.sim.features.Memory`)
        self._memories = {
            f: FEATURES[f].memory for f in config.obs_features if FEATURES[f].memory is not None
        }
        self.memories = {
            name: np.zeros((N, *memory.shape(M))) for name, memory in self._memories.items()
        }

    @property
    def batch_kernel_args(self) -> tuple | None:
        """The bank constants of the classical IMMs run beside the banks
        (:class:`~imm_gym.sim.imm_batch.IMMBatch`): the compiled engine's, None on the numpy
        engine."""
        return self.kernel_args if self._advance is compiled_step else None

    def _bank_per_slot(self) -> tuple:
        """The tracker's kernel constants with ``F``, ``Q``, ``R`` repeated for every slot."""
        if self.imm.kernel_args is None or self._advance is not compiled_step:
            raise ConfigError(
                "vary needs the compiled engine: a linear bank, a built-in sensor and filter"
            )
        F, Q, R, *rest = self.imm.kernel_args
        N = self.n_envs
        return (*(np.repeat(a, N, axis=0) for a in (F, Q, R)), *rest)

    def _blank_state(self) -> IMMState:
        N, M, n = self.n_envs, self.M, self.n
        return IMMState(
            np.zeros((N, M, n)),
            np.repeat(np.eye(n)[None, None], N * M, 0).reshape(N, M, n, n),
            np.full((N, M), 1.0 / M),
        )

    # ------------------------------------------------------------------ reset
    def reset(
        self,
        indices: NDArray[np.int64],
        seeds: list[int | None],
        initial_tpms: Array | None = None,
    ) -> None:
        """Start new episodes in the slots ``indices`` (one seed or None per slot).

        A slot given a seed gets fresh streams from it; a slot given None continues its streams
        (the next episode of the same sequence), or gets streams from OS entropy if it has none.
        ``initial_tpms`` (``(len(indices), M, M)``, valid TPMs) start these episodes from other
        TPMs than the configuration's (bank B keeps them): the same targets and noise from
        several starting TPMs in one batch (the best fixed TPM's search). A slot outside
        ``[0, n_envs - 1]`` (a negative one too) raises ``IndexError``, a slot listed twice or a
        seed count other than the slots' ``ValueError``, before any slot changes
        (:func:`checked_reset`).
        """
        indices, initial_tpms = checked_reset(indices, seeds, initial_tpms, self.n_envs, self.M)
        if indices.size == 0:
            return
        # slots given the same seed draw the same episode: drawn once (row `rows[p]` of the
        # batch is position p's), the twins' streams cloned after the draws
        twin = _first_of_each_seed(seeds)
        drawn = np.flatnonzero(twin == np.arange(indices.size))
        rows = np.searchsorted(drawn, twin)
        # every seed checked (its streams built) before a slot's streams are replaced: a
        # rejected seed leaves every slot's streams as they were
        rngs = list(self._rngs)
        for i, seed in zip(indices[drawn].tolist(), [seeds[p] for p in drawn], strict=True):
            if seed is not None:
                rngs[i] = streams(seed)
            elif rngs[i] is None:
                rngs[i] = streams(int(np.random.SeedSequence().generate_state(1)[0]))
        self._rngs = rngs
        scen_rngs = [self._rngs[i][0] for i in indices[drawn]]  # type: ignore[index]
        noise_rngs = [self._rngs[i][1] for i in indices[drawn]]  # type: ignore[index]
        cfg = self.config
        batch = draw_episodes(
            cfg.source, cfg.sensor, scen_rngs, noise_rngs, cfg.velocity_std, cfg.vary,
            self.design_bank,
        )
        for p in np.flatnonzero(twin != np.arange(indices.size)).tolist():
            scenario, noise = self._rngs[indices[twin[p]]]  # type: ignore[misc]
            self._rngs[indices[p]] = (clone(scenario), clone(noise))
        truth, meas = batch.truth, batch.measurements
        if batch.conditions is not None:
            self._set_conditions(indices, batch.conditions.take(rows))
        # the configuration's TPM unless told otherwise (also after a start from other TPMs)
        self.fixed_tpms[indices] = (
            self._configured_tpms[indices] if initial_tpms is None else initial_tpms
        )
        self.truth[indices] = truth.states[rows]
        self.z[indices] = meas.z[rows]
        self.detected[indices] = meas.detected[rows]
        self.outlier[indices] = meas.outlier[rows]
        self.true_model[indices] = true_model_index(truth, self.models)[rows]
        self._start(indices, batch.x0[rows], batch.P0[rows])

    def _set_conditions(self, indices: NDArray[np.int64], conditions: Conditions) -> None:
        """The slots ``indices`` at their episodes' conditions: their ``F (M, n, n)``, ``Q`` for
        their ``T`` and process-noise factors, their ``R``."""
        F, Q = bank_constants(
            self.models, conditions.T, conditions.q_scale, conditions.q_maneuver
        )
        self.kernel_args[0][indices] = F
        self.kernel_args[1][indices] = Q
        self.kernel_args[2][indices] = conditions.R
        self.sampling_period = self.sampling_period.copy()
        self.sampling_period[indices] = conditions.T
        self.velocity_noise = self.velocity_noise.copy()
        self.velocity_noise[indices] = velocity_noise(Q)
        if self.config.sojourn is not None and self.config.vary.T is not None:
            for i, T in zip(indices, conditions.T, strict=True):
                self._configured_tpms[i] = self.config.initial_tpm(T)
                self.shadow_tpms[i] = self.config.shadow_tpm(T)

    def reset_info(self, indices: NDArray[np.int64]) -> dict[str, Array]:
        """The reset info of the slots ``indices`` (new arrays, a row per slot): ``true_state``,
        each episode's first true state, and ``tpm``, the TPM it starts from."""
        indices = np.asarray(indices, dtype=np.int64)
        return {"true_state": self.truth[indices, 0], "tpm": self.tpm[indices]}

    def streams(self) -> list[tuple[np.random.Generator, np.random.Generator] | None]:
        """Each slot's ``(scenario, noise)`` generators (None for a slot never reset): the
        sequence of episodes a slot reset without a seed continues (what a checkpoint records)."""
        return list(self._rngs)

    def set_streams(
        self, generators: list[tuple[np.random.Generator, np.random.Generator]]
    ) -> None:
        """Give every slot its ``(scenario, noise)`` generators: its next reset without a seed
        draws from them (a checkpoint's slots continue where they were)."""
        if len(generators) != self.n_envs:
            raise ValueError(f"{len(generators)} stream pairs for {self.n_envs} slots")
        self._rngs = list(generators)

    def _start(self, indices: NDArray[np.int64], x0: Array, P0: Array) -> None:
        """Start the slots ``indices`` from the estimate ``x0 (n, 4)``, ``P0 (n, 4, 4)``: every
        bank at it with the tracker's initial probabilities (uniform for a linear bank, a
        heterogeneous bank's ``initial_probs``), the TPM at the fixed one, the features'
        quantities and memories at their start (copy-on-write: arrays handed out earlier, in
        infos, do not change under the caller)."""
        init = self.imm.init(x0, P0)
        self.position_accuracy = self.position_accuracy.copy()
        self.position_accuracy[indices] = np.sqrt(0.5 * (P0[:, 0, 0] + P0[:, 1, 1]))
        for bank in ("state_a", "state_b", "state_s"):
            state = getattr(self, bank)
            parts = [a.copy() for a in (state.x, state.P, state.mu)]
            for a, value in zip(parts, (init.x, init.P, init.mu), strict=True):
                a[indices] = value
            setattr(self, bank, IMMState(*parts))
        values = {
            "tpm": self.fixed_tpms[indices],
            "mu": init.mu,
            "mu_prev": init.mu,
            "mu_b": init.mu,
            "mu_s": init.mu,
            "mu_s_prev": init.mu,
            "cbar": init.mu,
            "loglik": 0.0,
            "cbar_s": init.mu,
            "loglik_s": 0.0,
            "model_nis": 0.0,
            "innovation": 0.0,
            "velocity": x0[:, 2:4],
            "velocity_prev": x0[:, 2:4],
            "velocity_s": x0[:, 2:4],
            "velocity_s_prev": x0[:, 2:4],
            "turn_rate_estimate": 0.0,
            "k": 0,
            "done": False,
        }
        for name, value in values.items():
            array = getattr(self, name).copy()
            array[indices] = value
            setattr(self, name, array)
        for name, memory in self._memories.items():
            state = self.memories[name].copy()
            state[indices] = memory.initial(init.mu)
            self.memories[name] = state
        if self.stay_bank is not None:
            self.stay_bank.start(indices, init, self.kernel_args)
        if self.learned_detector is not None:
            self.learned_detector.start(indices, init, self.kernel_args)

    @property
    def reward_scale(self) -> float | Array:
        """Metres per unit of reward: ``EnvConfig.reward_scale``, or each slot's first-measurement
        accuracy ``(N,)`` with ``reward_scale="measurement"``."""
        scale = self.config.reward_scale
        return self.position_accuracy if scale == "measurement" else scale  # type: ignore[return-value]

    @property
    def stay_base_tpms(self) -> Array:
        """``(N, M, M)`` the TPMs the ``stay`` action moves from: the slots' own (bank B's; with
        ``detector_share``, their stays, at least 1/M), or a stay on each row's diagonal and the
        rest of the row spread evenly (``stay_base="evidence"``: the stay bank's
        :meth:`~imm_gym.sim.stay_bank.StayBank.centre`, ``"evidence_best"``: its
        :meth:`~imm_gym.sim.stay_bank.StayBank.best`, ``"uniform"``: 1/M) — with
        ``detector_share``, that share of the jumps placed by the :attr:`detector_belief`
        (:func:`imm_gym.sim.stay_bank.detector_tpm_rows`)."""
        base = self.config.stay_base
        if base == "tracker" and self.config.detector_share == 0.0:
            return self.fixed_tpms
        if base == "tracker":  # the detector's rows take stays of at least 1/M
            stays = np.maximum(np.diagonal(self.fixed_tpms, axis1=-2, axis2=-1), 1.0 / self.M)
        elif base == "uniform":
            stays = np.full(self.n_envs, 1.0 / self.M)
        elif base == "evidence":
            stays = self.stay_bank.centre()  # type: ignore[union-attr]
        else:
            stays = self.stay_bank.best()  # type: ignore[union-attr]
        if self.config.detector_share > 0.0:
            return detector_tpm_rows(stays, self.detector_belief, self.config.detector_share)
        return stay_tpm_rows(stays, self.M)

    @property
    def detector_belief(self) -> Array:
        """``(N, M)`` the maneuver detector's belief (``EnvConfig.detector``,
        :mod:`imm_gym.sim.detectors`): the shadow IMM's mode probabilities, the smoothed
        turn rate of bank A's estimate interpolated between the models' turn rates, or the
        learned detector's belief."""
        if self.config.detector == "shadow":
            return self.mu_s
        if self.learned_detector is not None:
            return self.learned_detector.belief
        return self._turn_rate_belief(self.turn_rate_estimate)  # type: ignore[misc]

    @property
    def stay_bank_evidence(self) -> Array:
        """``(N, S)`` the stay bank's evidence for each single stay minus the best prior's
        (nats; the pairs of ``stay_grid="pairs"`` are not observed)."""
        bank = self.stay_bank
        return bank.relative()[:, : bank.n_single]  # type: ignore[union-attr]

    # ------------------------------------------------------------------ actions
    def tpm_from_action(self, action: NDArray[Any], tpm: Array | None = None) -> Array:
        """The TPMs an action ``(N, action_dim)`` produces from ``tpm`` (default: the current
        TPMs) and the slots' own TPMs, :func:`imm_gym.sim.actions.tpm_from_action`."""
        return tpm_from_action(self.validate_action(action), self.tpm if tpm is None else tpm,
                               self.config, self.stay_base_tpms)

    def check_action(self, action: NDArray[Any]) -> Array:
        """Validate shape ``(N, action_dim)`` and finiteness, then clip to [-1, 1] (float64)."""
        return np.clip(self.validate_action(action), -1.0, 1.0)

    def validate_action(self, action: NDArray[Any]) -> Array:
        """``action`` as a C-contiguous float64 array after checking shape ``(N, action_dim)``
        and finiteness (not clipped), its entries in the bank's order of the models."""
        a = validate_action(action, self.n_envs, self.action_dim)
        if self.model_order is None:
            return a
        return np.ascontiguousarray(a[:, self._action_index])  # indexed columns: Fortran order

    # ------------------------------------------------------------------ step
    def step(self, action: NDArray[Any], active: NDArray[np.bool_] | None = None) -> StepResult:
        """Advance the ``active`` slots (all by default) one step with their actions.

        Inactive slots keep their state (their outputs in the result are meaningless: the vector
        fronts mask them). An active slot whose episode ended must be reset first.

        Raises:
            ValueError: ``active`` not a boolean mask of shape ``(n_envs,)`` (an index array
                would be read as a mask of other slots).
        """
        active = checked_active(active, self.n_envs)
        all_active = active is None or bool(np.asarray(active).all())
        # np.count_nonzero, not ndarray.any: a C call, several times cheaper on small arrays
        if np.count_nonzero(self.done if active is None else self.done & active):
            ended = np.flatnonzero(self.done if active is None else self.done & active).tolist()
            raise RuntimeError(f"episodes in slots {ended} have ended; call reset before step")
        before = None if all_active else self._snapshot()
        cfg = self.config
        k1, step, z, det, truth, true_model = step_inputs(
            self.k, self.horizon, self.z, self.detected, self.truth, self.true_model
        )
        out = self._advance_banks(self.validate_action(action), z, det, truth)
        info: dict[str, Any] = {
            "true_state": truth,
            "true_model": true_model,
            "estimate": out.estimate,
            "covariance": out.covariance,
            "position_error": out.position_error,
            "mode_probs": out.mode_probs.copy(),
            "loglik": out.loglik.copy(),
            "model_nis": out.model_nis.copy(),
            "nis": out.nis,
            "detected": det,
            "tpm": out.tpm.copy(),
            "step": step,
        }
        bank_error = None
        if self._reward.needs_stay_bank:
            bank_error = self.stay_bank.position_error(  # type: ignore[union-attr]
                truth[:, :2], cfg.divergence_error
            )
            info["stay_bank_position_error"] = bank_error
        reward, terms = self._reward(out, self.reward_scale, true_model, self.tpm, bank_error)
        info.update(terms)
        if cfg.shadow == "fixed":
            info["shadow_position_error"] = out.shadow_position_error
        info["diverged"] = diverged = out.diverged
        self._record(out, k1)
        truncated = (k1 >= self.horizon) & ~diverged
        self.done = diverged | truncated
        if before is not None:
            self._restore(before, ~np.asarray(active, dtype=bool))
        if np.count_nonzero(diverged):  # only a diverged slot can carry NaN/inf
            info = {key: _finite(value) for key, value in info.items()}
        # terminated a copy: a front that rewrites it (an autoreset row) must not move the info
        return StepResult(self.observe(), reward, diverged.copy(), truncated, info)

    def _advance_banks(
        self, action: Array, z: Array, detected: NDArray[np.bool_], truth: Array
    ) -> BankStep:
        """The banks' step by the engine, then the stay bank's on the same measurements (at the
        detector's belief before the step), then the learned detector's."""
        out = self._advance(self, action, z, detected, truth)
        bank_a = IMMState(out.x_a, out.P_a, out.mode_probs)
        if self.stay_bank is not None:
            self.stay_bank.step(z, detected, bank_a, self.detector_belief)
        if self.learned_detector is not None:
            self.learned_detector.step(z, detected, bank_a, self.sampling_period)
        return out

    def _record(self, out: BankStep, k: NDArray[np.int64]) -> None:
        """Take the banks' step ``out`` as every slot's state at step ``k``: the banks'
        posteriors (bank A's and B's probabilities are the fused ``U``), the quantities the
        features read, and the features' memories advanced."""
        cfg = self.config
        self.state_a = IMMState(out.x_a, out.P_a, out.mode_probs)
        if cfg.parallel:
            self.state_b = IMMState(out.x_b, out.P_b, out.mode_probs)
            self.mu_b = out.mu_b
        if cfg.shadow == "fixed":
            self.state_s = IMMState(out.x_s, out.P_s, out.mu_s)
            self.mu_s_prev, self.mu_s = self.mu_s, out.mu_s
            self.cbar_s, self.loglik_s = out.cbar_s, out.loglik_s
            self.velocity_s_prev, self.velocity_s = self.velocity_s, out.velocity_s
        self.k = k
        self.tpm = out.tpm
        self.mu_prev = self.mu
        self.mu = out.mode_probs
        self.cbar = out.cbar
        self.loglik = out.loglik
        self.model_nis = out.model_nis
        self.innovation = out.innovation
        self.velocity_prev, self.velocity = self.velocity, out.velocity
        if cfg.detector == "turn_rate":
            rate = heading_rate(self.velocity_prev, self.velocity, self.sampling_period)
            self.turn_rate_estimate = (
                TURN_RATE_FACTOR * self.turn_rate_estimate + (1.0 - TURN_RATE_FACTOR) * rate
            )
        self._update_memories()

    _SLOT_ARRAYS = (
        "k",
        "done",
        "tpm",
        "mu",
        "mu_prev",
        "mu_b",
        "mu_s",
        "mu_s_prev",
        "cbar",
        "loglik",
        "cbar_s",
        "loglik_s",
        "model_nis",
        "innovation",
        "velocity",
        "velocity_prev",
        "velocity_s",
        "velocity_s_prev",
        "turn_rate_estimate",
    )

    def _snapshot(self) -> dict[str, Any]:
        snap: dict[str, Any] = {name: getattr(self, name) for name in self._SLOT_ARRAYS}
        for bank in ("state_a", "state_b", "state_s"):
            snap[bank] = getattr(self, bank)
        snap["memories"] = dict(self.memories)
        if self.stay_bank is not None:
            snap["stay_bank"] = self.stay_bank.snapshot()
        if self.learned_detector is not None:
            snap["learned_detector"] = self.learned_detector.snapshot()
        return snap

    def _restore(self, snap: dict[str, Any], rows: NDArray[np.bool_]) -> None:
        """Put back the pre-step values of the slots ``rows``."""
        for name in self._SLOT_ARRAYS:
            new = getattr(self, name)
            if new is not snap[name]:
                new = new.copy()
                new[rows] = snap[name][rows]
                setattr(self, name, new)
        for bank in ("state_a", "state_b", "state_s"):
            new, old = getattr(self, bank), snap[bank]
            if new is not old:
                parts = []
                for a_new, a_old in ((new.x, old.x), (new.P, old.P), (new.mu, old.mu)):
                    a_new = a_new.copy()
                    a_new[rows] = a_old[rows]
                    parts.append(a_new)
                setattr(self, bank, IMMState(*parts))
        for name, old in snap["memories"].items():
            new = self.memories[name]
            if new is not old:
                new = new.copy()
                new[rows] = old[rows]
                self.memories[name] = new
        if self.stay_bank is not None:
            self.stay_bank.restore(snap["stay_bank"], rows)
        if self.learned_detector is not None:
            self.learned_detector.restore(snap["learned_detector"], rows)

    def _update_memories(self) -> None:
        """Advance the observed features' memories by one step."""
        for name, memory in self._memories.items():
            self.memories[name] = memory.advance(self.memories[name], self)

    # ------------------------------------------------------------------ observation
    def observe(self) -> NDArray[np.float32]:
        """The observation of every slot (see the module docstring for the layout)."""
        blocks = [self.mu, self.mu_prev]
        blocks += [FEATURES[f].observe(self) for f in self.config.obs_features]
        obs = np.concatenate(blocks, axis=-1)
        if self.model_order is not None:
            obs = obs[:, self._obs_index]
        if np.count_nonzero(np.isfinite(obs)) != obs.size:  # a diverged slot
            obs = np.nan_to_num(obs, nan=0.0, posinf=1.0, neginf=-1.0)
        obs = obs.astype(np.float32)
        np.maximum(obs, self.obs_low, out=obs)  # clip to the Box (ufuncs: no wrapper overhead)
        return np.minimum(obs, self.obs_high, out=obs)

    def critic_state(self) -> NDArray[np.float32]:
        """Ground truth for a critic that is trained but never acts (asymmetric actor-critic):
        per slot, the combined estimate's error ``x̂ - x`` (position / 50 m, velocity / 5 m/s),
        the same for the reward's baseline — the stay bank's IMMs' estimates weighted by their
        evidence under the ``bank_advantage`` reward, else the shadow's estimate (zeros without
        a shadow) —, and the true model of the coming step, one-hot (all zeros where no model
        of the bank matches the motion: ``true_model`` -1); clipped to
        ``[-CRITIC_CLIP, CRITIC_CLIP]``.

        The return of a step depends on how far each tracker is off the target now and on the
        maneuver to come, which no observation reveals; a value function that sees them
        predicts returns with less noise. Policies must not act on it (SPEC §5).
        """
        rows = np.arange(self.n_envs)
        truth = self.truth[rows, self.k, :4]
        scale = np.array([50.0, 50.0, 5.0, 5.0])
        # position and velocity: the first four entries of a bank's common state (6 with CA)
        estimate = self.imm.combine(self.mu, self.state_a.x, self.state_a.P)[0]
        blocks = [(estimate[:, :4] - truth) / scale]
        if REWARD_TERMS[self.config.reward].needs_stay_bank:
            bank = self.stay_bank  # type: ignore[union-attr]
            estimate_b = np.einsum("rs,rsi->ri", bank.posterior_weights(), bank.estimates())
            blocks.append((estimate_b[:, :4] - truth) / scale)
        elif self.config.shadow == "fixed":
            estimate_s = self.imm.combine(self.mu_s, self.state_s.x, self.state_s.P)[0]
            blocks.append((estimate_s[:, :4] - truth) / scale)
        else:
            blocks.append(np.zeros((self.n_envs, 4)))
        coming = self.true_model[rows, np.minimum(self.k, self.horizon - 1)]
        # one-hot; a row of zeros where no bank model matches the motion (true model -1)
        blocks.append((coming[:, None] == np.arange(self.M)).astype(np.float64))
        out = np.clip(np.concatenate(blocks, axis=-1), -CRITIC_CLIP, CRITIC_CLIP)
        if self.model_order is not None:
            out = out[:, self._critic_index]
        return np.nan_to_num(out).astype(np.float32)


def _finite(value: Any) -> Any:
    """Non-finite floats (a diverged slot) replaced by finite stand-ins for the API."""
    if isinstance(value, np.ndarray) and value.dtype.kind == "f":
        return np.nan_to_num(value, nan=0.0, posinf=INFINITY_STAND_IN, neginf=-INFINITY_STAND_IN)
    return value


def _first_of_each_seed(seeds: list[int | None]) -> NDArray[np.intp]:
    """For each position of ``seeds``, the first position given the same integer seed (its own
    for None — a slot that continues its own streams shares them with no other — and for
    anything but an integer, which :func:`~imm_gym.seeding.streams` then refuses)."""
    first: dict[int, int] = {}
    twin = np.arange(len(seeds))
    for p, seed in enumerate(seeds):
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            twin[p] = first.setdefault(int(seed), p)
    return twin
