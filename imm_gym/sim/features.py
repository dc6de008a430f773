r"""The observation-feature registry: every optional observation block declared once.

An observation is ``[mu(t), mu(t-1)]`` followed by the blocks named in
:attr:`~imm_gym.sim.env_config.EnvConfig.obs_features`, in that order. A block is a
:class:`Feature`: its name, a one-line meaning (the environment's datasheet table is generated
from it, :func:`datasheet_table`), its length for ``M`` models and ``m`` measurement components,
its bounds, what it needs of the configuration (the shadow IMM, the parallel bank), how it is
computed from the core's per-step quantities (:class:`StepView`) and, for a memory, how that
memory starts and advances. Adding a feature is one :func:`register` call here (and its test).

Memories are exponential moving averages :math:`m(t) = \lambda m(t-1) + (1 - \lambda) w(t)`,
one per factor ``lambda``, advanced after every step (only for observed features); the evidence
memories (``shadow_evidence``, ``stay_evidence``) are discounted sums
:math:`m(t) = \lambda m(t-1) + w(t)`, as their descriptions say.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.imm import measurement_loglik
from imm_gym.tracking.tpm import stay_tpm_rows

Array = NDArray[np.float64]

#: Whitened innovations are clipped to ``[-INNOVATION_CLIP, INNOVATION_CLIP]`` and divided by it.
INNOVATION_CLIP = 5.0
#: Heading rate (rad/s) that the ``turn_rate`` features map to 1.
TURN_RATE_SCALE = float(np.deg2rad(10.0))
#: Factors ``lambda`` of the ``turn_rate_ema`` / ``prob_ema`` / ``shadow_turn_rate_ema``
#: memories (about 3 and 10 steps).
EMA_FACTORS = (0.7, 0.9)
#: Factors of the ``turn_magnitude_ema`` memory (about 10 and 33 steps): gentle and sharp turners
#: want different TPMs (a looser one for turn rates well below the bank's).
MAGNITUDE_EMA_FACTORS = (0.9, 0.97)
#: Decades either side of 1 that the ``maneuver_snr`` and ``tracking_index`` features resolve
#: (:func:`log_decades`).
MANEUVER_SNR_DECADES = 3.0
TRACKING_INDEX_DECADES = 4.0
#: Decades either side of 1 that the ``turn_band`` feature resolves.
TURN_BAND_DECADES = 2.0
#: Speed (m/s) that the ``speed`` feature maps to 1.
SPEED_SCALE = 30.0
#: Factors of the ``shadow_evidence`` memory (about 10 and 33 steps).
EVIDENCE_FACTORS = (0.9, 0.97)
#: Per-step clip (nats) of the evidence for the shadow's TPM: one outlier moves it at most this.
EVIDENCE_STEP_CLIP = 3.0
#: Evidence (nats) that the ``shadow_evidence`` and ``stay_evidence`` features map to
#: tanh(1) ≈ 0.76.
EVIDENCE_SCALE = 4.0
#: Stays of the ``stay_evidence`` TPMs after the uniform one (``1/M``).
EVIDENCE_STAYS = (0.6, 0.8, 0.9, 0.95, 0.98, 0.995)
#: Factor of the ``stay_evidence`` memory (about 33 steps).
STAY_EVIDENCE_FACTOR = 0.97


class StepView(Protocol):
    """The core's quantities after a step that features are computed from (N slots, M models,
    m measurement components). Ground truth is not among them: policies never see it."""

    config: Any  # the EnvConfig
    horizon: int  # K, steps of an episode
    n_envs: int
    k: NDArray[np.int64]  # (N,) steps taken
    mu: Array  # (N, M) mu(t): bank A's, or the fused U when parallel
    mu_prev: Array  # (N, M) mu(t-1)
    mu_b: Array  # (N, M) bank B's probabilities before fusion
    mu_s: Array  # (N, M) the shadow IMM's
    mu_s_prev: Array  # (N, M) the shadow IMM's at t-1
    cbar: Array  # (N, M) bank A's predicted model probabilities of the last step
    cbar_s: Array  # (N, M) the shadow IMM's
    loglik_s: Array  # (N, M) the shadow IMM's per-model log-likelihoods
    tpm: Array  # (N, M, M) the TPM of the last step
    loglik: Array  # (N, M) bank A's per-model log-likelihoods
    model_nis: Array  # (N, M)
    innovation: Array  # (N, M, m) whitened innovations
    velocity: Array  # (N, 2) velocity of the combined estimate at t
    velocity_prev: Array  # (N, 2) at t-1
    velocity_s: Array  # (N, 2) the shadow's estimate at t
    velocity_s_prev: Array  # (N, 2) at t-1
    stay_bank_evidence: Array  # (N, S) the stay bank's evidence minus the best (nats)
    detector_belief: Array  # (N, M) the maneuver detector's belief for the coming step
    sampling_period: Array  # (N,) each slot's T (s)
    velocity_noise: Array  # (N, M) each model's RMS velocity process noise per step (m/s)
    position_accuracy: Array  # (N,) RMS position accuracy of the slot's first measurement (m)
    memories: dict[str, Array]  # each memory feature's state


@dataclass(frozen=True)
class Memory:
    """A feature's state carried across steps.

    Attributes:
        shape: the state's shape per slot for ``M`` models.
        initial: the state of slots starting an episode, from their initial model probabilities
            ``(n, M)`` (a float or an array broadcast over them).
        advance: the next state from the previous one and the step's view.
    """

    shape: Callable[[int], tuple[int, ...]]
    initial: Callable[[Array], Array | float]
    advance: Callable[[Array, StepView], Array]


@dataclass(frozen=True)
class Feature:
    """One optional observation block.

    Attributes:
        name: the key in ``obs_features``.
        meaning: one line for the datasheet (length in parentheses is added).
        size: block length for ``M`` models and ``m`` measurement components.
        low, high: bounds of every entry (the observation is clipped to them).
        observe: the ``(N, size)`` block from the view (before clipping).
        needs_shadow: computed from the shadow IMM (needs ``shadow="fixed"``).
        needs_parallel: computed from bank B (needs ``parallel=True``).
        needs_stay_bank: computed from the stay bank (:mod:`imm_gym.sim.stay_bank`; the core
            runs it when an observed feature needs it).
        needs_linear_bank: computed from the models' ``Q`` (a linear bank's, not the
            heterogeneous bank's state-dependent noise).
        memory: the state it keeps across steps, if any.
        models: how the block's entries are per model (:mod:`imm_gym.sim.model_order` reorders
            them): ``""`` not at all, ``"M"`` entry ``j`` is model ``j``'s, ``"kM"`` blocks of
            ``M`` (factor-major), ``"Mm"`` ``M`` blocks of ``m`` (model-major), ``"MM"`` an
            ``M x M`` matrix, row-major.
    """

    name: str
    meaning: str
    size: Callable[[int, int], int]
    low: float
    high: float
    observe: Callable[[StepView], Array]
    size_label: str = ""
    needs_shadow: bool = False
    needs_parallel: bool = False
    needs_stay_bank: bool = False
    needs_linear_bank: bool = False
    memory: Memory | None = None
    models: str = ""


#: Every feature by name, in declaration order.
FEATURES: dict[str, Feature] = {}


def register(feature: Feature) -> Feature:
    """Add ``feature`` to :data:`FEATURES` (names are unique)."""
    if feature.name in FEATURES:
        raise ValueError(f"observation feature {feature.name!r} is already registered")
    FEATURES[feature.name] = feature
    return feature


def feature_sizes(n_models: int, dim_z: int) -> dict[str, int]:
    """Length of each optional observation block."""
    return {name: f.size(n_models, dim_z) for name, f in FEATURES.items()}


def shadow_features() -> tuple[str, ...]:
    """The features computed from the shadow IMM."""
    return tuple(name for name, f in FEATURES.items() if f.needs_shadow)


def observation_size(features: Sequence[str], n_models: int, dim_z: int) -> int:
    """Entries of the whole observation (``[mu(t), mu(t-1)]`` then the blocks), as
    :func:`bounds` lays it out, with no array built."""
    return 2 * n_models + sum(FEATURES[name].size(n_models, dim_z) for name in features)


def bounds(
    features: tuple[str, ...], n_models: int, dim_z: int
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Lower and upper bounds of the whole observation (``[mu(t), mu(t-1)]`` then the blocks)."""
    lows, highs = [np.zeros(2 * n_models)], [np.ones(2 * n_models)]
    for name in features:
        f = FEATURES[name]
        size = f.size(n_models, dim_z)
        lows.append(np.full(size, f.low))
        highs.append(np.full(size, f.high))
    return np.concatenate(lows).astype(np.float32), np.concatenate(highs).astype(np.float32)


