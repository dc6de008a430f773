"""Tests of imm_gym.tracking.linalg: angle wrapping, the Jacobi eigendecomposition, the
Cholesky factor, inverse/log-det, the Mahalanobis quadratic form."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from imm_gym.tracking.linalg import (
    EIG_LANES,
    cholesky_lanes,
    cholesky_psd,
    inv_logdet,
    mahalanobis,
    sym_eig,
    wrap_angle,
)

PI = np.pi


# --------------------------------------------------------------------------- wrap_angle


@pytest.mark.parametrize(
    ("angle", "expected"),
    [
        (0.0, 0.0),
        (PI, PI),
        (-PI, PI),
        (3 * PI, PI),
        (-3 * PI, PI),
        (2 * PI, 0.0),
        (-2 * PI, 0.0),
        (PI / 2, PI / 2),
        (-PI / 2, -PI / 2),
        (1.5 * PI, -0.5 * PI),
        (-1.5 * PI, 0.5 * PI),
        (7.0, 7.0 - 2 * PI),
        (-7.0, -7.0 + 2 * PI),
    ],
)
def test_wrap_angle_values(angle: float, expected: float) -> None:
    got = wrap_angle(np.array(angle))
    assert got == pytest.approx(expected, abs=1e-12)
    assert -PI < got <= PI


@pytest.mark.parametrize(
    "angle",
    [
        # One ulp above np.pi. wrap_angle(-np.pi) == np.pi, so -np.pi is outside the range of
        # wrap_angle by its own convention; this input must not map to -np.pi either.
        np.nextafter(PI, 4.0),
        np.nextafter(PI, 0.0),
        np.nextafter(-PI, -4.0),
        np.nextafter(-PI, 0.0),
        3 * PI,
        np.nextafter(3 * PI, 10.0),
        -1e-300,
        1e-300,
    ],
)
def test_wrap_angle_half_open_interval_at_the_boundary(angle: float) -> None:
    got = float(wrap_angle(np.array(angle)))
    assert -PI < got <= PI
    # The wrapped angle is the same direction.
    assert np.cos(got) == pytest.approx(np.cos(angle), abs=1e-12)
    assert np.sin(got) == pytest.approx(np.sin(angle), abs=1e-12)


def test_wrap_angle_is_idempotent_at_the_boundary() -> None:
    a = np.array([np.nextafter(PI, 4.0), PI, -PI, np.nextafter(-PI, 0.0)])
    w = wrap_angle(a)
    np.testing.assert_array_equal(wrap_angle(w), w)


def test_wrap_angle_random_batch() -> None:
    rng = np.random.default_rng(0)
    a = rng.uniform(-1e4, 1e4, size=(50, 40))
    w = wrap_angle(a)
    assert w.shape == a.shape
    assert np.all(w > -PI)
    assert np.all(w <= PI)
    k = (a - w) / (2 * PI)
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)


# --------------------------------------------------------------------------- sym_eig


def _random_symmetric(rng: np.random.Generator, n: int, pd: bool) -> np.ndarray:
    A = rng.standard_normal((n, n))
    if pd:
        return A @ A.T + 0.1 * np.eye(n)
    return 0.5 * (A + A.T)


def _check_eig(P: np.ndarray) -> None:
    s, U = sym_eig(P)
    n = P.shape[-1]
    assert s.shape == P.shape[:-1]
    assert U.shape == P.shape
    scale = max(1.0, float(np.abs(P).max()))
    recon = U @ (s[..., :, None] * np.swapaxes(U, -1, -2))
    np.testing.assert_allclose(recon, P, atol=1e-10 * scale, rtol=0)
    eye = np.broadcast_to(np.eye(n), P.shape)
    np.testing.assert_allclose(np.swapaxes(U, -1, -2) @ U, eye, atol=1e-12)
    np.testing.assert_allclose(
        np.sort(s, axis=-1), np.linalg.eigvalsh(P), atol=1e-10 * scale, rtol=0
    )


@pytest.mark.parametrize("n", [4, 6])
@pytest.mark.parametrize("pd", [True, False], ids=["pd", "indefinite"])
def test_sym_eig_random(n: int, pd: bool) -> None:
    rng = np.random.default_rng(100 + n + pd)
    for _ in range(20):
        _check_eig(_random_symmetric(rng, n, pd))


@pytest.mark.parametrize("n", [4, 6])
def test_sym_eig_batched_matches_single(n: int) -> None:
    rng = np.random.default_rng(n)
    P = np.stack([_random_symmetric(rng, n, True) for _ in range(12)]).reshape(3, 4, n, n)
    _check_eig(P)
    s, U = sym_eig(P)
    s1, U1 = sym_eig(P[1, 2])
    np.testing.assert_array_equal(s[1, 2], s1)
    np.testing.assert_array_equal(U[1, 2], U1)


def test_sym_eig_degenerate_eigenvalues() -> None:
    P = np.diag([2500.0, 2500.0, 25.0, 25.0])
    _check_eig(P)
    s, _ = sym_eig(P)
    np.testing.assert_allclose(np.sort(s), [25.0, 25.0, 2500.0, 2500.0])
    # Rotated copy: same spectrum, off-diagonal entries everywhere.
    rng = np.random.default_rng(7)
    Qm, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    _check_eig(Qm @ P @ Qm.T)


@pytest.mark.parametrize("tiny", [1e-150, 1e-200, 1e-296, 5e-324])
def test_sym_eig_of_equal_diagonals_and_a_tiny_coupling(tiny: float) -> None:
    """Equal diagonal entries and an off-diagonal entry whose square underflows: the rotation's
    ``sqrt(d^2 + 4 a_pq^2)`` was 0 and its tangent ``2 a_pq / 0`` infinite, so every eigenvalue
    came out NaN; the eigenvalues are ``2600.3 ± tiny`` and the others'."""
    P = np.diag([2600.3, 2600.3, 25.24, 25.24])
    P[0, 2] = P[2, 0] = P[1, 3] = P[3, 1] = 50.12
    P[0, 1] = P[1, 0] = tiny
    _check_eig(P)
    s, _ = sym_eig(P)
    np.testing.assert_allclose(np.sort(s), np.linalg.eigvalsh(P), rtol=1e-12)


