"""Property tests (hypothesis): the IMM cycle keeps probabilities and covariances valid."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from imm_gym import IMM, IMMState, Sonar, paper_bank, stay_tpm
from imm_gym.tracking.linalg import wrap_angle

PI = math.pi
SONAR = Sonar()
BANK = paper_bank()
IMMS = {engine: IMM(BANK, SONAR, engine=engine) for engine in ("numpy", "compiled")}

positive = st.floats(min_value=1e-3, max_value=1.0, allow_nan=False)
probability_vectors = st.lists(positive, min_size=3, max_size=3).map(
    lambda v: np.array(v) / np.sum(v)
)
tpms = st.lists(probability_vectors, min_size=3, max_size=3).map(np.array)


@st.composite
def covariances(draw: st.DrawFn) -> np.ndarray:
    """Random PD 4x4: position std 1-200 m, velocity std 0.1-20 m/s, random correlations."""
    pos_std = draw(st.lists(st.floats(1.0, 200.0), min_size=2, max_size=2))
    vel_std = draw(st.lists(st.floats(0.1, 20.0), min_size=2, max_size=2))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((4, 4))
    C = A @ A.T + 0.2 * np.eye(4)
    d = 1.0 / np.sqrt(np.diag(C))
    std = np.array(pos_std + vel_std)
    P = (std[:, None] * std[None, :]) * (d[:, None] * C * d[None, :])
    return 0.5 * (P + P.T)


@st.composite
def imm_inputs(draw: st.DrawFn):
    rng_m = draw(st.floats(1000.0, 10000.0))
    bearing = draw(st.floats(-PI, PI))
    speed = draw(st.floats(0.0, 30.0))
    heading = draw(st.floats(-PI, PI))
    base = np.array(
        [
            rng_m * math.cos(bearing),
            rng_m * math.sin(bearing),
            speed * math.cos(heading),
            speed * math.sin(heading),
        ]
    )
    Ps = np.stack([draw(covariances()) for _ in range(3)])
    # model-conditioned means differ by up to ~2 standard deviations (exercises the spread terms)
    offsets = np.array(draw(st.lists(st.floats(-2.0, 2.0), min_size=12, max_size=12)))
    xs = base + offsets.reshape(3, 4) * np.sqrt(np.diagonal(Ps, axis1=-2, axis2=-1))
    mu = draw(probability_vectors)
    tpm = draw(tpms)
    noise = np.array(draw(st.lists(st.floats(-4.0, 4.0), min_size=2, max_size=2)))
    z = SONAR.wrap(SONAR.h(base) + noise * SONAR.sigma)
    return xs, Ps, mu, tpm, z


def _assert_pd(P: np.ndarray) -> None:
    np.testing.assert_allclose(P, np.swapaxes(P, -1, -2), rtol=1e-12, atol=1e-9)
    assert np.all(np.linalg.eigvalsh(P) > 0)


@pytest.mark.parametrize("engine", IMMS)
@settings(max_examples=50, deadline=None)
@given(inputs=imm_inputs())
def test_imm_step_keeps_probabilities_and_covariances_valid(engine, inputs) -> None:
    xs, Ps, mu, tpm, z = inputs
    state = IMMState(x=xs[None], P=Ps[None], mu=mu[None])
    new, out = IMMS[engine].step(state, tpm, z[None])
    for name, a in [
        ("x", out.x),
        ("P", out.P),
        ("mode_probs", out.mode_probs),
        ("cbar", out.cbar),
        ("loglik", out.loglik),
        ("model_nis", out.model_nis),
        ("nis", out.nis),
        ("state.x", new.x),
        ("state.P", new.P),
    ]:
        assert np.all(np.isfinite(a)), name
    for p in (out.mode_probs, new.mu, out.cbar):
        assert np.all(p >= 0.0) and np.all(p <= 1.0)
        assert p.sum() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(out.cbar[0], mu @ tpm, rtol=1e-12)
    _assert_pd(out.P[0])
    for j in range(3):
        _assert_pd(new.P[0, j])
    assert np.all(out.model_nis >= 0) and np.all(out.nis >= 0)


@settings(max_examples=50, deadline=None)
@given(n=st.integers(1, 12), stay=st.floats(0.0, 1.0))
def test_stay_tpm_rows_sum_to_one(n: int, stay: float) -> None:
    tpm = stay_tpm(n, stay)
    assert tpm.shape == (n, n)
    np.testing.assert_allclose(tpm.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(tpm >= 0.0)
    if n > 1:
        np.testing.assert_allclose(np.diag(tpm), stay)


@settings(max_examples=50, deadline=None)
@given(a=st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False))
@example(a=PI)
@example(a=-PI)
@example(a=3 * PI)
@example(a=float(np.nextafter(PI, 4.0)))
def test_wrap_angle_range(a: float) -> None:
    w = float(wrap_angle(np.array(a)))
    assert -PI < w <= PI
    # same direction: a - w is a multiple of 2 pi (to the rounding of a)
    k = (a - w) / (2 * PI)
    assert abs(k - round(k)) < 1e-9 + 1e-15 * abs(a)


bearings = st.floats(-1e3, 1e3).map(lambda a: float(wrap_angle(np.array(a))))


@settings(max_examples=50, deadline=None)
@given(
    a=st.tuples(st.floats(0.0, 1e5), bearings),
    b=st.tuples(st.floats(0.0, 1e5), bearings),
)
def test_sonar_residual_range(a: tuple[float, float], b: tuple[float, float]) -> None:
    d = SONAR.residual(np.array([a]), np.array([b]))[0]
    assert d[0] == a[0] - b[0]
    assert -PI < d[1] <= PI
    assert math.cos(d[1]) == pytest.approx(math.cos(a[1] - b[1]), abs=1e-9)
    assert math.sin(d[1]) == pytest.approx(math.sin(a[1] - b[1]), abs=1e-9)