def datasheet_table() -> str:
    """The observation table of the environments' datasheet (markdown), from the registry."""
    rows = [
        "| index | meaning | min | max |",
        "|---|---|---|---|",
        "| 0 .. M−1 | model probabilities μ(t) (fused U if parallel) | 0 | 1 |",
        "| M .. 2M−1 | model probabilities μ(t−1) | 0 | 1 |",
        "| then, in the order of ``obs_features``: | | | |",
    ]
    for f in FEATURES.values():
        needs = (
            " [shadow]" if f.needs_shadow
            else " [parallel]" if f.needs_parallel
            else " [stay bank]" if f.needs_stay_bank
            else " [linear bank]" if f.needs_linear_bank
            else ""
        )
        rows.append(
            f"| ``{f.name}`` | {f.meaning} ({f.size_label}){needs} | {f.low:g} | {f.high:g} |"
        )
    return "\n".join(rows)


# ---------------------------------------------------------------------------- computations
def heading_rate(v_prev: Array, v: Array, T: Array | float) -> Array:
    r"""Heading rate between two velocity estimates ``(N, 2)``:
    :math:`\dot\psi = \operatorname{atan2}(v_{k-1} \times v_k,\ v_{k-1} \cdot v_k) / T`
    (0 where either velocity is zero: ``+ 0.0`` makes a dot product of -0 +0, where atan2
    would read a half turn)."""
    cross = v_prev[:, 0] * v[:, 1] - v_prev[:, 1] * v[:, 0]
    dot = v_prev[:, 0] * v[:, 0] + v_prev[:, 1] * v[:, 1]
    return np.arctan2(cross, dot + 0.0) / T