def test_sym_eig_indefinite() -> None:
    P = np.array(
        [
            [4.0, 1.0, 0.0, 2.0],
            [1.0, -3.0, 0.5, 0.0],
            [0.0, 0.5, 1.0, -1.0],
            [2.0, 0.0, -1.0, -2.0],
        ]
    )
    _check_eig(P)
    s, _ = sym_eig(P)
    assert s.min() < 0 < s.max()


def test_sym_eig_badly_scaled_covariance() -> None:
    # A tracker covariance: position ~ 1e4 m^2, velocity ~ 1 (m/s)^2, correlated.
    P = np.array(
        [
            [2.5e3, 1.2e3, 40.0, 10.0],
            [1.2e3, 9.0e3, 5.0, 60.0],
            [40.0, 5.0, 2.0, 0.3],
            [10.0, 60.0, 0.3, 3.0],
        ]
    )
    _check_eig(P)


def test_sym_eig_uses_symmetric_part() -> None:
    rng = np.random.default_rng(3)
    A = rng.standard_normal((4, 4))
    s, _ = sym_eig(A)
    np.testing.assert_allclose(np.sort(s), np.linalg.eigvalsh(0.5 * (A + A.T)), atol=1e-12)


def _hard_matrices(rng: np.random.Generator) -> list[np.ndarray]:
    """Matrices that stop sweeping early or late: diagonal, zero, degenerate, ill-conditioned,
    indefinite, random SPD, and one with a NaN (never converges: all sweeps)."""
    Qm, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    nan = _random_symmetric(rng, 4, True)
    nan[0, 1] = nan[1, 0] = np.nan
    return [
        np.diag([4.0, 3.0, 2.0, 1.0]),
        np.zeros((4, 4)),
        np.diag([2500.0, 2500.0, 25.0, 25.0]),
        Qm @ np.diag([2500.0, 2500.0, 25.0, 25.0]) @ Qm.T,
        Qm @ np.diag([1e8, 1.0, 1e-4, 1e-8]) @ Qm.T,
        _random_symmetric(rng, 4, False),
        nan,
        *(_random_symmetric(rng, 4, True) for _ in range(5)),
    ]


