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
#: Matrices that :func:`sym_eig` diagonalizes per call of :func:`jacobi_eig_lanes` (a multiple
#: of the 8 doubles of an AVX-512 register).
EIG_LANES = 96


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
    method (Golub & Van Loan §8.5), compiled with numba and vectorized across matrices
    (:func:`jacobi_eig_lanes`): for the 4x4 to 6x6 blocks of a tracker it is several times faster
    than LAPACK's per-matrix call, and each matrix's result does not depend on the batch it is in
    (bit-identical scalar and vector envs).
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


def cholesky_psd(P: Array) -> Array:
    """Lower-triangular ``L`` with ``P = L L^T`` of symmetric positive semi-definite matrices.

    Column by column (Cholesky-Banachiewicz, Golub & Van Loan §4.2):
    ``L_cc = sqrt(max(P_cc - sum_{k<c} L_ck^2, 0))``,
    ``L_rc = (P_rc - sum_{k<c} L_rk L_ck) / L_cc`` for ``r > c``. A pivot that rounding has
    made zero or negative (``P`` lost definiteness) gives a zero column instead of failing: the
    Cholesky UKF then draws no sigma points along that direction (the SVD-UKF takes ``|s|``).
    The lower triangle of ``P`` is read. :func:`cholesky_lanes` is the same in compiled code.

    Args:
        P: ``(..., n, n)``.

    Returns:
        ``L`` of the same shape, zero above the diagonal.
    """
    n = P.shape[-1]
    L = np.zeros_like(P, dtype=np.float64)
    for c in range(n):  # the sums term by term, in the compiled loops' order
        d = P[..., c, c]
        for k in range(c):
            d = d - L[..., c, k] * L[..., c, k]
        pivot = np.sqrt(np.maximum(d, 0.0))
        L[..., c, c] = pivot
        inverse = np.divide(1.0, pivot, out=np.zeros_like(pivot), where=pivot > 0.0)
        for r in range(c + 1, n):
            v = P[..., r, c]
            for k in range(c):
                v = v - L[..., r, k] * L[..., c, k]
            L[..., r, c] = v * inverse
    return L


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def cholesky_lanes(
    P: Array, L: Array, lanes: int, pivot: Array, inverse: Array
) -> None:  # pragma: no cover - jitted
    """:func:`cholesky_psd` of the lanes ``i < lanes`` of ``P (n, n, lanes+)`` into ``L`` (the
    lane index innermost: every loop runs across matrices; ``pivot``, ``inverse``: ``(lanes+,)``
    scratch)."""
    n = P.shape[0]
    for c in range(n):
        for i in range(lanes):
            pivot[i] = P[c, c, i]
        for k in range(c):
            for i in range(lanes):
                pivot[i] -= L[c, k, i] * L[c, k, i]
        for i in range(lanes):
            pivot[i] = np.sqrt(max(pivot[i], 0.0))
            L[c, c, i] = pivot[i]
            inverse[i] = 1.0 / pivot[i] if pivot[i] > 0.0 else 0.0
        for r in range(c + 1, n):
            for i in range(lanes):
                L[r, c, i] = P[r, c, i]
            for k in range(c):
                for i in range(lanes):
                    L[r, c, i] -= L[r, k, i] * L[c, k, i]
            for i in range(lanes):
                L[r, c, i] = L[r, c, i] * inverse[i]
                L[c, r, i] = 0.0


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _jacobi_eig(P: Array, max_sweeps: int) -> tuple[Array, Array]:  # pragma: no cover - jitted
    """:func:`jacobi_eig_lanes` on the ``(n, n)`` blocks of ``P`` (shape ``(B, n, n)``),
    ``EIG_LANES`` at a time; returns ``s (B, n)`` and ``U (B, n, n)``."""
    B, n, _ = P.shape
    a = np.empty((n, n, EIG_LANES))
    v = np.empty((n, n, EIG_LANES))
    s_out = np.empty((B, n))
    U_out = np.empty((B, n, n))
    for b0 in range(0, B, EIG_LANES):
        lanes = min(EIG_LANES, B - b0)
        for i in range(n):
            for j in range(i, n):
                for lane in range(lanes):
                    a[i, j, lane] = 0.5 * (P[b0 + lane, i, j] + P[b0 + lane, j, i])
        jacobi_eig_lanes(a, v, lanes, max_sweeps)
        for lane in range(lanes):
            for i in range(n):
                s_out[b0 + lane, i] = a[i, i, lane]
                for j in range(n):
                    U_out[b0 + lane, i, j] = v[i, j, lane]
    return s_out, U_out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def jacobi_eig_lanes(
    a: Array, v: Array, lanes: int, max_sweeps: int
) -> None:  # pragma: no cover - jitted
    """Diagonalize the symmetric matrices ``a[:, :, l]``, ``l < lanes``, in place by Jacobi
    sweeps in the parallel (Brent-Luk round-robin) order; ``v[:, :, l]`` gets their eigenvectors
    (``a``, ``v``: ``(n, n, L)``, the matrices side by side along the last, contiguous axis: one
    SIMD lane per matrix).

    Only the upper triangle of ``a`` is read and updated. A rotation ``J(p, q, theta)`` zeroes
    ``a_pq`` with ``t = tan(theta)`` the smaller root of ``t^2 + 2 t cot(2 theta) - 1 = 0``,
    ``cot(2 theta) = (a_qq - a_pp) / (2 a_pq)``: ``a_pp -= t a_pq``, ``a_qq += t a_pq``,
    ``(a_kp, a_kq) <- (c a_kp - s a_kq, s a_kp + c a_kq)`` with ``c = 1 / sqrt(1 + t^2)``,
    ``s = t c``, and the same on the columns of ``v``. A sweep is ``n - 1`` rounds (``n`` even;
    one more, with a idle index, for ``n`` odd) of ``n / 2`` rotations on disjoint index pairs
    (Golub & Van Loan §8.5.5): the rotations of a round commute, so their rotation parameters
    are computed together from the round's start (one pass over the lanes) and applied one
    after the other. A matrix stops sweeping once its off-diagonal mass falls below ``1e-32`` of
    its diagonal mass (machine precision; quadratic convergence). On return the eigenvalues are
    ``diag(a[:, :, l])`` and ``a_in = v diag(a) v^T``.

    Each step is one loop over the lanes that the compiler vectorizes. A converged lane, or one
    whose ``a_pq`` is already 0, gets the identity rotation (``c = 1``, ``s = t = 0``: every
    update returns its input exactly) and keeps its ``a_pq``: each matrix gets exactly the
    rotations and the rounding it would get alone, so its result does not depend on the other
    lanes.
    """
    n = a.shape[0]
    half = (n + n % 2) // 2
    jacobi_sweeps(
        a,
        v,
        lanes,
        max_sweeps,
        np.empty(lanes, dtype=np.bool_),
        np.empty(lanes),
        np.empty(lanes),
        np.empty((half, lanes)),
        np.empty((half, lanes)),
        np.empty((half, 2), dtype=np.int64),
        np.empty((2, lanes)),
    )