def turn_rate(view: StepView) -> Array:
    """``(N,)`` heading rate of the combined estimate over the last step / ``TURN_RATE_SCALE``."""
    return heading_rate(view.velocity_prev, view.velocity, view.sampling_period) / TURN_RATE_SCALE


def shadow_turn_rate(view: StepView) -> Array:
    """``(N,)`` the same for the shadow IMM's estimate."""
    rate = heading_rate(view.velocity_s_prev, view.velocity_s, view.sampling_period)
    return rate / TURN_RATE_SCALE


def bank_turn_rate(bank: Any) -> float:
    """The largest ``|omega|`` (rad/s) of a linear bank's CT models: the unit of the ``*_bank``
    turn-rate features (:data:`TURN_RATE_SCALE` for a bank without CT models or a heterogeneous
    bank, whose CT model estimates its turn rate)."""
    rates = [abs(m.omega) for m in bank if getattr(m, "kind", None) == "ct"] if isinstance(
        bank, tuple
    ) else []
    return max(rates) if rates else TURN_RATE_SCALE


def model_turn_rates(bank: Any) -> Array:
    """``(M,)`` each model's turn rate in units of :func:`bank_turn_rate` (CT models; 0 for CV
    and CA): which model a per-model entry belongs to (a linear bank's)."""
    rates = [m.omega if getattr(m, "kind", None) == "ct" else 0.0 for m in bank]
    return np.asarray(rates, dtype=float) / bank_turn_rate(bank)


def model_kinds(bank: Any) -> Array:
    """``(2 M,)`` which kind each model of a linear bank is, factor-major: ``[is CA per model,
    is CT per model]`` (CV models are 0 in both)."""
    kinds = [getattr(m, "kind", None) for m in bank]
    return np.array([[k == "ca" for k in kinds], [k == "ct" for k in kinds]], float).ravel()


def turn_rate_bank(view: StepView) -> Array:
    """``(N,)`` heading rate of the combined estimate in units of the bank's turn rate."""
    rate = heading_rate(view.velocity_prev, view.velocity, view.sampling_period)
    return rate / bank_turn_rate(view.config.bank)


def shadow_turn_rate_bank(view: StepView) -> Array:
    """``(N,)`` the same for the shadow IMM's estimate."""
    rate = heading_rate(view.velocity_s_prev, view.velocity_s, view.sampling_period)
    return rate / bank_turn_rate(view.config.bank)


def log_decades(x: Array, decades: float) -> Array:
    r"""A positive ratio on a log scale, :math:`\log_{10} x / d` clipped to [-1, 1]: ``d``
    decades either side of 1 resolved."""
    return np.clip(np.log10(np.maximum(x, 10.0**-decades)) / decades, -1.0, 1.0)


