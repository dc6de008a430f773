"""A batch of classical IMMs beside each slot's banks, on the slot's measurements: the stay
bank's (one IMM per switching prior, :mod:`imm_gym.sim.stay_bank`) and the learned detector's
(one IMM at the uniform TPM, :mod:`imm_gym.sim.learned_detector`).

Slot ``i``'s IMMs are rows ``i * S .. i * S + S - 1`` of one batch: one call of the tracker's
compiled cycle (:func:`imm_gym.tracking.kernels.imm.imm_step`), or of its numpy ``step``,
advances them all, each at its own TPM. An IMM whose innovation covariance fails (a diverged
filter) restarts from a fallback posterior, its slot's bank A's.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.imm import IMMState, Tracker
from imm_gym.tracking.kernels.imm import imm_step

Array = NDArray[np.float64]


class BatchStep(NamedTuple):
    """One cycle of the batch's ``B = N * S`` IMMs (rows as the batch's)."""

    cbar: Array  # (B, M) predicted mode probabilities
    loglik: Array  # (B, M) each model's measurement log-likelihood
    nis: Array  # (B,) NIS of the predicted measurement mixture (0 unless the batch's ``nis``)
    estimate: Array  # (B, n) combined estimate
    failed: NDArray[np.bool_]  # (B,) rows whose innovation covariance failed


class IMMBatch:
    """``S`` classical IMMs for each of N slots (module docstring).

    Args:
        imm: the slots' tracker.
        n_envs: the number of slots N.
        per_slot: the IMMs per slot S.
        kernel_args: the core's compiled bank constants (``F``, ``Q``, ``R`` with a leading axis
            of 1, or N: one bank per slot), None for the numpy engine.
        nis: whether the compiled cycle computes the NIS of the predicted measurement mixture
            (the numpy engine always does).
    """

    def __init__(
        self, imm: Tracker, n_envs: int, per_slot: int, kernel_args: tuple | None,
        nis: bool = False,
    ) -> None:
        M, n = imm.n_models, imm.n
        self.imm = imm
        self.n_envs, self.S = n_envs, per_slot
        self._nis = nis
        B = n_envs * per_slot
        self._args = None if kernel_args is None else self._own_args(kernel_args)
        #: the IMMs' posteriors, ``(B, M, n)``, ``(B, M, n, n)``, ``(B, M)``
        self.state = IMMState(
            np.zeros((B, M, n)),
            np.repeat(np.eye(n)[None, None], B * M, 0).reshape(B, M, n, n),
            np.full((B, M), 1.0 / M),
        )

    def _own_args(self, kernel_args: tuple) -> tuple:
        """The compiled constants for the ``N * S`` rows: shared ones as they are, one bank per
        slot repeated for each of its IMMs (rows set at :meth:`start`)."""
        F, Q, R, *rest = kernel_args
        if F.shape[0] == 1:
            return kernel_args
        return (*(np.repeat(a, self.S, axis=0) for a in (F, Q, R)), *rest)

    def rows(self, indices: NDArray[np.int64]) -> NDArray[np.int64]:
        """The batch rows of the slots ``indices`` (each slot's S IMMs)."""
        return (np.asarray(indices)[:, None] * self.S + np.arange(self.S)).ravel()

    def start(
        self, indices: NDArray[np.int64], init: IMMState, kernel_args: tuple | None
    ) -> None:
        """Start the slots ``indices`` from ``init`` (one posterior per slot, bank A's initial
        one); under varied conditions, at the slots' constants ``kernel_args`` (the core's,
        rows ``indices`` already set)."""
        rows = self.rows(indices)
        parts = []
        for a, value in zip(_arrays(self.state), _arrays(init), strict=True):
            a = a.copy()
            a[rows] = np.repeat(value, self.S, axis=0)
            parts.append(a)
        self.state = IMMState(*parts)
        if self._args is not None and self._args[0].shape[0] > 1 and kernel_args is not None:
            for own, slot in zip(self._args[:3], kernel_args[:3], strict=True):
                own[rows] = np.repeat(slot[indices], self.S, axis=0)

    def step(
        self, tpm_rows: Array, z: Array, detected: NDArray[np.bool_], fallback: IMMState
    ) -> BatchStep:
        """Advance every IMM at its TPM ``tpm_rows (B, M, M)`` on its slot's measurement ``z
        (N, m)`` (``detected (N,)``); a failed IMM restarts from its slot's row of
        ``fallback`` (the step's outputs keep its failure)."""
        S = self.S
        # C-contiguous (np.repeat's copies are): the compiled cycle is cached for that layout,
        # a step's column of the episode's measurements would compile it anew (minutes)
        z_rows = np.repeat(z, S, axis=0) if S > 1 else np.ascontiguousarray(z)
        det_rows = np.repeat(detected, S) if S > 1 else np.ascontiguousarray(detected)
        state, out = self._advance(tpm_rows, z_rows, det_rows)
        if np.count_nonzero(out.failed):
            slot = np.flatnonzero(out.failed) // S
            for a, value in zip(_arrays(state), _arrays(fallback), strict=True):
                a[out.failed] = value[slot]
        self.state = state
        return out

    def _advance(
        self, tpm_rows: Array, z: Array, detected: NDArray[np.bool_]
    ) -> tuple[IMMState, BatchStep]:
        """One cycle of all IMMs: their posteriors and the cycle's outputs."""
        if self._args is None:
            state, out = self.imm.step(
                self.state, tpm_rows, z, detected, check=False, allow_failure=True
            )
            return state, BatchStep(out.cbar, out.loglik, out.nis, out.x, out.failed)
        B, M, n = self.state.x.shape
        x, P, mu = np.empty((B, M, n)), np.empty((B, M, n, n)), np.empty((B, M))
        cbar, loglik, nis = np.empty((B, M)), np.empty((B, M)), np.empty(B)
        estimate, failed = np.empty((B, n)), np.empty(B, dtype=bool)
        outs = (
            x, P, mu, cbar, loglik, np.empty((B, M)), np.empty((B, M, z.shape[1])),
            nis, estimate, np.empty((B, n, n)), failed,
        )
        imm_step(
            self.state.x, self.state.P, self.state.mu, tpm_rows, z, detected,
            *self._args, self._nis, *outs,
        )
        return IMMState(x, P, mu), BatchStep(cbar, loglik, nis, estimate, failed)

    def snapshot(self) -> IMMState:
        """The IMMs' posteriors (arrays are replaced, never written, by a step)."""
        return self.state

    def restore(self, state: IMMState, slots: NDArray[np.bool_]) -> None:
        """Put back the posteriors of ``state`` for the slots where ``slots (N,)`` is True."""
        rows = np.repeat(slots, self.S)
        parts = []
        for new, old in zip(_arrays(self.state), _arrays(state), strict=True):
            new = new.copy()
            new[rows] = old[rows]
            parts.append(new)
        self.state = IMMState(*parts)


def _arrays(state: IMMState) -> tuple[Array, Array, Array]:
    return state.x, state.P, state.mu
