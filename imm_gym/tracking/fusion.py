"""Parallel IMM banks fused by Shannon entropy (TIP-IMM §3.3, eqs. 18-19; SPEC §4, §6).

Bank A runs the adapted TPM, bank B the fixed initial TPM, on the same measurements. Their model
probabilities are fused so that the more certain bank (lower entropy) weighs more:

    U = H(U_B) / (H(U_A) + H(U_B)) * U_A + H(U_A) / (H(U_A) + H(U_B)) * U_B,
    H(u) = -sum_j u_j log2 u_j.

SPEC §6 defaults: ``U`` replaces the model probabilities of both banks before the next mixing
(feedback), the TPM rule compares ``U(t)`` with ``U(t-1)``, and the output is bank A's model
estimates weighted by ``U``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def entropy(u: Array) -> Array:
    """Shannon entropy in bits over the last axis, with ``0 log 0 = 0``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(u > 0, u * np.log2(np.where(u > 0, u, 1.0)), 0.0)
    return -terms.sum(axis=-1)


def fuse(u_a: Array, u_b: Array) -> Array:
    """Entropy-weighted fusion (eq. 19) of ``(N, M)`` probability vectors.

    When both banks are certain (both entropies 0) they get equal weights.
    """
    h_a = entropy(u_a)[..., None]
    h_b = entropy(u_b)[..., None]
    total = h_a + h_b
    w_a = np.divide(h_b, total, out=np.full_like(total, 0.5), where=total > 0)
    u = w_a * u_a + (1.0 - w_a) * u_b
    return u / u.sum(axis=-1, keepdims=True)
