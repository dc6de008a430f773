"""Motion-model helpers (:mod:`imm_gym.tracking.models`) against values worked by hand or by an
independent quadrature: the turn-noise ratios on both sides of their series threshold, the RMS
velocity noise of a ``Q``."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym.tracking.models import turn_noise_ratios, velocity_noise, white_acceleration_noise


def _ratios_by_quadrature(u: float) -> tuple[float, float]:
    """``S_1 = (1 - cos u) / u^2 = int_0^1 sin(u t) / u dt`` and ``S_2 = (u - sin u) / u^3 =
    int_0^1 2 sin^2(u t / 2) / u^2 dt`` (integrands free of cancellation) by 40-point
    Gauss-Legendre, exact to rounding for ``|u| <= 2``."""
    nodes, weights = np.polynomial.legendre.leggauss(40)
    t, w = 0.5 * (nodes + 1.0), 0.5 * weights
    s1 = np.sum(w * np.sin(u * t) / u)
    s2 = np.sum(w * 2.0 * np.sin(0.5 * u * t) ** 2 / u**2)
    return float(s1), float(s2)


@pytest.mark.parametrize(
    "u", [1e-4, -0.003, 0.011, -0.012, 0.02, 0.03, 0.05, 0.0999, 0.1, 0.1001, 0.3, 1.0, 2.0]
)
def test_turn_noise_ratios_keep_their_digits_on_both_sides_of_the_series_threshold(
    u: float,
) -> None:
    """To 1e-13 relative (the docstring's bound: the closed form loses at most ``6 eps / u^2`` at
    and beyond ``|u| = 0.1``; below it the series). ``u - sin u`` evaluated in closed form at
    ``u = 0.011`` loses 3e-12."""
    s1, s2 = turn_noise_ratios(u)
    r1, r2 = _ratios_by_quadrature(u)
    assert float(s1) == pytest.approx(r1, rel=1e-13, abs=0.0)
    assert float(s2) == pytest.approx(r2, rel=1e-13, abs=0.0)


def test_velocity_noise_is_the_rms_of_both_velocity_variances() -> None:
    """``sqrt((Q_vxvx + Q_vyvy) / 2)`` by hand for a ``Q`` whose axes differ, over any leading
    axes, and ``sqrt(q T)`` for white-noise acceleration of intensity ``q``."""
    Q = np.diag([1.0, 1.0, 0.02, 0.18])
    assert float(velocity_noise(Q)) == pytest.approx(math.sqrt(0.1), rel=1e-15)
    Qs = np.stack([Q, np.diag([5.0, 5.0, 0.5, 0.0]), np.diag([0.1, 0.1, 0.12, 0.12])])
    np.testing.assert_allclose(
        velocity_noise(Qs[None]), [[math.sqrt(0.1), 0.5, math.sqrt(0.12)]], rtol=1e-15
    )
    for omega, T, q in ((0.0, 1.0, 0.12), (math.radians(4.0), 5.0, 0.3), (-0.2, 0.1, 2.0)):
        Qc = white_acceleration_noise(omega, T, q)
        assert float(velocity_noise(Qc)) == pytest.approx(math.sqrt(q * T), rel=1e-14)