def maneuver_snr(view: StepView) -> Array:
    r"""``(N,)`` how far a turn at the bank's rate moves the target off a straight line in one
    step, in units of the measurement accuracy, on a log scale:
    :math:`\log_{10}(|v|\,\omega_{bank} T^2 / (2 \sigma_p)) / 3` clipped to [-1, 1]
    (``sigma_p``: the slot's first-measurement accuracy). Near -1 the models are
    indistinguishable step by step, near 1 a single step tells them apart."""
    speed = np.hypot(view.velocity[:, 0], view.velocity[:, 1])
    T = view.sampling_period
    offset = speed * bank_turn_rate(view.config.bank) * T * T / (2.0 * view.position_accuracy)
    return log_decades(offset, MANEUVER_SNR_DECADES)


def turn_band(view: StepView) -> Array:
    r"""``(N,)`` how wide a band of turn rates the bank's CT models are designed to fly, relative
    to their rate, at the estimated speed, on a log scale: the lateral acceleration their
    process noise absorbs over the one a turn at their rate takes,
    :math:`\bar a / (|\hat v|\,\omega_{bank})` with :math:`\bar a` the CT models' mean RMS
    velocity noise per step over ``T`` (``sqrt(q / T)`` for white-noise acceleration of
    intensity ``q``) and :math:`|\hat v|` the combined estimate's speed, as
    :math:`\log_{10} / 2` clipped to [-1, 1] (the band of
    :meth:`~imm_gym.scenarios.segments.RandomFamily.designed_band` is ``±c`` times it). Near -1 a
    turn off the bank's rate is one its CT models do not absorb; near 1 they absorb any turn."""
    cts = [j for j, m in enumerate(view.config.bank) if m.kind == "ct"]
    accel = view.velocity_noise[:, cts].mean(axis=1) / view.sampling_period
    speed = np.hypot(view.velocity[:, 0], view.velocity[:, 1])
    turn = np.maximum(speed * bank_turn_rate(view.config.bank), np.finfo(np.float64).tiny)
    return log_decades(accel / turn, TURN_BAND_DECADES)


def tracking_index(view: StepView) -> Array:
    r"""``(N, M)`` each model's tracking index (Kalata 1984) on a log scale: the position spread
    one step of the model's process noise causes, in units of the measurement accuracy,
    :math:`\lambda_j = \sigma_{v,j} T / \sigma_p`, with :math:`\sigma_{v,j}^2` the mean of
    ``Q_j``'s velocity variances (``q T`` for white-noise acceleration of intensity ``q``, so
    :math:`\lambda_j = \sqrt{q_j T^3} / \sigma_p`), as :math:`\log_{10}\lambda_j / 4` clipped to
    [-1, 1]. How the tracker is tuned against its sensor, model by model: the differences
    between entries are the maneuver models' noise against the first model's."""
    index = view.velocity_noise * (view.sampling_period / view.position_accuracy)[:, None]
    return log_decades(index, TRACKING_INDEX_DECADES)


def shadow_evidence_step(view: StepView) -> Array:
    r"""``(N,)`` the last measurement's evidence for the shadow's TPM against bank A's, in nats:
    :math:`\log p_S(z_t \mid Z^{t-1}) - \log p_A(z_t \mid Z^{t-1})` (each the IMM's
    :func:`~imm_gym.tracking.imm.measurement_loglik`, :math:`\log \sum_j \bar c_j \Lambda_j`),
    clipped to ``±EVIDENCE_STEP_CLIP``; 0 on a missed detection. Summed over steps it is the log
    Bayes factor of the two trackers: which switching prior predicts this target's measurements
    better, in the tracker's own units whatever the sensor, speed or sampling period."""
    gain = measurement_loglik(view.loglik_s, view.cbar_s) - measurement_loglik(
        view.loglik, view.cbar
    )
    return np.clip(gain, -EVIDENCE_STEP_CLIP, EVIDENCE_STEP_CLIP)


def evidence_stays(n_models: int) -> Array:
    """``(S,)`` the stays whose evidence is weighed (the ``stay_evidence`` feature, the stay
    bank's single stays): ``1/M`` (uniform), then each of :data:`EVIDENCE_STAYS`."""
    return np.array([1.0 / n_models, *EVIDENCE_STAYS])


