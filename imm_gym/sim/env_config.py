"""Configuration of the TPM-adaptation environments (frozen, typed, validated).

Pass an :class:`EnvConfig`, a dict (``gymnasium.make(id, config={...})``) or keyword arguments
(``gymnasium.make(id, parallel=True)``); unknown keys and out-of-range values raise
:class:`~imm_gym.validation.ConfigError` naming the field.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.scenarios.catalog import SCENARIOS
from imm_gym.scenarios.segments import RandomFamily, Scenario, TruthSource
from imm_gym.sim.conditions import Variation, check_variation
from imm_gym.sim.detectors import DETECTORS, model_turn_rates
from imm_gym.sim.features import FEATURES, shadow_features
from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS, DetectorNetwork, turn_rate_order
from imm_gym.sim.model_order import MODEL_ORDERS
from imm_gym.sim.rewards import MODE_SCORES, REWARD_TERMS
from imm_gym.tracking.filters import FILTERS
from imm_gym.tracking.hetero import HeteroBank
from imm_gym.tracking.initiation import MAX_VELOCITY_STD, MIN_VELOCITY_STD
from imm_gym.tracking.models import MotionModel, paper_bank
from imm_gym.tracking.sensors import Sonar
from imm_gym.tracking.tpm import MAX_T_OVER_SOJOURN, stay_tpm, tpm_from_sojourn
from imm_gym.validation import (
    ConfigError,
    check_choice,
    check_range,
    check_sequence,
    from_dict,
    shown,
    store,
)

ACTION_MODES = ("scale", "set", "stay", "stay_step")
SHADOWS = ("fixed", "none")
STAY_BASES = ("tracker", "evidence", "evidence_best", "uniform")
#: The stay bank's grids (:func:`imm_gym.sim.stay_bank.grid_stays`): one stay for every row, or
#: also the per-model pairs.
STAY_GRIDS = ("stays", "pairs")
ENGINES = ("auto", "compiled", "numpy")
#: The built-in optional observation blocks (the registry, :data:`imm_gym.sim.features.FEATURES`,
#: is what ``obs_features`` is checked against).
OBS_FEATURES = tuple(FEATURES)
#: The built-in observation features computed from the shadow IMM (they need ``shadow="fixed"``).
SHADOW_FEATURES = shadow_features()
#: The per-episode reward scales ``reward_scale`` may name instead of a number of metres.
REWARD_SCALES = ("measurement",)
#: The least number of metres ``reward_scale`` may be (a micrometre): far below any tracker's
#: accuracy, far enough above the floats' underflow that ``reward_scale²`` is never 0.
MIN_REWARD_SCALE = 1e-6

Array = NDArray[np.float64]


def _bank_model(i: int, model: Any) -> Any:
    """Entry ``i`` of a linear bank: a mapping becomes a :class:`MotionModel`, whose errors are
    prefixed with ``bank[i]`` (``bank[1]: model.intensity must be in (0.0, inf), got -1``)."""
    if not isinstance(model, Mapping):
        return model
    try:
        return from_dict(MotionModel, model, f"bank[{i}]")
    except ConfigError as err:
        message = str(err)
        if message.startswith(f"bank[{i}]"):
            raise
        raise ConfigError(f"bank[{i}]: {message}") from None


@dataclass(frozen=True)
class EnvConfig:
    """Everything that defines a TPM-adaptation environment.

    Attributes:
        scenario: ``"random"`` (the randomized family), a named scenario of
            :data:`imm_gym.scenarios.catalog.SCENARIOS` (``"paper"``: SPEC §3) or a
            :class:`~imm_gym.scenarios.segments.Scenario`.
        family: the randomized family's parameters (used when ``scenario == "random"``).
        sensor: the sonar (noise, position, outliers, missed detections).
        vary: ranges of the conditions each episode draws for itself — sampling period, sensor
            noise, outlier and detection probabilities (:class:`~imm_gym.sim.conditions.
            Variation`; nothing varies by default). Needs the compiled engine and a linear bank;
            a varied ``T`` needs ``scenario="random"`` and continuous-time process noise.
        bank: the motion models of the IMM bank, or a
            :class:`~imm_gym.tracking.hetero.HeteroBank` (or a mapping of its fields): seed 002's
            NCV/CT/CTRA models in their own state spaces (needs ``filter="ekf"``).
        filter: ``"ukf"`` (SVD-UKF), ``"ukf-cholesky"`` (the UKF with Cholesky sigma points:
            faster, not the paper's) or ``"ekf"``.
        initial_stay: diagonal of the initial (and fixed-bank) TPM, one stay for every model or
            one per model; each row's off-diagonal entries equal
            (:func:`~imm_gym.tracking.tpm.stay_tpm`).
        sojourn: mean sojourn time of each model (s), or None: the initial (and fixed-bank) TPM
            is then ``exp(A T)`` of the continuous-time chain with these sojourns
            (:func:`~imm_gym.tracking.tpm.tpm_from_sojourn`), for each episode's ``T``, in place
            of ``initial_stay``; the shadow's too unless ``shadow_stay`` is set.
        p_min: every TPM an action produces has its entries in ``[p_min, 1 - p_min]`` (< 1/M).
            The initial TPM is used as configured: with ``p_min`` at most its smallest entry the
            zero ``scale`` action keeps it (classical IMM); TIP-IMM's floor 0.05 (SPEC §6) lies
            above the paper TPM's 0.0025, so there the first action already floors it.
        action_mode: ``"scale"`` (per-entry factors ``max_factor ** a`` on the current TPM),
            ``"set"`` (row logits ``logit_scale * a``, softmax per row), ``"stay"`` (``M``
            entries: each row's stay probability ``logit_scale * a`` logits from the initial
            TPM's, the row's switching structure kept) or ``"stay_step"`` (the same, each step
            from the current TPM's stays; :mod:`imm_gym.sim.actions`); in both stay modes a
            stay is kept in ``[min(1/M, initial stay), 1 - (M - 1) p_min]``.
        stay_base: the TPM the ``stay`` mode moves from: ``"tracker"`` (the tracker's own,
            bank B's) or ``"evidence"`` (each step, the stay the measurements support so far:
            the evidence-weighted stay of the stay bank, one classical IMM per stay,
            :mod:`imm_gym.sim.stay_bank`; the zero action then selects the switching prior by
            its evidence), or ``"evidence_best"`` (the stay of the stay bank's IMM with the
            largest evidence), or ``"uniform"`` (the stay ``1/M``: with ``detector_share`` the
            prior the detector alone leans, and the policy learns where to hold a mode). All
            but ``"tracker"`` need ``action_mode="stay"``.
        detector_share: in the ``stay`` mode, the share ``v`` of each row of the base's jumps
            placed by a maneuver detector's belief (``detector``; by default the shadow IMM's
            mode probabilities, which the action does not steer) instead of evenly (the
            ``tracker`` base: its TPM's stays, at least 1/M, the rest of the row so placed):
            each step's base TPM is ``r I + (1 - r) 1 q^T`` with ``q = (1 - v) / M + v b``
            (``b`` the belief) and ``r`` the base's stay rescaled so that ``v = 0`` gives the
            base's TPM (:func:`imm_gym.sim.stay_bank.detector_tpm_rows`); the stay bank's IMMs
            run these
            priors too, so its evidence weighs them. 0 (default) turns it off; in ``[0, 1]``;
            with the ``shadow`` detector needs ``shadow="fixed"``.
        detector: the belief that places ``detector_share`` of the jumps
            (:mod:`imm_gym.sim.detectors`): ``"shadow"`` (default; the shadow IMM's mode
            probabilities), ``"turn_rate"`` (the estimated turn rate, smoothed, interpolated
            between the models' turn rates: needs a linear bank and ``detector_share > 0``) or
            ``"learned"`` (a network's belief of the coming step's turn rate from a window of an
            unsteered uniform-TPM IMM, :mod:`imm_gym.sim.learned_detector`: needs a linear bank
            of distinct turn rates and ``detector_share > 0``).
        detector_weights: the ``learned`` detector's network, a detector file
            (:class:`~imm_gym.sim.learned_detector.DetectorNetwork`; ``python -m
            agents.detector`` writes one); None (default): the shipped one. Unused by the other
            detectors (a configuration file may name it for the policies that use it).
        stay_grid: the stay bank's priors: ``"stays"`` (one stay for every row, 1/M .. 0.995)
            or ``"pairs"`` (those and the per-model pairs, the stay of the model first in the
            canonical order sticky — CV, whatever the listing — and the others' shorter-lived,
            :func:`imm_gym.sim.stay_bank.grid_stays`), so that the
            ``evidence`` and ``evidence_best`` bases are a stay per row; needs one of them.
        max_factor: largest per-step factor of ``scale`` mode (> 1).
        logit_scale: logit of ``set`` mode, or change of the stay's logit in the stay modes,
            for an action of 1 (> 0).
        parallel: run bank B with the fixed TPM and fuse by entropy (TIP-IMM §3.3).
        shadow: ``"fixed"`` runs a classical IMM with a fixed TPM in lock-step on the same
            measurements (for the ``advantage`` reward and diagnostics) or ``"none"``.
        shadow_stay: diagonal of the shadow's TPM (``None``: ``initial_stay``). Set it to the
            best fixed TPM's (0.6 on the randomized family) to reward beating that bar.
        reward: the rewarded term of :mod:`imm_gym.sim.rewards`: ``"advantage"`` —
            ``(e_shadow - e) / reward_scale`` with ``e`` the position error of the combined
            estimate —, ``"squared_advantage"`` — ``(e_shadow² - e²) / reward_scale²``, the
            per-step terms of the mean squared error that the RMSE(t) of the ARMSE are made of —,
            ``"bank_advantage"`` — ``(e_bank - e) / reward_scale`` with ``e_bank`` the stay
            bank's IMMs' errors weighted by their evidence (it runs the stay bank; not with
            the ``turn_rate`` detector's priors, which the action would move) — or
            ``"error"`` — ``-e / reward_scale``.
        reward_scale: metres per unit of reward (at least ``MIN_REWARD_SCALE``, 1e-6 m), or
            ``"measurement"``: each episode's own scale, the RMS position accuracy of its first
            measurement ``sqrt(tr P0_pos / 2)`` (the sensor's accuracy at the target's range),
            so that trackers of every accuracy weigh alike in training across trackers.
        tpm_cost: weight of the TPM's divergence from the shadow's,
            :func:`imm_gym.tracking.tpm.row_divergence` (nats), subtracted from the reward each
            step: the policy leaves the shadow's TPM only where that pays (0: no cost; needs the
            shadow).
        tpm_change_cost: weight of the TPM's divergence from the previous step's TPM
            (:func:`imm_gym.tracking.tpm.row_divergence`, nats), subtracted from the reward each
            step: a TPM that changes only where that pays.
        mode_reward: weight of the mode-identification term added to the reward, the log score
            of bank A's mode probabilities beyond the shadow's on the true model
            (:func:`imm_gym.sim.rewards.mode_score`; training only: it reads the truth; needs the
            shadow).
        mode_score: the mode-identification term: ``"log"`` the log score above, ``"hit"``
            whether the most probable model is the true one, beyond the shadow's
            (:func:`imm_gym.sim.rewards.mode_hit`: identification without paying for
            confidence).
        obs_features: extra observation blocks, from :data:`OBS_FEATURES` (declared in
            :mod:`imm_gym.sim.features`).
        model_order: the order of the models in the observation and the action: ``"bank"`` (as
            ``bank`` lists them) or ``"canonical"`` (CV, CA, then CT by turn rate, +ω before
            −ω: :mod:`imm_gym.sim.model_order`), so that a policy acts alike on a tracker
            however its configuration lists the models. ``info`` keeps the bank's order.
        loglik_clip: per-model log-likelihoods relative to the best model are clipped to
            ``[-loglik_clip, 0]`` and divided by it.
        velocity_std: standard deviation of the initial velocity (m/s), SPEC §6, in
            ``[MIN_VELOCITY_STD, MAX_VELOCITY_STD]`` (about 1.5e-154 .. 1e6,
            :mod:`imm_gym.tracking.initiation`). The UKFs need the first prediction's spread,
            about ``velocity_std · T``, well inside the target's range: sigma points spread
            across the sensor give a wrong first update, whose covariance the divergence check
            takes for a lost track (the default family at T = 1 s: every run lost at 1e4 m/s,
            none at 3e3 m/s; the EKF, linearized at the estimate, tracks both).
        divergence_error: position error (m) that ends an episode as diverged.
        divergence_cov: trace of the position covariance (m²) that ends an episode as diverged.
        engine: how the banks run (:mod:`imm_gym.sim.engines`): ``"compiled"`` (one numba call
            per step; built-in sensor and filter, linear bank), ``"numpy"`` (any tracker) or
            ``"auto"`` (compiled where possible). Same numbers either way (to rounding).
    """

    scenario: str | Scenario = "random"
    family: RandomFamily = field(default_factory=RandomFamily)
    sensor: Sonar = field(default_factory=Sonar)
    vary: Variation = field(default_factory=Variation)
    bank: tuple[MotionModel, ...] | HeteroBank = field(default_factory=paper_bank)
    filter: str = "ukf"
    initial_stay: float | tuple[float, ...] = 0.995
    sojourn: tuple[float, ...] | None = None
    p_min: float = 1e-3
    action_mode: str = "scale"
    stay_base: str = "tracker"
    detector_share: float = 0.0
    detector: str = "shadow"
    detector_weights: str | None = None
    stay_grid: str = "stays"
    max_factor: float = 2.0
    logit_scale: float = 4.0
    parallel: bool = False
    shadow: str = "fixed"
    shadow_stay: float | None = None
    reward: str = "advantage"
    reward_scale: float | str = 10.0
    tpm_cost: float = 0.0
    tpm_change_cost: float = 0.0
    mode_reward: float = 0.0
    mode_score: str = "log"
    obs_features: tuple[str, ...] = ()
    model_order: str = "bank"
    loglik_clip: float = 20.0
    velocity_std: float = 5.0
    divergence_error: float = 5000.0
    divergence_cov: float = 1e8
    engine: str = "auto"

    def __post_init__(self) -> None:
        if isinstance(self.scenario, Mapping):
            store(self, "scenario", from_dict(Scenario, self.scenario, "scenario"))
        elif not isinstance(self.scenario, Scenario):
            check_choice("scenario", self.scenario, ("random", *SCENARIOS))
        for name, cls in (("family", RandomFamily), ("sensor", Sonar), ("vary", Variation)):
            value = getattr(self, name)
            if isinstance(value, Mapping):
                store(self, name, from_dict(cls, value, name))
            elif not isinstance(value, cls):
                raise ConfigError(f"{name} must be a {cls.__name__} or a mapping")
        if isinstance(self.bank, (Mapping, HeteroBank)):
            bank: tuple[MotionModel, ...] | HeteroBank = from_dict(HeteroBank, self.bank, "bank")
            if self.filter != "ekf":
                raise ConfigError("a heterogeneous bank (NCV/CT/CTRA) needs filter 'ekf'")
        else:
            bank = tuple(_bank_model(i, m) for i, m in enumerate(check_sequence("bank", self.bank)))
            if len(bank) < 2 or not all(isinstance(m, MotionModel) for m in bank):
                raise ConfigError("bank must hold at least 2 MotionModel entries")
        store(self, "bank", bank)
        check_choice("filter", self.filter, tuple(f for f in FILTERS if f != "kf"))
        M = len(bank)
        if isinstance(self.initial_stay, (list, tuple, np.ndarray)):
            stay = tuple(
                check_range(f"initial_stay[{i}]", s, 0.0, 1.0)
                for i, s in enumerate(check_sequence("initial_stay", self.initial_stay, M))
            )
        else:
            stay = check_range("initial_stay", self.initial_stay, 0.0, 1.0)
        store(self, "initial_stay", stay)
        if self.sojourn is not None:
            sojourn = check_sequence("sojourn", self.sojourn, M)
            store(self, "sojourn", tuple(
                check_range(f"sojourn[{i}]", t, 0.0, lo_open=True) for i, t in enumerate(sojourn)
            ))
            # exp(A T) at the longest sampling period an episode can have
            longest = self.vary.T[1] if self.vary.T is not None else self.source.T
            for i, t in enumerate(self.sojourn):
                if longest / t > MAX_T_OVER_SOJOURN:
                    raise ConfigError(
                        f"sojourn[{i}] must be at least T / {MAX_T_OVER_SOJOURN:g} = "
                        f"{longest / MAX_T_OVER_SOJOURN:g} s at the sampling period {longest:g} s, "
                        f"got {t!r}"
                    )
        store(self, "p_min", check_range("p_min", self.p_min, 0.0, 1.0 / M, hi_open=True))
        check_choice("action_mode", self.action_mode, ACTION_MODES)
        check_choice("model_order", self.model_order, MODEL_ORDERS)
        check_choice("stay_base", self.stay_base, STAY_BASES)
        if self.stay_base != "tracker" and self.action_mode != "stay":
            raise ConfigError(
                f"stay_base {self.stay_base!r} needs action_mode 'stay', got {self.action_mode!r}"
            )
        share = check_range("detector_share", self.detector_share, 0.0, 1.0)
        store(self, "detector_share", share)
        if share > 0.0 and self.action_mode != "stay":
            raise ConfigError(
                f"detector_share > 0 needs action_mode 'stay' (the stays it places the jumps of), "
                f"got {self.action_mode!r}"
            )
        check_choice("detector", self.detector, DETECTORS)
        observed = "detector_belief" in check_sequence("obs_features", self.obs_features)
        if self.detector != "shadow" and share == 0.0 and not observed:
            raise ConfigError(
                f"detector {self.detector!r} places the detector_share of the jumps (unless "
                f"obs_features has 'detector_belief'): detector_share must be in (0, 1], got 0"
            )
        omegas = model_turn_rates(self.bank)
        if self.detector != "shadow" and omegas is None:
            raise ConfigError(
                f"detector {self.detector!r} needs a linear bank (the models' turn rates its "
                f"belief is placed on), got a heterogeneous one"
            )
        if self.detector_weights is not None:
            if not isinstance(self.detector_weights, str | Path):
                raise ConfigError(f"detector_weights must be a file path or None, got "
                                  f"{shown(self.detector_weights)}")
            store(self, "detector_weights", str(self.detector_weights))
        if self.detector == "learned":
            turn_rate_order(omegas)  # distinct turn rates
            DetectorNetwork.load(self.detector_weights or DEFAULT_WEIGHTS).check_models(M)
        check_choice("stay_grid", self.stay_grid, STAY_GRIDS)
        if self.stay_grid != "stays" and self.stay_base not in ("evidence", "evidence_best"):
            raise ConfigError(
                f"stay_grid {self.stay_grid!r} needs stay_base 'evidence' or 'evidence_best' (the "
                f"bases it gives a stay per row), got {self.stay_base!r}"
            )
        store(self, "max_factor", check_range("max_factor", self.max_factor, 1.0, lo_open=True))
        store(self, "logit_scale", check_range("logit_scale", self.logit_scale, 0.0, lo_open=True))
        if not isinstance(self.parallel, bool):
            raise ConfigError(f"parallel must be a bool, got {shown(self.parallel)}")
        check_choice("shadow", self.shadow, SHADOWS)
        if self.detector == "shadow" and self.shadow == "none" and (
            self.detector_share > 0.0 or observed
        ):
            raise ConfigError("detector_share > 0 and the detector_belief feature need shadow "
                              "'fixed' with the shadow detector (whose mode probabilities they "
                              "use)")
        if self.shadow_stay is not None:
            store(self, "shadow_stay", check_range("shadow_stay", self.shadow_stay, 0.0, 1.0))
        check_choice("reward", self.reward, tuple(REWARD_TERMS))
        if REWARD_TERMS[self.reward].needs_shadow and self.shadow == "none":
            raise ConfigError(f"reward {self.reward!r} needs shadow 'fixed'")
        if (
            REWARD_TERMS[self.reward].needs_stay_bank
            and self.detector == "turn_rate"
            and self.detector_share > 0.0
        ):
            raise ConfigError(
                f"reward {self.reward!r} with detector 'turn_rate' and detector_share > 0 would "
                "let the action move its baseline (the stay bank runs the detector's priors, and "
                "the turn-rate detector reads the steered tracker's velocity): use detector "
                "'shadow' or 'learned', or another reward"
            )
        if isinstance(self.reward_scale, str):
            check_choice("reward_scale", self.reward_scale, REWARD_SCALES)
        else:
            store(
                self,
                "reward_scale",
                check_range("reward_scale", self.reward_scale, MIN_REWARD_SCALE),
            )
        store(self, "tpm_cost", check_range("tpm_cost", self.tpm_cost, 0.0))
        if self.tpm_cost > 0.0 and self.shadow == "none":
            raise ConfigError("tpm_cost > 0 needs shadow 'fixed' (the TPM it is measured from)")
        store(self, "tpm_change_cost", check_range("tpm_change_cost", self.tpm_change_cost, 0.0))
        store(self, "mode_reward", check_range("mode_reward", self.mode_reward, 0.0))
        if self.mode_reward > 0.0 and self.shadow == "none":
            raise ConfigError("mode_reward > 0 needs shadow 'fixed' (the probabilities it is "
                              "measured against)")
        check_choice("mode_score", self.mode_score, tuple(MODE_SCORES))
        features = check_sequence("obs_features", self.obs_features)
        for i, f in enumerate(features):
            check_choice(f"obs_features[{i}]", f, tuple(FEATURES))
        if len(set(features)) != len(features):
            raise ConfigError(f"obs_features has duplicates: {features}")
        for f in features:
            if FEATURES[f].needs_parallel and not self.parallel:
                raise ConfigError(f"obs_features {f!r} needs parallel=True")
            if FEATURES[f].needs_shadow and self.shadow == "none":
                raise ConfigError(f"obs_features {f!r} needs shadow 'fixed'")
            if FEATURES[f].needs_linear_bank and not isinstance(self.bank, tuple):
                raise ConfigError(
                    f"obs_features {f!r} needs a linear bank (the models' Q), got a "
                    "heterogeneous one"
                )
        has_ct = any(m.kind == "ct" for m in self.linear_bank or ())
        if "turn_band" in features and not has_ct:
            raise ConfigError("obs_features 'turn_band' needs a linear bank with a CT model")
        store(self, "obs_features", features)
        for name in ("loglik_clip", "divergence_error", "divergence_cov"):
            store(self, name, check_range(name, getattr(self, name), 0.0, lo_open=True))
        store(self, "velocity_std", check_range(
            "velocity_std", self.velocity_std, MIN_VELOCITY_STD, MAX_VELOCITY_STD))
        check_choice("engine", self.engine, ENGINES)
        check_variation(self.vary, self.scenario, self.bank, self.sensor)
        if self.vary.active and self.engine == "numpy":
            raise ConfigError("vary needs engine 'compiled' or 'auto' (a bank per episode)")
        if self.scenario == "random" and self.family.designed_share > 0.0 and not has_ct:
            raise ConfigError(
                "family.designed_share needs a linear bank with a CT model (the turns its "
                "targets are drawn for)"
            )

    @property
    def linear_bank(self) -> tuple[MotionModel, ...] | None:
        """The bank's models where the bank is linear, else None (a heterogeneous bank)."""
        return self.bank if isinstance(self.bank, tuple) else None

    @property
    def source(self) -> TruthSource:
        """What ``reset`` draws a scenario from."""
        if isinstance(self.scenario, Scenario):
            return self.scenario
        return self.family if self.scenario == "random" else SCENARIOS[self.scenario]()

    def initial_tpm(self, T: float) -> Array:
        """The ``(M, M)`` TPM episodes at sampling period ``T`` start from (and bank B keeps):
        ``exp(A T)`` of the sojourns, or ``initial_stay`` on the diagonal."""
        if self.sojourn is not None:
            return tpm_from_sojourn(self.sojourn, T)
        return stay_tpm(len(self.bank), self.initial_stay)

    def shadow_tpm(self, T: float) -> Array:
        """The shadow IMM's ``(M, M)`` TPM at ``T``: ``shadow_stay`` on the diagonal, or the
        initial TPM."""
        if self.shadow_stay is None:
            return self.initial_tpm(T)
        return stay_tpm(len(self.bank), self.shadow_stay)

    def replace(self, **changes: Any) -> EnvConfig:
        """A copy with some fields changed (validated; an unknown field is a
        :class:`ConfigError` naming it, as in a mapping)."""
        fields = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - fields)
        if unknown:
            raise ConfigError(
                f"EnvConfig: unknown key(s) {unknown}; allowed keys are {sorted(fields)}"
            )
        return dataclasses.replace(self, **changes)

    @classmethod
    def build(
        cls,
        config: EnvConfig | Mapping[str, Any] | None = None,
        preset: Mapping[str, Any] | None = None,
        **kwargs: Any,
    ) -> EnvConfig:
        """From an :class:`EnvConfig` or mapping, updated with keyword arguments; a ``preset``
        (a registered id's fields) is the base a ``config`` mapping updates (an
        :class:`EnvConfig` is the whole configuration: it replaces the preset)."""
        if preset is not None and (config is None or isinstance(config, Mapping)):
            config = {**preset, **(config or {})}
        if config is None:
            base: dict[str, Any] = {}
        elif isinstance(config, EnvConfig):
            return config.replace(**kwargs) if kwargs else config
        elif isinstance(config, Mapping):
            base = dict(config)
        else:
            raise ConfigError(
                f"config must be an EnvConfig or a mapping, got {type(config).__name__}"
            )
        return from_dict(cls, {**base, **kwargs}, "EnvConfig")