def _jacobi_sweeps(
    a: Array,
    v: Array,
    lanes: int,
    max_sweeps: int,
    converged: NDArray[np.bool_],
    off: Array,
    diag: Array,
    c: Array,
    s: Array,
    pairs: NDArray[np.int64],
    old: Array,
) -> None:  # pragma: no cover - jitted
    """:func:`jacobi_eig_lanes` with its scratch passed in (for a caller that diagonalizes
    block after block: no allocations per block): ``converged``, ``off``, ``diag`` of at least
    ``lanes`` entries, ``c``, ``s`` ``(half, >= lanes)``, ``pairs`` ``(half, 2)`` int64, ``old``
    ``(2, >= lanes)``, ``half = ceil(n / 2)``."""
    n = a.shape[0]
    n_even = n + n % 2
    for i in range(n):
        for j in range(n):
            for lane in range(lanes):
                v[i, j, lane] = 1.0 if i == j else 0.0
    for _ in range(max_sweeps):
        if _mark_converged(a, lanes, converged, off, diag) == lanes:
            break
        for r in range(n_even - 1):
            npairs = _round_pairs(n, r, pairs)
            for k in range(npairs):
                _rotation(a, pairs[k, 0], pairs[k, 1], lanes, converged, k, c, s)
            for k in range(npairs):
                p, q = pairs[k, 0], pairs[k, 1]
                for i in range(n):
                    if i != p and i != q:
                        _rotate_lanes(
                            a, min(i, p), max(i, p), min(i, q), max(i, q), lanes, k, c, s, old
                        )
                for i in range(n):
                    _rotate_lanes(v, i, p, i, q, lanes, k, c, s, old)