def stay_tpms(n_models: int) -> Array:
    """``(S, M, M)`` the TPMs the ``stay_evidence`` feature weighs: the :func:`evidence_stays`
    on the diagonal, the rest of each row spread evenly."""
    return stay_tpm_rows(evidence_stays(n_models), n_models)


def stay_evidence_step(view: StepView) -> Array:
    r"""``(N, S)`` the last measurement's evidence for each TPM of :func:`stay_tpms` against the
    best of them, in nats: with the shadow IMM's per-model likelihoods :math:`\Lambda_j` and its
    probabilities :math:`\mu(t-1)`, :math:`e_s = \log \sum_j [\mu(t-1)^T \Pi_s]_j \Lambda_j`
    (the switching prior ``Pi_s``'s one-step prediction of the mode, the mixing of the states
    left as the shadow's) minus the largest over ``s``, clipped to ``-EVIDENCE_STEP_CLIP``.
    The models' likelihoods tell the stays apart only where the shadow's own TPM is sticky (at
    the uniform TPM every model starts each step from the same mixed state): give it the
    tracker's TPM (``shadow_stay=None``)."""
    M = view.mu_s_prev.shape[1]
    cbar = np.einsum("ni,sij->nsj", view.mu_s_prev, stay_tpms(M))
    loglik = np.broadcast_to(view.loglik_s[:, None, :], cbar.shape)
    e = measurement_loglik(loglik.reshape(-1, M), cbar.reshape(-1, M)).reshape(cbar.shape[:2])
    return np.maximum(e - e.max(axis=1, keepdims=True), -EVIDENCE_STEP_CLIP)


def _relative_evidence(view: StepView) -> Array:
    total = view.memories["stay_evidence"]
    return np.tanh((total - total.max(axis=1, keepdims=True)) / EVIDENCE_SCALE)


def _ema(factors: tuple[float, ...], signal: Callable[[StepView], Array]) -> Memory:
    """Moving averages of a scalar signal ``(N,)``, one per factor, starting at 0."""
    lam = np.asarray(factors)
    return Memory(
        shape=lambda M: (len(factors),),
        initial=lambda mu0: 0.0,
        advance=lambda m, view: lam * m + (1.0 - lam) * signal(view)[:, None],
    )


def _memory_of(name: str) -> Callable[[StepView], Array]:
    return lambda view: view.memories[name].reshape(view.n_envs, -1)


def _relative_loglik(view: StepView) -> Array:
    clip = view.config.loglik_clip
    rel = view.loglik - view.loglik.max(axis=-1, keepdims=True)
    return np.clip(rel, -clip, 0.0) / clip


def _whitened_innovation(view: StepView) -> Array:
    w = np.clip(view.innovation, -INNOVATION_CLIP, INNOVATION_CLIP) / INNOVATION_CLIP
    return w.reshape(view.n_envs, -1)


def _clipped_shadow_rate(view: StepView) -> Array:
    return np.clip(shadow_turn_rate(view), -1.0, 1.0)


_LAM = np.asarray(EMA_FACTORS)
_EVIDENCE_LAM = np.asarray(EVIDENCE_FACTORS)

