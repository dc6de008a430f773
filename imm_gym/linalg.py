"""Small batched linear-algebra kernels used by the filters.

All functions act on the trailing matrix axes and broadcast over any leading batch axes, e.g.
``(N, M, n, n)`` for N trackers with M models each.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

LOG_2PI = float(np.log(2.0 * np.pi))

JACOBI_MAX_SWEEPS = 12


def wrap_angle(a: Array) -> Array:
    """Wrap angles to the half-open interval (-pi, pi].

    ``pi - mod(pi - a, 2 pi)``; ``mod`` can round up to exactly ``2 pi`` for a tiny negative
    argument (``a`` one ulp above pi), which the last step maps back to ``pi``.
    """
    w = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    return np.where(w <= -np.pi, w + 2.0 * np.pi, w)


def symmetrize(P: Array) -> Array:
    """Return ``(P + P^T) / 2`` over the trailing two axes."""
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def sym_eig(P: Array) -> tuple[Array, Array]:
    """Eigendecomposition ``P = U diag(s) U^T`` of symmetric matrices.

    For a symmetric matrix this *is* its singular value decomposition up to column signs
    (singular values ``|s|``), which is how the SVD-UKF uses it. Computed by the cyclic Jacobi
    method (Golub & Van Loan §8.5), compiled with numba: for the 4x4 to 6x6 blocks of a tracker
    it is 3-4x faster than LAPACK's per-matrix call, and each matrix's result does not depend on
    the batch it is in (bit-identical scalar and vector envs).
    The columns of ``U`` come unsorted; the symmetric sigma-point set does not depend on their
    order or sign.

    Args:
        P: ``(..., n, n)`` symmetric matrices (the mean of ``P`` and ``P^T`` is decomposed).

    Returns:
        ``s`` of shape ``(..., n)`` and ``U`` of shape ``(..., n, n)`` with orthonormal columns.
    """
    n = P.shape[-1]
    flat = np.ascontiguousarray(P, dtype=np.float64).reshape(-1, n, n)
    s, U = _jacobi_eig(flat, JACOBI_MAX_SWEEPS)
    return s.reshape(*P.shape[:-1]), U.reshape(P.shape)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _jacobi_eig(P: Array, max_sweeps: int) -> tuple[Array, Array]:  # pragma: no cover - jitted
    """:func:`jacobi_eig_inplace` on the ``(n, n)`` blocks of ``P`` (shape ``(B, n, n)``)."""
    B, n, _ = P.shape
    a = np.empty((B, n, n))
    U_out = np.empty((B, n, n))
    for b in range(B):
        for i in range(n):
            for j in range(n):
                a[b, i, j] = 0.5 * (P[b, i, j] + P[b, j, i])
    jacobi_eig_inplace(a, U_out, max_sweeps, np.empty(B, dtype=np.bool_))
    s_out = np.empty((B, n))
    for b in range(B):
        for i in range(n):
            s_out[b, i] = a[b, i, i]
    return s_out, U_out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def jacobi_eig_inplace(
    a: Array, v: Array, max_sweeps: int, converged: NDArray[np.bool_]
) -> None:  # pragma: no cover - jitted
    """Diagonalize the symmetric ``a[b]`` in place by cyclic Jacobi sweeps; ``v[b]`` gets the
    eigenvectors (``a``, ``v``: ``(B, n, n)``; ``converged``: ``(B,)`` scratch).

    A rotation ``J(p, q, theta)`` zeroes ``a_pq`` with ``t = tan(theta)`` the smaller root of
    ``t^2 + 2 t cot(2 theta) - 1 = 0``, ``cot(2 theta) = (a_qq - a_pp) / (2 a_pq)``:
    ``a_pp -= t a_pq``, ``a_qq += t a_pq``, ``(a_kp, a_kq) <- (c a_kp - s a_kq, s a_kp + c a_kq)``,
    and the same on the columns of ``v``. A matrix stops sweeping once its off-diagonal mass
    falls below ``1e-32`` of its diagonal mass (machine precision; quadratic convergence). On
    return the eigenvalues are ``diag(a[b])`` and ``a_in[b] = v[b] diag(a[b]) v[b]^T``.

    The B matrices are swept in lock-step — rotation ``(p, q)`` of every unconverged matrix,
    then the next — so that the B independent dependency chains of square roots and divisions
    overlap in the processor; each matrix gets exactly the rotations it would get alone.
    """
    B, n = a.shape[0], a.shape[1]
    for b in range(B):
        converged[b] = False
        for i in range(n):
            for j in range(n):
                v[b, i, j] = 1.0 if i == j else 0.0
    for _ in range(max_sweeps):
        active = 0
        for b in range(B):
            if converged[b]:
                continue
            off = 0.0
            diag = 0.0
            for p in range(n):
                diag += a[b, p, p] * a[b, p, p]
                for q in range(p + 1, n):
                    off += a[b, p, q] * a[b, p, q]
            converged[b] = off <= 1e-32 * diag
            active += not converged[b]
        if active == 0:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                for b in range(B):
                    apq = a[b, p, q]
                    if converged[b] or apq == 0.0:
                        continue
                    d = a[b, q, q] - a[b, p, p]
                    root = np.sqrt(d * d + 4.0 * apq * apq)
                    t = 2.0 * apq / (d + root if d >= 0.0 else d - root)
                    c = 1.0 / np.sqrt(1.0 + t * t)
                    s = t * c
                    a[b, p, p] -= t * apq
                    a[b, q, q] += t * apq
                    a[b, p, q] = 0.0
                    a[b, q, p] = 0.0
                    for k in range(n):
                        if k != p and k != q:
                            akp = a[b, k, p]
                            akq = a[b, k, q]
                            a[b, k, p] = a[b, p, k] = c * akp - s * akq
                            a[b, k, q] = a[b, q, k] = s * akp + c * akq
                    for k in range(n):
                        vkp = v[b, k, p]
                        vkq = v[b, k, q]
                        v[b, k, p] = c * vkp - s * vkq
                        v[b, k, q] = s * vkp + c * vkq


def inv_logdet(S: Array) -> tuple[Array, Array]:
    """Inverse and log-determinant of symmetric positive definite matrices.

    2x2 blocks (range-bearing, position measurements) use the closed form
    ``S^-1 = [[d, -b], [-b, a]] / (a d - b^2)``; larger blocks a Cholesky factorization.

    Args:
        S: ``(..., m, m)`` symmetric positive definite.

    Returns:
        ``(S^-1, log det S)`` shaped ``(..., m, m)`` and ``(...)``.

    Raises:
        np.linalg.LinAlgError: if a block is not positive definite.
    """
    m = S.shape[-1]
    if m == 2:
        a, b, d = S[..., 0, 0], 0.5 * (S[..., 0, 1] + S[..., 1, 0]), S[..., 1, 1]
        det = a * d - b * b
        if not (np.minimum(a, det) > 0).all():  # also catches NaN
            raise np.linalg.LinAlgError("innovation covariance is not positive definite")
        inv = np.empty_like(S)
        inv[..., 0, 0] = d / det
        inv[..., 1, 1] = a / det
        inv[..., 0, 1] = inv[..., 1, 0] = -b / det
        return inv, np.log(det)
    L = np.linalg.cholesky(S)
    eye = np.broadcast_to(np.eye(m), S.shape)
    L_inv = np.linalg.solve(L, eye)
    inv = np.swapaxes(L_inv, -1, -2) @ L_inv
    logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
    return inv, logdet


def mahalanobis(nu: Array, S_inv: Array) -> Array:
    """Quadratic form ``nu^T S^-1 nu``: ``(..., m), (..., m, m) -> (...)``."""
    return np.einsum("...i,...ij,...j->...", nu, S_inv, nu)