def test_sym_eig_lanes_do_not_interact() -> None:
    # More than two calls' worth of lanes, the hard cases spread over them: every matrix gets
    # bit for bit what it gets alone, whatever its neighbours (converged or not) do.
    rng = np.random.default_rng(11)
    hard = _hard_matrices(rng)
    P = np.stack([hard[i % len(hard)] for i in range(2 * EIG_LANES + 7)])
    P[len(hard) :: 5] = np.stack([_random_symmetric(rng, 4, True) for _ in P[len(hard) :: 5]])
    s, U = sym_eig(P)
    for i in range(P.shape[0]):
        s1, U1 = sym_eig(P[i])
        np.testing.assert_array_equal(s[i], s1)
        np.testing.assert_array_equal(U[i], U1)
    finite = np.isfinite(P).all(axis=(-1, -2))
    assert not finite.all()
    for i in np.flatnonzero(finite)[:40]:
        _check_eig(P[i])


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    log_spread=st.floats(0.0, 10.0),
    n=st.sampled_from([4, 6]),
)
def test_sym_eig_matches_eigh_on_random_covariances(seed: int, log_spread: float, n: int) -> None:
    # Random orthogonal basis and eigenvalues spread over up to 10 decades (tracker covariances
    # mix m^2 and (m/s)^2), some of them repeated.
    rng = np.random.default_rng(seed)
    Qm, _ = np.linalg.qr(rng.standard_normal((n, n)))
    eigenvalues = 10.0 ** rng.uniform(-log_spread / 2, log_spread / 2, n)
    eigenvalues[rng.random(n) < 0.2] = eigenvalues[0]
    P = (Qm * eigenvalues) @ Qm.T
    P = 0.5 * (P + P.T)
    _check_eig(P)
    s, _ = sym_eig(P)
    np.testing.assert_allclose(
        np.sort(s), np.linalg.eigh(P)[0], rtol=0, atol=1e-12 * eigenvalues.max()
    )


# --------------------------------------------------------------------------- cholesky


def _random_covariance(rng: np.random.Generator, n: int, log_spread: float) -> np.ndarray:
    Qm, _ = np.linalg.qr(rng.standard_normal((n, n)))
    P = (Qm * 10.0 ** rng.uniform(-log_spread / 2, log_spread / 2, n)) @ Qm.T
    return 0.5 * (P + P.T)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    log_spread=st.floats(0.0, 8.0),
    n=st.sampled_from([2, 4, 5, 6]),
)
def test_cholesky_psd_factors_a_covariance(seed: int, log_spread: float, n: int) -> None:
    P = _random_covariance(np.random.default_rng(seed), n, log_spread)
    L = cholesky_psd(P)
    np.testing.assert_array_equal(L, np.tril(L))
    assert np.all(np.diag(L) > 0)
    np.testing.assert_allclose(L @ L.T, P, rtol=0, atol=1e-12 * np.abs(P).max())
    np.testing.assert_allclose(L, np.linalg.cholesky(P), rtol=1e-8, atol=1e-12 * np.abs(L).max())