#: :func:`_jacobi_sweeps` compiled as a function of its own (its lane loops vectorize best
#: apart from a large caller)
jacobi_sweeps = numba.njit(cache=True, nogil=True, error_model="numpy")(_jacobi_sweeps)
#: the same sweeps inlined into a compiled caller, which compiles them with its own constants
#: (one tracker: lane count and size known, every loop unrolled)
jacobi_sweeps_inlined = numba.njit(nogil=True, error_model="numpy", inline="always")(
    _jacobi_sweeps
)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _round_pairs(n: int, r: int, pairs: NDArray[np.int64]) -> int:  # pragma: no cover - jitted
    """Index pairs ``(p < q)`` of round ``r`` of the round-robin tournament on ``n`` indices
    (circle method: index 0 fixed, the others rotated by ``r``; for odd ``n`` the pair with the
    idle index ``n`` is dropped), into ``pairs``; returns their number."""
    n_even = n + n % 2
    count = 0
    for i in range(n_even // 2):
        p = 0 if i == 0 else (i - 1 + r) % (n_even - 1) + 1
        q = (n_even - 2 - i + r) % (n_even - 1) + 1
        if p < n and q < n:
            pairs[count, 0] = min(p, q)
            pairs[count, 1] = max(p, q)
            count += 1
    return count


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _mark_converged(
    a: Array, lanes: int, converged: NDArray[np.bool_], off: Array, diag: Array
) -> int:  # pragma: no cover - jitted
    """``converged[l] = sum_{p<q} a_pq^2 <= 1e-32 sum_p a_pp^2`` (upper triangle of lane ``l``;
    ``off``, ``diag`` scratch); returns the number of converged lanes."""
    n = a.shape[0]
    for lane in range(lanes):
        off[lane] = 0.0
        diag[lane] = 0.0
    for p in range(n):
        for lane in range(lanes):
            diag[lane] += a[p, p, lane] * a[p, p, lane]
        for q in range(p + 1, n):
            for lane in range(lanes):
                off[lane] += a[p, q, lane] * a[p, q, lane]
    count = 0
    for lane in range(lanes):
        converged[lane] = off[lane] <= 1e-32 * diag[lane]
        count += converged[lane]
    return count


#: Below this, :func:`_rotation`'s ``sqrt(d^2 + 4 a_pq^2)`` is taken by ``hypot``, which does not
#: underflow (the squares of entries below about 1e-154 do); above, the plain form keeps its bits.
_UNDERFLOW_ROOT = 1e-140


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _rotation(
    a: Array, p: int, q: int, lanes: int, converged: NDArray[np.bool_], k: int, c: Array, s: Array
) -> None:  # pragma: no cover - jitted
    """The Jacobi rotation ``(c[k], s[k])`` that zeroes ``a_pq`` of each lane, applied to ``a_pp``,
    ``a_qq``, ``a_pq`` (see :func:`jacobi_eig_lanes`); the identity in the lanes left as they
    are (converged, or ``a_pq = 0``).

    ``root = sqrt(d^2 + 4 a_pq^2)`` is taken in a pass of its own (held in ``s[k]`` until the
    sine overwrites it) and retaken by ``hypot`` in the rare lanes where the squares may have
    underflowed: a branch inside the main loop kept it from vectorizing (20 % of the UKF
    kernel)."""
    small = 0
    for lane in range(lanes):
        d = a[q, q, lane] - a[p, p, lane]
        apq = a[p, q, lane]
        s[k, lane] = np.sqrt(d * d + 4.0 * apq * apq)
        small += s[k, lane] < _UNDERFLOW_ROOT
    if small:  # d^2 or apq^2 may have underflowed (root 0: t = inf)
        for lane in range(lanes):
            if s[k, lane] < _UNDERFLOW_ROOT:
                s[k, lane] = np.hypot(a[q, q, lane] - a[p, p, lane], 2.0 * a[p, q, lane])
    for lane in range(lanes):
        apq = a[p, q, lane]
        app = a[p, p, lane]
        aqq = a[q, q, lane]
        skip = converged[lane] | (apq == 0.0)
        d = aqq - app
        root = s[k, lane]
        t = 2.0 * apq / (d + root if d >= 0.0 else d - root)
        t = 0.0 if skip else t
        cos = 1.0 / np.sqrt(1.0 + t * t)
        c[k, lane] = cos
        s[k, lane] = t * cos
        a[p, p, lane] = app - t * apq
        a[q, q, lane] = aqq + t * apq
        a[p, q, lane] = apq if skip else 0.0


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _rotate_lanes(
    x: Array, i: int, j: int, k: int, l: int, lanes: int, r: int, c: Array, s: Array, old: Array
) -> None:  # pragma: no cover - jitted
    """``(x_ij, x_kl) <- (c x_ij - s x_kl, s x_ij + c x_kl)`` in every lane (rotation ``r``:
    ``c[r]``, ``s[r]``).

    Through a copy of the two rows in ``old`` (``(2, L)`` scratch): each loop then writes one row
    of ``x`` and reads other rows, which the compiler vectorizes; reading and writing both rows of
    ``x`` in one loop, at a distance it cannot see, ran scalar (perf: 21 % of the UKF kernel).
    """
    for lane in range(lanes):
        old[0, lane] = x[i, j, lane]
        old[1, lane] = x[k, l, lane]
    for lane in range(lanes):
        x[i, j, lane] = c[r, lane] * old[0, lane] - s[r, lane] * old[1, lane]
    for lane in range(lanes):
        x[k, l, lane] = s[r, lane] * old[0, lane] + c[r, lane] * old[1, lane]


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
    """Quadratic form ``nu^T S^-1 nu``: ``(..., m), (..., m, m) -> (...)``.

    ``S^-1 nu`` as one matrix-vector product per block, then the sum of ``nu * S^-1 nu`` over
    its last axis (as the filters' NIS): each block's value is the same bit for bit whatever
    the leading axes hold (a three-operand ``einsum`` rounded a batch of one otherwise than a
    larger batch, so a run's NIS depended on how many runs shared its core).
    """
    return np.sum(nu * (S_inv @ nu[..., None])[..., 0], axis=-1)
