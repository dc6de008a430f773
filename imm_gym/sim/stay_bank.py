r"""The stay bank: one classical IMM per switching prior of a grid, run on each slot's
measurements, and the exact evidence of the measurements for each.

For the stays :math:`s \in \{1/M, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995\}` (:func:`grid_stays`) each
slot runs the classical IMM with the TPM :math:`\Pi_s` (the stay on the diagonal, the rest of
the row spread evenly) beside its banks. The IMM's predictive density of a measurement is the
normalizer of its mode update, :math:`p_s(z_t \mid Z^{t-1}) = \sum_j \bar c_{s,j} \Lambda_{s,j}`
(:func:`imm_gym.tracking.imm.measurement_loglik`), so

.. math::
    E_s(t) = \lambda E_s(t-1) + \max\big(e_s(t) - \max_r e_r(t),\ -\varepsilon\big),
    \qquad e_s(t) = \log p_s(z_t \mid Z^{t-1}),

is the discounted log evidence of the measurements for each switching prior against the best
(:data:`STAY_BANK_FACTOR` :math:`\lambda`, per-step floor :data:`STAY_BANK_FLOOR`
:math:`\varepsilon`: one outlier moves it by at most that). Unlike the ``stay_evidence``
feature's one-step approximation (one IMM's likelihoods reweighted by each prior), every
:math:`\Pi_s` here also mixes its own states, so the evidence is the IMM's exact one.

The evidence serves two ends: the ``stay_bank_evidence`` observation block and the base of the
``stay`` action: with ``EnvConfig.stay_base = "evidence"`` the stay
:math:`\sigma(\sum_s w_s \operatorname{logit} s)` at the posterior weights
:math:`w = \operatorname{softmax}(E)` (:meth:`StayBank.centre`), with ``"evidence_best"`` the
stay :math:`\arg\max_s E_s` (:meth:`StayBank.best`).

With ``EnvConfig.stay_grid = "pairs"`` the bank also runs the per-model priors of
:data:`PAIR_FIRST` × :data:`PAIR_OTHERS` (:func:`grid_stays`): the stay of the model first in the
canonical order — straight flight (CV, else CA), whatever the listing — sticky, every other
model's shorter-lived, which no single stay
expresses (the ``best-fixed-rows`` baseline's family). The stays are then per row,
:math:`s_{k,i}`, and the centre and the best are per row too:
:math:`\sigma(\sum_k w_k \operatorname{logit} s_{k,i})` and :math:`s_{\arg\max_k E_k, i}`.

With ``EnvConfig.detector_share`` each IMM runs the prior of :func:`detector_tpm_rows` at its
stay instead of :math:`\Pi_s`: its jumps placed partly by the slot's maneuver detector
(``EnvConfig.detector``: the shadow IMM's mode probabilities, the turn-rate interpolation or
the learned belief), the priors the ``stay`` action then moves between.

The bank also gives an accuracy no action moves (:meth:`StayBank.position_error`): the position
errors of its IMMs weighted by the evidence the step's ``stay`` base was computed from,
:math:`\bar e(t) = \sum_s w_s(t-1) \lVert \hat p_s(t) - p(t) \rVert`, the baseline of the
``bank_advantage`` reward (:mod:`imm_gym.sim.rewards`).

A missed detection is evidence for none (every :math:`e_s = 0`). An IMM of the bank whose
innovation covariance fails (a diverged filter) gets the floor and restarts from bank A's
posterior.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.features import EVIDENCE_STAYS, evidence_stays
from imm_gym.sim.imm_batch import IMMBatch
from imm_gym.tracking.imm import IMMState, Tracker, measurement_loglik
from imm_gym.tracking.tpm import stay_tpm_rows

Array = NDArray[np.float64]

#: Discount factor ``lambda`` of the stay bank's evidence (about 100 steps).
STAY_BANK_FACTOR = 0.99
#: Per-step floor (nats) of each stay's evidence against the best.
STAY_BANK_FLOOR = 10.0


#: ``stay_grid: "pairs"``: the sticky model's stays of the per-model priors the stay bank runs
#: beside the single stays...
PAIR_FIRST = (0.95, 0.99, 0.999)
#: ...and every other model's (after ``1/M``).
PAIR_OTHERS = (0.6, 0.8, 0.9)


def grid_stays(n_models: int, grid: str = "stays", sticky: int = 0) -> Array:
    """``(S, M)`` each prior's stay per row: the single stays ``1/M`` and :data:`EVIDENCE_STAYS`
    on every row, then with ``grid="pairs"`` each ``a`` of :data:`PAIR_FIRST` on row ``sticky``
    and ``b`` of ``1/M`` and :data:`PAIR_OTHERS` on every other row (``(a, b, ..., b)`` for
    ``sticky = 0``)."""
    M = n_models
    singles = np.repeat(evidence_stays(M)[:, None], M, axis=1)
    if grid == "stays":
        return singles
    pairs = np.array([[b] * M for _ in PAIR_FIRST for b in (1.0 / M, *PAIR_OTHERS)])
    pairs[:, sticky] = np.repeat(PAIR_FIRST, 1 + len(PAIR_OTHERS))
    return np.concatenate([singles, pairs])


def detector_tpm_rows(stays: Array, belief: Array, share: float | Array) -> Array:
    r"""``(N, M, M)`` switching priors whose jumps follow a maneuver detector
    (``EnvConfig.detector_share``).

    Each row keeps its mode with probability :math:`r` and otherwise redraws it from
    :math:`q`, an even spread moved the share :math:`v` toward the detector's mode
    probabilities :math:`\mu_S` (the shadow IMM's, which the action does not steer):

    .. math::
        \Pi = r I + (1 - r)\, \mathbf 1 q^\top, \qquad
        q = \frac{1 - v}{M} \mathbf 1 + v \mu_S, \qquad
        r = \frac{s - 1/M}{1 - 1/M},

    so the predicted mode probabilities are :math:`\bar c = r \mu + (1 - r) q`. With
    :math:`v = 0` (or a uniform belief) this is
    :func:`~imm_gym.tracking.tpm.stay_tpm_rows` of the stays ``s``
    (to rounding); with :math:`v > 0` a nearly uniform prior still leans toward the mode the
    detector has accumulated evidence for, so the mode probabilities keep identifying the
    maneuver where one step's likelihoods cannot.

    Args:
        stays: the stays ``s`` in ``[1/M, 1]``: one per prior ``(..., )`` or one per row
            ``(..., M)`` (row ``i`` keeps its mode with its own :math:`r_i`), told apart by
            having one axis fewer than ``belief`` or as many.
        belief: ``(..., M)`` the detector's mode probabilities.
        share: ``v`` in ``[0, 1]``, one for all rows or one per prior ``(...,)``.

    Returns:
        ``(..., M, M)``, the leading axes of the three broadcast together (the stay bank's
        ``(N, S)``: every slot's belief at every stay of its grid).
    """
    belief = np.asarray(belief, dtype=np.float64)
    M = belief.shape[-1]
    s = np.asarray(stays, dtype=np.float64)
    per_row = s if s.ndim == belief.ndim else s[..., None]
    keep = (per_row - 1.0 / M) / (1.0 - 1.0 / M)
    v = np.asarray(share, dtype=np.float64)
    v = v[..., None] if v.ndim else v
    q = (1.0 - v) / M + v * belief
    return (1.0 - keep)[..., :, None] * q[..., None, :] + keep[..., :, None] * np.eye(M)


class StayBank:
    """One classical IMM per prior of :func:`grid_stays` for each of N slots (module
    docstring).

    The ``N * S`` IMMs are rows ``i * S + s`` of one :class:`~imm_gym.sim.imm_batch.IMMBatch`:
    one call of the tracker's compiled cycle (or of its numpy ``step``) advances them all.

    Args:
        imm: the slots' tracker.
        n_envs: the number of slots N.
        kernel_args: the core's compiled bank constants (``F``, ``Q``, ``R`` with a leading axis
            of 1, or N: one bank per slot), None for the numpy engine.
        detector_share: ``v > 0``: each stay's IMM runs :func:`detector_tpm_rows` at its stay
            (the jumps placed by the slot's detector, :meth:`step`'s ``belief``) instead of the
            evenly spread stay TPM, so that the evidence compares the priors the ``stay``
            action moves between.
        grid: ``"stays"`` or ``"pairs"`` (:func:`grid_stays`).
        sticky: the bank index of the model whose stay the pairs make sticky (the first in the
            canonical order, :func:`~imm_gym.sim.model_order.canonical_order`: straight flight,
            whatever the listing).
    """

    def __init__(
        self,
        imm: Tracker,
        n_envs: int,
        kernel_args: tuple | None,
        detector_share: float = 0.0,
        grid: str = "stays",
        sticky: int = 0,
    ) -> None:
        M = imm.n_models
        self.n_envs = N = n_envs
        self.detector_share = detector_share
        #: ``(S, M)`` each prior's stay per row, the stays' logits, ``(S, M, M)`` the TPMs
        self.stays = grid_stays(M, grid, sticky)
        self.logits = np.log(self.stays) - np.log1p(-self.stays)
        self.tpms = stay_tpm_rows(self.stays, M)
        self.S = S = len(self.tpms)
        #: the single stays' count: the first columns of the evidence (the observed ones)
        self.n_single = 1 + len(EVIDENCE_STAYS)
        # a fresh, writable array for every N (a read-only view at N = 1 would compile another
        # specialization of the kernel)
        self._tpm_rows = np.tile(self.tpms, (N, 1, 1))
        #: the ``N * S`` IMMs, rows ``i * S + s``
        self.batch = IMMBatch(imm, N, S, kernel_args)
        #: ``(N, S)`` the discounted evidence :math:`E_s` (relative: its largest entry is the
        #: best stay's)
        self.evidence = np.zeros((N, S))
        #: ``(N, S)`` the evidence's weights :math:`\operatorname{softmax}(E)` before the last
        #: step (the step's base was computed from them)
        self.weights = np.full((N, S), 1.0 / S)

    @property
    def state(self) -> IMMState:
        """The IMMs' posteriors, ``(N * S, M, n)``, ``(N * S, M, n, n)``, ``(N * S, M)``."""
        return self.batch.state

    def start(
        self, indices: NDArray[np.int64], init: IMMState, kernel_args: tuple | None
    ) -> None:
        """Start the slots ``indices`` from bank A's initial posterior ``init`` (one row per
        slot), with zero evidence; under varied conditions, at the slots' constants
        ``kernel_args`` (the core's, rows ``indices`` already set)."""
        self.batch.start(indices, init, kernel_args)
        self.evidence = self.evidence.copy()
        self.evidence[indices] = 0.0

    def _relative_likelihoods(self) -> Array:
        r"""``(N, S)`` :math:`\exp(E_s - \max_r E_r)` (:meth:`relative`), the unnormalized
        weights."""
        return np.exp(self.relative())

    def posterior_weights(self) -> Array:
        r"""``(N, S)`` :math:`w = \operatorname{softmax}(E)`, the stays' weights the evidence
        so far gives (uniform at the start of an episode)."""
        w = self._relative_likelihoods()
        return w / w.sum(axis=1, keepdims=True)

    def centre(self) -> Array:
        r"""``(N, M)`` the evidence's stay of each row
        :math:`\sigma(\sum_s w_s \operatorname{logit} s_i)`, :math:`w` =
        :meth:`posterior_weights`: the switching prior the measurements so far support, averaged
        on the logit scale (the mean of the grid's logit stays at the start of an episode)."""
        w = self._relative_likelihoods()
        # one product per row: a slot's stay does not depend on how many slots share the batch
        # (a BLAS product of the whole batch rounds by its shape)
        logit = np.matmul(w[:, None, :], self.logits)[:, 0] / w.sum(axis=1, keepdims=True)
        return 1.0 / (1.0 + np.exp(-logit))

    def estimates(self) -> Array:
        r"""``(N, S, n)`` each IMM's combined estimate :math:`\hat x_s = \sum_j \mu_{s,j}
        x_{s,j}`."""
        x, mu = self.state.x, self.state.mu
        return np.einsum("rm,rmi->ri", mu, x).reshape(self.n_envs, self.S, -1)

    def position_error(self, position: Array, cap: float) -> Array:
        r"""``(N,)`` :math:`\sum_s w_s \min(\lVert \hat p_s - p \rVert, c)`: the position
        errors of the bank's IMMs after the last :meth:`step` (each IMM's combined estimate
        :math:`\hat p_s = \sum_j \mu_{s,j} x_{s,j}`), each capped at ``cap`` like the
        banks', weighted by the evidence before that step (:attr:`weights`). ``position (N, 2)``:
        the true positions. No action moves it: it depends on the measurements alone."""
        error = np.linalg.norm(self.estimates()[:, :, :2] - position[:, None, :], axis=-1)
        error = np.where(error <= cap, error, cap)  # NaN -> the cap
        return np.sum(self.weights * error, axis=1)

    def best(self) -> Array:
        """``(N, M)`` the stays of the prior whose IMM has the largest evidence so far (the
        grid's first, 1/M, at the start of an episode)."""
        return self.stays[np.argmax(self.evidence, axis=1)]

    def relative(self) -> Array:
        """``(N, S)`` each stay's evidence minus the best's (nats, ``<= 0``)."""
        return self.evidence - self.evidence.max(axis=1, keepdims=True)

    def step(
        self,
        z: Array,
        detected: NDArray[np.bool_],
        fallback: IMMState,
        belief: Array | None = None,
    ) -> None:
        """Advance every IMM on its slot's measurement ``z (N, m)`` (``detected (N,)``) and add
        the step's evidence; an IMM that fails restarts from ``fallback``, bank A's posterior
        after the step. ``belief (N, M)``: the detector's mode probabilities before the step
        (needed with ``detector_share``)."""
        N, S, M = self.n_envs, self.S, self.stays.shape[1]
        if self.detector_share > 0.0:
            if belief is None:
                raise ValueError("a stay bank with detector_share needs the detector's belief")
            # every slot's belief at every stay of the grid, (N, S, M, M), in the kernel's array
            self._tpm_rows.reshape(N, S, M, M)[:] = detector_tpm_rows(
                self.stays[None], belief[:, None], self.detector_share
            )
        out = self.batch.step(self._tpm_rows, z, detected, fallback)
        ok = ~out.failed
        e = measurement_loglik(  # failed rows: finite stand-ins, replaced by the floor below
            np.where(ok[:, None], out.loglik, 0.0), np.where(ok[:, None], out.cbar, 1.0 / M)
        )
        det_rows = np.repeat(detected, S)
        e = np.where(det_rows & ok, e, 0.0).reshape(N, S)  # a missed detection: no evidence
        ok = ok.reshape(N, S)
        best = np.max(np.where(ok, e, -np.inf), axis=1, keepdims=True)
        best = np.where(np.isfinite(best), best, 0.0)
        gain = np.where(ok, np.maximum(e - best, -STAY_BANK_FLOOR), -STAY_BANK_FLOOR)
        self.weights = self.posterior_weights()
        self.evidence = STAY_BANK_FACTOR * self.evidence + gain

    def snapshot(self) -> tuple[IMMState, Array]:
        """The bank's state (arrays are replaced, never written, by a step)."""
        return self.batch.snapshot(), self.evidence

    def restore(self, snap: tuple[IMMState, Array], slots: NDArray[np.bool_]) -> None:
        """Put back the values of ``snap`` for the slots where ``slots (N,)`` is True."""
        state, evidence = snap
        self.batch.restore(state, slots)
        self.evidence = np.where(slots[:, None], evidence, self.evidence)