def test_cholesky_psd_batched_and_lower_triangle_only() -> None:
    rng = np.random.default_rng(3)
    P = np.stack([_random_covariance(rng, 4, 4.0) for _ in range(6)]).reshape(2, 3, 4, 4)
    L = cholesky_psd(P)
    assert L.shape == P.shape
    np.testing.assert_array_equal(L[1, 2], cholesky_psd(P[1, 2]))
    upper_changed = P + np.triu(np.full((4, 4), 7.0), 1)  # read: the diagonal and below
    np.testing.assert_array_equal(cholesky_psd(upper_changed), L)


def test_cholesky_psd_of_a_singular_or_indefinite_matrix_has_zero_columns() -> None:
    P = np.diag([100.0, 0.0, 1.0, 1.0])
    L = cholesky_psd(P)
    np.testing.assert_array_equal(L, np.diag([10.0, 0.0, 1.0, 1.0]))
    rng = np.random.default_rng(13)
    Qm, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    indefinite = Qm @ np.diag([400.0, 100.0, 4.0, -1e-3]) @ Qm.T
    indefinite = 0.5 * (indefinite + indefinite.T)
    L = cholesky_psd(indefinite)
    assert np.all(np.isfinite(L)) and L[3, 3] == 0.0


@numba.njit
def _lanes(P: np.ndarray, lanes: int) -> np.ndarray:
    L = np.full_like(P, np.nan)
    cholesky_lanes(P, L, lanes, np.empty(P.shape[2]), np.empty(P.shape[2]))
    return L


@pytest.mark.parametrize("n", [2, 4, 6])
def test_cholesky_lanes_equals_cholesky_psd_bit_for_bit(n: int) -> None:
    rng = np.random.default_rng(n)
    P = np.stack([_random_covariance(rng, n, 6.0) for _ in range(11)])
    P[4] = np.diag(np.arange(n, dtype=float))  # a zero pivot
    lanes = np.ascontiguousarray(np.moveaxis(P, 0, -1))  # (n, n, lanes)
    L = np.moveaxis(_lanes(lanes, 10), -1, 0)
    np.testing.assert_array_equal(L[:10], cholesky_psd(P[:10]))
    assert np.isnan(L[10]).all()  # lanes past ``lanes`` untouched


# --------------------------------------------------------------------------- inv_logdet