# ---------------------------------------------------------------------------- the registry
register(Feature(
    "tpm", "current TPM, row-major", lambda M, m: M * M, 0.0, 1.0,
    lambda v: v.tpm.reshape(v.n_envs, -1), size_label="M·M", models="MM",
))
register(Feature(
    "loglik", "log-likelihood minus the best model's, clipped to ±``loglik_clip`` and divided"
    " by it", lambda M, m: M, -1.0, 0.0, _relative_loglik, size_label="M", models="M",
))
register(Feature(
    "nis", "per-model NIS squashed, nis / (nis + m)", lambda M, m: M, 0.0, 1.0,
    lambda v: v.model_nis / (v.model_nis + v.config.sensor.dim_z), size_label="M", models="M",
))
register(Feature(
    "innovation", "per-model whitened innovations L⁻¹ν clipped to ±5 and divided by 5,"
    " model-major", lambda M, m: M * m, -1.0, 1.0, _whitened_innovation, size_label="M·m",
    models="Mm",
))
register(Feature(
    "bank_b", "bank B's probabilities before fusion", lambda M, m: M, 0.0, 1.0,
    lambda v: v.mu_b, size_label="M", models="M", needs_parallel=True,
))
register(Feature(
    "shadow_probs", "the shadow IMM's probabilities: a maneuver detector the action does not"
    " influence", lambda M, m: M, 0.0, 1.0, lambda v: v.mu_s, size_label="M", models="M",
    needs_shadow=True,
))
register(Feature(
    "time", "k / K", lambda M, m: 1, 0.0, 1.0, lambda v: (v.k / v.horizon)[:, None],
    size_label="1",
))
register(Feature(
    "turn_rate", "heading rate of the combined estimate over the last step,"
    " atan2(v(t−1) × v(t), v(t−1) · v(t)) / T, over 10°/s, clipped", lambda M, m: 1, -1.0, 1.0,
    lambda v: turn_rate(v)[:, None], size_label="1",
))
register(Feature(
    "shadow_turn_rate", "the same for the shadow IMM's estimate", lambda M, m: 1, -1.0, 1.0,
    lambda v: shadow_turn_rate(v)[:, None], size_label="1", needs_shadow=True,
))
register(Feature(
    "turn_rate_ema", "moving averages of the (unclipped) turn rate, λ = 0.7, 0.9, then clipped",
    lambda M, m: len(EMA_FACTORS), -1.0, 1.0, _memory_of("turn_rate_ema"), size_label="2",
    memory=_ema(EMA_FACTORS, turn_rate),
))
register(Feature(
    "prob_ema", "moving averages of μ(t), λ = 0.7, 0.9, starting at μ(0), factor-major",
    lambda M, m: len(EMA_FACTORS) * M, 0.0, 1.0, _memory_of("prob_ema"), size_label="2M",
    models="kM",
    memory=Memory(
        shape=lambda M: (len(EMA_FACTORS), M),
        initial=lambda mu0: mu0[:, None, :],
        advance=lambda m, v: _LAM[:, None] * m + (1.0 - _LAM[:, None]) * v.mu[:, None],
    ),
))
register(Feature(
    "shadow_turn_rate_ema", "moving averages of the shadow's turn rate clipped to ±1,"
    " λ = 0.7, 0.9: a memory the action cannot steer", lambda M, m: len(EMA_FACTORS), -1.0, 1.0,
    _memory_of("shadow_turn_rate_ema"), size_label="2", needs_shadow=True,
    memory=_ema(EMA_FACTORS, _clipped_shadow_rate),
))
register(Feature(
    "turn_magnitude_ema", "moving averages of the shadow's turn-rate magnitude clipped to 1,"
    " λ = 0.9, 0.97: how sharply this target turns", lambda M, m: len(MAGNITUDE_EMA_FACTORS),
    0.0, 1.0, _memory_of("turn_magnitude_ema"), size_label="2", needs_shadow=True,
    memory=_ema(MAGNITUDE_EMA_FACTORS, lambda v: np.abs(_clipped_shadow_rate(v))),
))
register(Feature(
    "speed", "speed of the combined estimate over 30 m/s, clipped", lambda M, m: 1, 0.0, 1.0,
    lambda v: np.hypot(v.velocity[:, 0], v.velocity[:, 1])[:, None] / SPEED_SCALE,
    size_label="1",
))
register(Feature(
    "turn_rate_bank", "heading rate of the combined estimate over the last step in units of the"
    " bank's largest CT turn rate, clipped to ±2 and halved", lambda M, m: 1, -1.0, 1.0,
    lambda v: (np.clip(turn_rate_bank(v), -2.0, 2.0) / 2.0)[:, None], size_label="1",
))
register(Feature(
    "model_turn_rate", "each model's turn rate over the bank's largest |ω| (0 for CV and CA"
    " models): which model a per-model entry is, for a network shared by the models",
    lambda M, m: M, -1.0, 1.0,
    lambda v: np.broadcast_to(model_turn_rates(v.config.bank), (v.n_envs, len(v.config.bank))),
    size_label="M", models="M", needs_linear_bank=True,
))
register(Feature(
    "model_kind", "whether each model is a CA model, then whether it is a CT model (factor-"
    "major; CV models are 0 in both): with model_turn_rate, which model a per-model entry is",
    lambda M, m: 2 * M, 0.0, 1.0,
    lambda v: np.broadcast_to(model_kinds(v.config.bank), (v.n_envs, 2 * len(v.config.bank))),
    size_label="2M", models="kM", needs_linear_bank=True,
))
register(Feature(
    "shadow_turn_rate_bank", "the same for the shadow IMM's estimate", lambda M, m: 1, -1.0, 1.0,
    lambda v: (np.clip(shadow_turn_rate_bank(v), -2.0, 2.0) / 2.0)[:, None], size_label="1",
    needs_shadow=True,
))
register(Feature(
    "turn_magnitude_bank_ema", "moving averages of the shadow's turn-rate magnitude in units of"
    " the bank's, clipped to 1, λ = 0.9, 0.97", lambda M, m: len(MAGNITUDE_EMA_FACTORS), 0.0, 1.0,
    _memory_of("turn_magnitude_bank_ema"), size_label="2", needs_shadow=True,
    memory=_ema(MAGNITUDE_EMA_FACTORS, lambda v: np.minimum(np.abs(shadow_turn_rate_bank(v)), 1.0)),
))
register(Feature(
    "maneuver_snr", "log10 of a bank turn's one-step offset |v| ω T² / 2 over the measurement"
    " accuracy, / 3, clipped: how distinguishable the models are", lambda M, m: 1, -1.0, 1.0,
    lambda v: maneuver_snr(v)[:, None], size_label="1",
))
register(Feature(
    "tracking_index", "each model's tracking index σ_v T / σ_p (RMS velocity process noise per"
    " step times T over the measurement accuracy), log10 / 4, clipped: how the tracker is tuned",
    lambda M, m: M, -1.0, 1.0, tracking_index, size_label="M", models="M", needs_linear_bank=True,
))
register(Feature(
    "turn_band", "the CT models' acceleration noise sqrt(q / T) over the acceleration |v| ω of a"
    " turn at the bank's rate, log10 / 2, clipped: how wide a band of turns they are designed"
    " to fly", lambda M, m: 1, -1.0, 1.0, lambda v: turn_band(v)[:, None], size_label="1",
    needs_linear_bank=True,
))
register(Feature(
    "shadow_evidence", "discounted sums of the measurements' log-likelihood under the shadow"
    " IMM minus under bank A, λ = 0.9, 0.97, each step's clipped to ±3 nats, tanh(sum / 4): which"
    " TPM this target's measurements support", lambda M, m: len(EVIDENCE_FACTORS), -1.0, 1.0,
    lambda v: np.tanh(v.memories["shadow_evidence"] / EVIDENCE_SCALE), size_label="2",
    needs_shadow=True,
    memory=Memory(
        shape=lambda M: (len(EVIDENCE_FACTORS),),
        initial=lambda mu0: 0.0,
        advance=lambda m, v: _EVIDENCE_LAM * m + shadow_evidence_step(v)[:, None],
    ),
))
register(Feature(
    "stay_evidence", "discounted sums (λ = 0.97) of the measurements' log-likelihood under the"
    " stays 1/M, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995 (the shadow's probabilities and likelihoods),"
    " minus the best, tanh(· / 4): which switching prior this target's measurements support",
    lambda M, m: 1 + len(EVIDENCE_STAYS), -1.0, 0.0, _relative_evidence,
    size_label=str(1 + len(EVIDENCE_STAYS)),
    needs_shadow=True,
    memory=Memory(
        shape=lambda M: (1 + len(EVIDENCE_STAYS),),
        initial=lambda mu0: 0.0,
        advance=lambda m, v: STAY_EVIDENCE_FACTOR * m + stay_evidence_step(v),
    ),
))
register(Feature(
    "stay_bank_evidence", "the exact evidence of one classical IMM per stay 1/M, 0.6, 0.8, 0.9,"
    " 0.95, 0.98, 0.995 (the stay bank): discounted sums (λ = 0.99) of each IMM's measurement"
    " log-likelihood minus the best's, each step's floored at −10 nats, tanh(· / 4); with"
    " stay_grid 'pairs' these seven, the best taken over the pairs too",
    lambda M, m: 1 + len(EVIDENCE_STAYS), -1.0, 0.0,
    lambda v: np.tanh(v.stay_bank_evidence / EVIDENCE_SCALE),
    size_label=str(1 + len(EVIDENCE_STAYS)), needs_stay_bank=True,
))
register(Feature(
    "detector_belief", "the maneuver detector's belief for the coming step (EnvConfig.detector:"
    " the learned network's, the turn-rate interpolation, or the shadow's probabilities)",
    lambda M, m: M, 0.0, 1.0, lambda v: v.detector_belief, size_label="M", models="M",
))
