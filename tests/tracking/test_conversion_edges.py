"""State conversions and the CT/CTRA closed form (:mod:`imm_gym.tracking.conversions`) where
their special cases switch: the G integrals across the series radius, the Jacobian's heading row
near rest, the heading cap at 3 standard deviations of the speed (and none between the Cartesian
spaces)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym.tracking.conversions import conversion, convert, g_integrals


def _gauss_legendre_g(n: int, theta: float) -> complex:
    """``G_n(theta) = int_0^1 tau^n exp(i theta tau) d tau`` by 40-point Gauss-Legendre: exact
    for polynomials of degree 79, so for ``|theta| <= 2`` the only error is the integrand's
    Taylor tail beyond ``tau^79`` (below 1e-90) and rounding."""
    nodes, weights = np.polynomial.legendre.leggauss(40)
    tau = 0.5 * (nodes + 1.0)
    return complex(0.5 * np.sum(weights * tau**n * np.exp(1j * theta * tau)))


@pytest.mark.parametrize(
    "theta", [1e-6, -0.003, 0.02, 0.1, -0.25, 0.3, 0.49, 0.4999, 0.5, 0.51, -0.6, 0.8, 2.0]
)
def test_g_integrals_are_accurate_to_rounding_on_both_sides_of_the_series_radius(
    theta: float,
) -> None:
    """``G_0, G_1, G_2`` to 1e-14 (they are of order 1): the power series below ``|theta| = 0.5``
    summed far enough (its 14th term is 5e-17 at the radius), the recursion
    ``G_n = (e^{i theta} - n G_{n-1}) / (i theta)`` only where its cancellation is small (it
    loses ``n`` factors ``1 / theta``: 5e-12 at ``theta = 0.02``)."""
    for n, g in enumerate(g_integrals(np.array(theta))):
        assert abs(complex(g) - _gauss_legendre_g(n, theta)) < 1e-14, (n, theta)


@pytest.mark.parametrize("v", [1e-4, 3e-5, 2e-6])
def test_heading_row_of_the_jacobian_is_one_over_the_speed_above_v_min(v: float) -> None:
    """Eq. (9) at a slow but moving target (``v`` above ``V_MIN = 1e-6`` m/s): ``d psi / d v_x =
    -v_y / v^2``, ``d psi / d v_y = v_x / v^2`` by hand, and a central difference of ``atan2``
    agrees."""
    ux, uy = 0.6, 0.8
    x = np.array([10.0, -4.0, v * ux, v * uy])
    _, J = conversion(x, "ncv", "ct")
    assert J[3, 2] == pytest.approx(-uy / v, rel=1e-12)
    assert J[3, 3] == pytest.approx(ux / v, rel=1e-12)
    eps = 1e-3 * v
    d_vx = (math.atan2(x[3], x[2] + eps) - math.atan2(x[3], x[2] - eps)) / (2 * eps)
    d_vy = (math.atan2(x[3] + eps, x[2]) - math.atan2(x[3] - eps, x[2])) / (2 * eps)
    np.testing.assert_allclose(J[3, 2:], [d_vx, d_vy], rtol=1e-5)


def test_heading_row_of_the_jacobian_stops_at_v_min_below_it() -> None:
    """Below ``V_MIN = 1e-6`` m/s the heading row is ``(-u_y, u_x) / 1e-6``, finite whatever the
    speed (module docstring), with ``u`` the unit velocity direction."""
    for v in (1e-9, 1e-12):
        _, J = conversion(np.array([0.0, 0.0, 0.0, -v]), "ncv", "ctra")
        np.testing.assert_allclose(J[3, 2:], [1e6, 0.0], rtol=1e-12)


def test_a_speed_of_exactly_three_standard_deviations_is_not_capped() -> None:
    """The heading is capped where the speed is *within* 3 standard deviations of 0
    (``v < 3 sqrt(lambda_max(P_v))``): at ``v = 3`` m/s with ``P_v = I`` the conversion is the
    first-order ``J P J^T``, its heading still correlated with ``y`` (``P_y,vy = 0.5``); a hair
    slower, capped and uncorrelated."""
    P = np.eye(4)
    P[1, 3] = P[3, 1] = 0.5
    for v, capped in ((3.0, False), (math.nextafter(3.0, 0.0), True)):
        x = np.array([0.0, 0.0, v, 0.0])
        _, P_ct = convert(x, P, "ncv", "ct")
        _, J = conversion(x, "ncv", "ct")
        raw = J @ P @ J.T
        assert raw[1, 3] == pytest.approx(0.5 / v, rel=1e-12)  # d psi / d v_y = 1 / v
        assert P_ct[1, 3] == (0.0 if capped else raw[1, 3])
        assert P_ct[3, 3] == pytest.approx(1.0 / v**2, rel=1e-12)


@pytest.mark.parametrize("v", [(0.0, 0.0), (0.01, -0.02), (-30.0, 0.5), (2.0, -40.0)])
def test_ncv_and_cart6_convert_by_selection_whatever_the_speed(v: tuple[float, float]) -> None:
    """Between the Cartesian spaces there is no heading to cap: ``cart6 -> ncv`` keeps the first
    four components and their covariance block, ``ncv -> cart6`` pads with zeros, at rest, slow or
    moving towards -x (a speed test on ``v_x`` would take ``v_y`` for a heading)."""
    rng = np.random.default_rng(4)
    A = rng.normal(size=(6, 6))
    P6 = A @ A.T + 0.1 * np.eye(6)
    x6 = np.array([100.0, -50.0, *v, 0.3, -0.2])
    x4, P4 = convert(x6, P6, "cart6", "ncv")
    np.testing.assert_array_equal(x4, x6[:4])
    np.testing.assert_allclose(P4, P6[:4, :4], rtol=1e-14, atol=0.0)
    x6b, P6b = convert(x6[:4], P6[:4, :4], "ncv", "cart6")
    np.testing.assert_array_equal(x6b, [*x6[:4], 0.0, 0.0])
    expected = np.zeros((6, 6))
    expected[:4, :4] = P6[:4, :4]
    np.testing.assert_allclose(P6b, expected, rtol=1e-14, atol=0.0)