@pytest.mark.parametrize("m", [2, 4])
def test_inv_logdet_matches_numpy(m: int) -> None:
    rng = np.random.default_rng(m)
    A = rng.standard_normal((5, 3, m, m))
    S = A @ np.swapaxes(A, -1, -2) + 0.5 * np.eye(m)
    S_inv, logdet = inv_logdet(S)
    assert S_inv.shape == S.shape
    assert logdet.shape == S.shape[:-2]
    np.testing.assert_allclose(S_inv, np.linalg.inv(S), rtol=1e-10, atol=1e-12)
    sign, ref = np.linalg.slogdet(S)
    assert np.all(sign == 1)
    np.testing.assert_allclose(logdet, ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("m", [2, 4])
def test_inv_logdet_scaled(m: int) -> None:
    # Range-bearing scales: 2500 m^2 and 1e-6 rad^2.
    rng = np.random.default_rng(10 + m)
    d = np.array([2500.0, 7.6e-7, 30.0, 1.0])[:m]
    C = rng.standard_normal((m, m))
    S = np.diag(np.sqrt(d)) @ (C @ C.T + np.eye(m)) @ np.diag(np.sqrt(d))
    S_inv, logdet = inv_logdet(S)
    np.testing.assert_allclose(S_inv @ S, np.eye(m), atol=1e-9)
    np.testing.assert_allclose(logdet, np.linalg.slogdet(S)[1], rtol=1e-12)


@pytest.mark.parametrize(
    "S",
    [
        np.array([[1.0, 2.0], [2.0, 1.0]]),  # indefinite
        np.array([[-1.0, 0.0], [0.0, -1.0]]),  # negative definite (det > 0, a < 0)
        np.array([[1.0, 1.0], [1.0, 1.0]]),  # singular
    ],
    ids=["indefinite", "negative", "singular"],
)
def test_inv_logdet_rejects_non_pd_2x2(S: np.ndarray) -> None:
    with pytest.raises(np.linalg.LinAlgError):
        inv_logdet(S)


def test_inv_logdet_rejects_non_pd_4x4() -> None:
    with pytest.raises(np.linalg.LinAlgError):
        inv_logdet(np.diag([1.0, 2.0, -1.0, 3.0]))


# --------------------------------------------------------------------------- mahalanobis


@pytest.mark.parametrize("m", [2, 3, 4])
@pytest.mark.parametrize("inner", [(), (3,)], ids=["rows", "rows-of-models"])
def test_mahalanobis_of_a_row_does_not_depend_on_the_batch(m: int, inner: tuple[int, ...]) -> None:
    """Each row's ``nu^T S^-1 nu`` is the same bit for bit in a batch of 1..5 rows as in the
    batch of 5 (a run's NIS in a core of its own, a shard's chunk, equals its NIS among others),
    and is the quadratic form."""
    rng = np.random.default_rng(m)
    for _ in range(50):
        nu = rng.standard_normal((5, *inner, m)) * 10.0 ** rng.uniform(-3, 3)
        A = rng.standard_normal((5, *inner, m, m))
        S_inv = np.linalg.inv(A @ np.swapaxes(A, -1, -2) + np.eye(m))
        full = mahalanobis(nu, S_inv)
        for n in range(1, 6):
            for start in range(6 - n):
                rows = slice(start, start + n)
                np.testing.assert_array_equal(mahalanobis(nu[rows], S_inv[rows]), full[rows])
        for i in range(5):
            np.testing.assert_array_equal(mahalanobis(nu[i], S_inv[i]), full[i])
        expected = np.einsum("...i,...i->...", nu, np.einsum("...ij,...j->...i", S_inv, nu))
        np.testing.assert_allclose(full, expected, rtol=1e-12)


def test_kernel_wrap_equals_wrap_angle() -> None:
    from imm_gym.tracking.kernels.imm import _wrap

    rng = np.random.default_rng(0)
    special = [PI, -PI, 3 * PI, -3 * PI, np.nextafter(PI, 4.0), np.nextafter(-PI, -4.0), 0.0]
    values = np.concatenate([special, rng.uniform(-20.0, 20.0, 2000), rng.uniform(-7, 7, 2000)])
    expected = wrap_angle(values)
    got = np.array([_wrap(float(v)) for v in values])
    assert np.all((got > -PI) & (got <= PI))
    # the same angle: at the boundary one ulp above pi is -pi + ulp here, pi in numpy's modulo
    np.testing.assert_allclose(np.sin(got), np.sin(expected), atol=1e-12)
    np.testing.assert_allclose(np.cos(got), np.cos(expected), atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sym_eig_of_a_covariance_whose_squares_underflow(seed: int) -> None:
    """A 4x4 covariance scaled by 1e-150: its rotations' roots ``sqrt(d^2 + 4 a_pq^2)`` fall below
    the 1e-140 under which squares may underflow, so they are retaken as ``hypot(a_qq - a_pp,
    2 a_pq)``. The eigenvalues still equal 1e-150 times LAPACK's of the unscaled matrix to
    1e-12, and ``U diag(s) U^T`` rebuilds the matrix with orthonormal ``U``."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(4, 4))
    A = A @ A.T + np.eye(4)
    P = 1e-150 * A
    s, U = sym_eig(P)
    np.testing.assert_allclose(np.sort(s), 1e-150 * np.linalg.eigvalsh(A), rtol=1e-12, atol=0)
    recon = U @ np.diag(s) @ U.T
    np.testing.assert_allclose(recon, P, rtol=0, atol=1e-13 * np.abs(P).max())
    np.testing.assert_allclose(U.T @ U, np.eye(4), atol=1e-12)
