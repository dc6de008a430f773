r"""Offline Q/R tuning of an IMM bank by the bare-bones sine-cosine algorithm (seed 003 §3.2).

**Search space.** A particle is ``theta = (log10 s_Q1, ..., log10 s_QM, log10 s_R)``: one factor
on each model's process noise ``Q_j`` and one on the measurement noise ``R`` the filters assume
(all models share the sensor, so one ``R`` factor instead of seed 003's one per model), inside the
box ``[lo, hi]^D``.

**Objective** (seed 003: "the actual mean square error of the innovation"): over a training set
of S runs and K steps, the steps ``D`` where the sensor detected the target (all S K of them at
detection probability 1),

.. math::
    J(\theta) = \frac{1}{|D| m} \sum_{(s,k) \in D} \lVert \Sigma^{-1/2}(z_{s,k} - \hat z_{s,k|k-1})
    \rVert^2,

with ``\hat z_{k|k-1} = \sum_j \bar c_j h_j(x_j^-)`` the IMM's predicted measurement and
``\Sigma = diag(\sigma^2)`` the *sensor's* nominal noise (fixed: it only makes position and velocity
commensurate, so inflating the filter's ``R`` cannot lower ``J``). ``J`` is the one-step
prediction error: the measurement noise alone contributes 1 (a predictor that knew the true state
would score ``J = 1`` in expectation), the state's prediction error the rest. A missed detection
has no innovation: the filter never sees that step's measurement, so it is not scored.

**Why offline and batched.** Seed 003 re-runs the optimizer at every time step on the data seen so
far. That is 10 particles x 100 generations of filtering per step, and the tuned values chase the
noise of a few samples. Here the tuner runs once, before tracking, on a training set of scenarios,
and a generation's P particles are P x S independent trackers of one batched IMM run
(:func:`imm_gym.papers.systems.run_bank` with per-tracker ``q_scale`` / ``r_scale``): one pass over
the K steps evaluates the whole swarm. The tuned bank is then a fixed configuration
(:class:`TunedBank`, saved and loaded as JSON).

**SCA** (Mirjalili 2016): with ``b`` the best particle so far,
``X_i <- X_i + r_1 \sin r_2 |r_3 b - X_i|`` if ``r_4 < 0.5`` else with ``\cos``;
``r_1 = a (1 - t / T_{max})`` (linear, ``a = 2``), ``r_2 \sim U(0, 2\pi)``, ``r_3 \sim U(0, 2)``,
``r_4 \sim U(0, 1)`` per component; the swarm moves every generation (no selection).

**BBSCA** (seed 003 §3.2.2): (i) ``r_1 = a e^{-\lambda t / T_{max}}`` (exponentially decreasing,
``\lambda = 4``: the extraction lost the constant); (ii) per component, with probability 1/2
(``r_5 < 0.5``) the sine-cosine step above, otherwise the Gaussian bare-bones step toward the best,
``Y_{ij} \sim N((b_j + X_{kj}) / 2, |b_j - X_{kj}|)`` with ``k`` a randomly chosen particle;
(iii) greedy selection, ``X_i <- Y_i`` if ``J(Y_i) \le J(X_i)`` (the extraction lost the sign, of
which §3.2.2 says it "reduces the possibility of search stagnation": ``\le``, which lets a
particle move along a plateau of equal fitness, where ``<`` would hold it still). Both spend P
evaluations per generation, so equal budgets are equal generation counts.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.papers.systems import run_bank
from imm_gym.sim.episodes import Batch
from imm_gym.tracking.hetero import HeteroIMM
from imm_gym.validation import (
    ConfigError,
    check_choice,
    check_finite,
    check_int,
    check_range,
    check_sequence,
    from_dict,
    store,
    unique_keys,
)

Array = NDArray[np.float64]

OPTIMIZERS = ("bbsca", "sca")


@dataclass(frozen=True)
class TunerConfig:
    """Settings of the optimizer (seed 003: 10 particles, 100 generations).

    Attributes:
        method: ``"bbsca"`` or ``"sca"``.
        particles: swarm size P (>= 2); generations: T_max (>= 1).
        bounds: the box of ``log10`` scales, ``lo < hi``.
        a: the initial ``r_1``; decay: BBSCA's ``lambda``.
        seed: the optimizer's generator seed.
    """

    method: str = "bbsca"
    particles: int = 10
    generations: int = 30
    bounds: tuple[float, float] = (-2.0, 2.0)
    a: float = 2.0
    decay: float = 4.0
    seed: int = 0

    def __post_init__(self) -> None:
        check_choice("tuner.method", self.method, OPTIMIZERS)
        store(self, "particles", check_int("tuner.particles", self.particles, 2))
        store(self, "generations", check_int("tuner.generations", self.generations, 1))
        lo, hi = check_sequence("tuner.bounds (low, high)", self.bounds, 2)
        lo = check_range("tuner.bounds[0]", lo, -10.0, 10.0)
        store(self, "bounds", (lo, check_range("tuner.bounds[1]", hi, lo, 10.0, lo_open=True)))
        store(self, "a", check_range("tuner.a", self.a, 0.0, lo_open=True))
        store(self, "decay", check_range("tuner.decay", self.decay, 0.0, lo_open=True))
        store(self, "seed", check_int("tuner.seed", self.seed, 0))


@dataclass(frozen=True)
class OptimResult:
    """Best point, its value, and the best value after each generation (``history[0]``: the
    initial swarm)."""

    best: Array
    value: float
    history: list[float]
    evaluations: int


def optimize(objective: Callable[[Array], Array], dim: int, config: TunerConfig) -> OptimResult:
    """Minimize ``objective`` (batched: ``(P, D) -> (P,)``) by SCA or BBSCA (module docstring).

    The initial swarm is uniform in the box and includes the point 0 (the untuned bank; clipped
    to the box if the box excludes it) as particle 0, so with a box around 0 the result is never
    worse than the untuned bank on the training set.

    Args:
        objective: ``(P, D) -> (P,)``; non-finite values count as ``inf``.
        dim: ``D``, the number of components of a particle.
        config: the optimizer's settings.
    """
    check_int("dim", dim, 1)
    rng = np.random.default_rng(config.seed)
    lo, hi = config.bounds
    P, G = config.particles, config.generations
    X = rng.uniform(lo, hi, size=(P, dim))
    X[0] = np.clip(0.0, lo, hi)
    f = np.asarray(objective(X), dtype=np.float64)
    f = np.where(np.isfinite(f), f, np.inf)
    b = int(np.argmin(f))
    best, best_f = X[b].copy(), float(f[b])
    history = [best_f]
    for t in range(G):
        r1 = step_scale(config.method, t, G, config.a, config.decay)
        Y = sine_cosine_step(X, best, r1, rng)
        if config.method == "bbsca":
            gauss = bare_bones_step(X, best, rng)
            Y = np.where(rng.uniform(size=X.shape) < 0.5, Y, gauss)  # r_5 < 0.5: sine-cosine
        Y = np.clip(Y, lo, hi)
        fy = np.asarray(objective(Y), dtype=np.float64)
        fy = np.where(np.isfinite(fy), fy, np.inf)
        X, f = next_swarm(config.method, X, f, Y, fy)
        b = int(np.argmin(fy))
        if fy[b] < best_f:
            best, best_f = Y[b].copy(), float(fy[b])
        history.append(best_f)
    return OptimResult(best, best_f, history, P * (G + 1))


def step_scale(method: str, t: int, generations: int, a: float, decay: float) -> float:
    """``r_1`` at generation ``t`` of ``T_max``: SCA ``a (1 - t / T_max)`` (linear), BBSCA
    ``a e^{-lambda t / T_max}`` (exponential, ``lambda = decay``)."""
    if method == "sca":
        return a * (1.0 - t / generations)
    return float(a * np.exp(-decay * t / generations))


def sine_cosine_step(X: Array, best: Array, r1: float, rng: np.random.Generator) -> Array:
    """SCA's proposal ``X + r_1 trig(r_2) |r_3 b - X|`` per component: ``trig = sin`` if
    ``r_4 < 0.5`` else ``cos``, ``r_2 ~ U(0, 2 pi)``, ``r_3 ~ U(0, 2)``, ``r_4 ~ U(0, 1)``."""
    r2 = rng.uniform(0.0, 2 * np.pi, size=X.shape)
    r3 = rng.uniform(0.0, 2.0, size=X.shape)
    r4 = rng.uniform(size=X.shape)
    trig = np.where(r4 < 0.5, np.sin(r2), np.cos(r2))
    return X + r1 * trig * np.abs(r3 * best - X)


def bare_bones_step(X: Array, best: Array, rng: np.random.Generator) -> Array:
    """BBSCA's Gaussian proposal ``Y_{ij} ~ N((b_j + X_{kj}) / 2, |b_j - X_{kj}|)`` (standard
    deviation ``|b_j - X_{kj}|``), ``k`` a particle drawn per component."""
    P, dim = X.shape
    k = rng.integers(0, P, size=X.shape)
    other = X[k, np.arange(dim)[None, :]]
    return rng.normal((best + other) / 2.0, np.abs(best - other))


def next_swarm(method: str, X: Array, f: Array, Y: Array, fy: Array) -> tuple[Array, Array]:
    """The swarm of the next generation: SCA moves every particle to its proposal (no
    selection), BBSCA keeps the better of the two (:func:`greedy_select`)."""
    if method == "bbsca":
        return greedy_select(X, f, Y, fy)
    return Y, fy


def greedy_select(X: Array, f: Array, Y: Array, fy: Array) -> tuple[Array, Array]:
    """BBSCA's greedy selection: particle ``i`` moves to ``Y_i`` where ``fy_i <= f_i`` (a tie
    moves it too, against stagnation), else stays; the swarm ``(P, D)`` and its values ``(P,)``."""
    move = fy <= f
    return np.where(move[:, None], Y, X), np.where(move, fy, f)


def innovation_mse(
    residual: Array, sigma: Array, failed: Array, detected: NDArray[np.bool_] | None = None
) -> Array:
    """Per-tracker ``J``: ``mean_{k, i} (nu / sigma)^2`` over the detected steps ``k``; ``inf``
    for a failed tracker, NaN for one without a detected step.

    Args:
        residual: ``(N, K, m)`` innovations ``z - z_hat`` (bearings wrapped); sigma: ``(m,)``;
        failed: ``(N,)``; detected: ``(N, K)``, the steps whose measurement the filter received
            (``None``: every step). A missed step's ``z`` is a measurement the filter never saw.
    """
    e = residual / sigma
    sq = np.sum(e * e, axis=2)
    if detected is None:
        detected = np.ones(sq.shape, dtype=bool)
    n = detected.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(detected, sq, 0.0).sum(axis=1) / (n * residual.shape[2])
    return np.where(failed | ((n > 0) & ~np.isfinite(out)), np.inf, out)


def bank_objective(
    imm: HeteroIMM, batch: Batch, tpm: Array, sigma: Array, tune_r: bool = True
) -> Callable[[Array], Array]:
    """``J`` of every particle of a swarm, in one batched run over the training batch.

    Args:
        imm: the bank (its models' own ``q_scale`` are the reference, 1 = untuned).
        batch: the training runs (S >= 1; a :class:`~imm_gym.sim.episodes.Batch` works
        too). tpm: the fixed TPM. sigma: the sensor's nominal standard deviations ``(m,)``.
        tune_r: particles carry the ``R`` factor as last component (else ``M`` components and
            ``R`` as the sensor has it).
    """
    if batch.n_runs < 1:
        raise ConfigError("the tuning set is empty: it needs at least one run")
    M, S = imm.n_models, batch.n_runs
    z = batch.measurements.z[:, 1:]
    detected = batch.measurements.detected[:, 1:]
    n = detected.sum(axis=1)
    if not n.any():
        raise ConfigError("the tuning set has no detected measurement: no innovation to score")
    sigma = np.asarray(sigma, dtype=np.float64)

    def objective(theta: Array) -> Array:
        theta = np.atleast_2d(theta)
        P = theta.shape[0]
        D = M + int(tune_r)
        if theta.ndim != 2 or theta.shape[1] != D:
            raise ConfigError(
                f"a particle has {D} components ({M} Q scales, {int(tune_r)} R), got particles of "
                f"shape {theta.shape}"
            )
        scales = 10.0 ** np.repeat(theta, S, axis=0)  # particle-major, (P S, D)
        r_scale = scales[:, M] if tune_r else None
        run = run_bank(imm, batch, tpm, q_scale=scales[:, :M], r_scale=r_scale, repeat=P)
        residual = imm.sensor.residual(np.tile(z, (P, 1, 1)), run.z_pred)
        per = innovation_mse(residual, sigma, run.failed, np.tile(detected, (P, 1)))
        # pooled over the runs' detected steps (the runs' mean where every step is detected)
        per = np.where(np.tile(n, P) > 0, per, 0.0).reshape(P, S)
        pooled = (per * n).sum(axis=1) / n.sum()
        return np.where(run.failed.reshape(P, S).any(axis=1), np.inf, pooled)

    return objective


@dataclass(frozen=True)
class TunedBank:
    """A tuned bank configuration: one ``Q`` factor per model and one ``R`` factor.

    Attributes:
        bank: name of the bank the factors apply to (``seed003``, ``seed002``).
        q_scale: ``(M,)`` factors (> 0); r_scale: factor (> 0).
        method: the optimizer; objective: training ``J`` of the tuned point; notes: free-form.
    """

    bank: str
    q_scale: tuple[float, ...]
    r_scale: float = 1.0
    method: str = "bbsca"
    objective: float | None = None
    notes: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.bank, str) or not self.bank:
            raise ConfigError(
                f"tuned.bank must be a non-empty string (the system's name), got {self.bank!r}"
            )
        q_scale = check_sequence("tuned.q_scale", self.q_scale)
        if not q_scale:
            raise ConfigError("tuned.q_scale must have one entry per model")
        store(
            self,
            "q_scale",
            tuple(
                check_range(f"tuned.q_scale[{i}]", s, 0.0, lo_open=True)
                for i, s in enumerate(q_scale)
            ),
        )
        store(self, "r_scale", check_range("tuned.r_scale", self.r_scale, 0.0, lo_open=True))
        check_choice("tuned.method", self.method, (*OPTIMIZERS, "none"))
        if self.objective is not None:
            store(self, "objective", check_finite("tuned.objective", self.objective))
        if not isinstance(self.notes, dict):
            raise ConfigError(f"tuned.notes must be a mapping, got {self.notes!r}")

    @classmethod
    def from_theta(
        cls, bank: str, theta: Array, n_models: int | None = None, **kwargs: Any
    ) -> TunedBank:
        """From ``log10`` factors: ``M`` Q factors, then the R factor if present."""
        s = 10.0 ** np.asarray(theta, dtype=np.float64)
        M = len(s) - 1 if n_models is None else n_models
        r = float(s[M]) if len(s) > M else 1.0
        return cls(bank, tuple(float(v) for v in s[:M]), r, **kwargs)

    @property
    def theta(self) -> Array:
        return np.log10(np.array([*self.q_scale, self.r_scale]))

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(asdict(self), indent=2))

    @classmethod
    def load(cls, path: str | Path, method: str | None = None) -> TunedBank:
        """The bank saved at ``path``; with ``method``, refused unless its ``method`` is that
        optimizer (a file tuned by SCA is not a BBSCA-tuned bank)."""
        try:
            data = json.loads(Path(path).read_text(), object_pairs_hook=unique_keys)
        except (OSError, ValueError) as err:  # unreadable, not JSON, a key given twice
            raise ConfigError(f"tuned bank {path}: cannot read ({err})") from None
        except RecursionError:
            raise ConfigError(f"tuned bank {path}: cannot read (nested too deeply)") from None
        tuned = from_dict(cls, data, f"tuned bank {path}")
        if method is not None and tuned.method != method:
            raise ConfigError(
                f"tuned bank {path}: its field method is {tuned.method!r}; it was given for the "
                f"policy {method!r}, which needs a bank tuned by {method!r}"
            )
        return tuned


def tune(
    imm: HeteroIMM,
    batch: Batch,
    tpm: Array,
    sigma: Array,
    config: TunerConfig,
    bank: str = "custom",
    tune_r: bool = True,
) -> tuple[TunedBank, OptimResult]:
    """Tune ``imm``'s Q (and R) factors on ``batch`` (see the module docstring)."""
    objective = bank_objective(imm, batch, tpm, sigma, tune_r)
    result = optimize(objective, imm.n_models + int(tune_r), config)
    tuned = TunedBank.from_theta(
        bank,
        result.best,
        imm.n_models,
        method=config.method,
        objective=result.value,
        notes={
            "train_runs": batch.n_runs,
            "evaluations": result.evaluations,
            "particles": config.particles,
            "generations": config.generations,
            "seed": config.seed,
        },
    )
    return tuned, result
