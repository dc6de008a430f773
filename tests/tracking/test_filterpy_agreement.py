"""imm_gym's IMM against an independent implementation: FilterPy's ``IMMEstimator`` over three
``UnscentedKalmanFilter``s, on one 150-step sonar episode of the paper scenario.

Both run the same bank (``paper_bank()``: CV, CT(+4°/s), CT(-4°/s)), the same TPM
(``0.995`` on the diagonal, ``0.0025`` off it), ``mu0 = 1/3`` each, the same scaled sigma points
(``alpha = 1, beta = 2, kappa = 0``) drawn from the symmetric square root of ``(n + lambda) P``
(from its SVD) and the
same initial state and covariance (:func:`imm_gym.tracking.initiation.initiate`). FilterPy's UKF
``predict`` propagates the sigma points of the mixed covariance through ``F_j`` (exact for a linear
model: ``F_j x``, ``F_j P F_j^T + Q_j``) and redraws them from the predicted covariance, as
imm_gym's update does; the bearing residual is wrapped to (-pi, pi].
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import IMMEstimator, MerweScaledSigmaPoints
from filterpy.kalman import UnscentedKalmanFilter as FilterPyUKF

from imm_gym.scenarios.segments import generate_truth, paper_scenario
from imm_gym.seeding import streams
from imm_gym.tracking.filters import UnscentedKalmanFilter
from imm_gym.tracking.initiation import initiate
from imm_gym.tracking.models import paper_bank
from imm_gym.tracking.sensors import Sonar

SEED = 0
TOL_M = 1e-8  # measured: 2e-11 m (3e-4 m with the sigma points U sqrt(S)'s columns)
MU0 = np.full(3, 1.0 / 3.0)


def _tpm(stay: float) -> np.ndarray:
    """``stay`` on the diagonal, ``(1 - stay) / 2`` off it."""
    return np.where(np.eye(3, dtype=bool), stay, (1.0 - stay) / 2.0)


TPM = _tpm(0.995)


def _svd_sqrt(A: np.ndarray) -> np.ndarray:
    """The symmetric square root ``U diag(sqrt(s)) U^T`` of ``A = U diag(s) U^T``: FilterPy's
    sigma points are ``x`` plus and minus its rows, imm_gym's ``x ± gamma a_i`` with ``a_i`` its
    columns for ``P``."""
    U, s, _ = np.linalg.svd(A)
    return (U * np.sqrt(s)) @ U.T


def _sonar_h(x: np.ndarray) -> np.ndarray:
    """Range and bearing of a sonar at the origin."""
    return np.array([math.hypot(x[0], x[1]), math.atan2(x[1], x[0])])


def _residual_z(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a - b`` with the bearing difference wrapped to (-pi, pi]."""
    d = np.subtract(a, b)
    d[1] = math.pi - (math.pi - d[1]) % (2.0 * math.pi)
    return d


@pytest.fixture(scope="module")
def episode() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measurements ``z (151, 2)`` at ``t = 0..150`` and the track ``x0 (4,)``, ``P0 (4, 4)``
    initiated from ``z[0]``."""
    scenario = paper_scenario()
    assert scenario.horizon == 150
    scenario_rng, noise_rng = streams(SEED)
    truth = generate_truth([scenario], [scenario_rng])
    z = Sonar().measure(truth.states, [noise_rng]).z[0]
    x0, P0 = initiate(Sonar(), z[:1], np.array(scenario.velocity))
    return z, x0[0], P0[0]


@pytest.fixture(scope="module")
def filterpy_positions(episode) -> np.ndarray:
    """FilterPy's combined positions ``(150, 2)`` at steps 1..150."""
    z, x0, P0 = episode
    sonar = Sonar()
    filters = []
    for model in paper_bank():
        F = model.transition_matrix(1.0, 4)
        ukf = FilterPyUKF(
            dim_x=4,
            dim_z=2,
            dt=1.0,
            hx=_sonar_h,
            fx=lambda x, dt, F=F: F @ x,
            # FilterPy takes the square root in the sigma points (the UKF's own sqrt_fn is unused)
            points=MerweScaledSigmaPoints(4, alpha=1.0, beta=2.0, kappa=0.0, sqrt_method=_svd_sqrt),
            residual_z=_residual_z,
        )
        ukf.x, ukf.P = x0.copy(), P0.copy()
        ukf.Q, ukf.R = model.noise_covariance(4), sonar.R.copy()
        filters.append(ukf)
    imm = IMMEstimator(filters, MU0.copy(), TPM.copy())
    positions = []
    for zk in z[1:]:
        imm.predict()
        imm.update(zk)
        positions.append(imm.x[:2].copy())
    return np.array(positions)


def _imm_gym_positions(make_imm, episode, tpm: np.ndarray) -> np.ndarray:
    z, x0, P0 = episode
    imm = make_imm(paper_bank(), Sonar(), UnscentedKalmanFilter(alpha=1.0, beta=2.0, kappa=0.0))
    return imm.run(z[1:], tpm, x0, P0, mode_probs=MU0).x[:, :2]


def test_imm_agrees_with_filterpy(make_imm, episode, filterpy_positions) -> None:
    ours = _imm_gym_positions(make_imm, episode, TPM)
    gap = np.linalg.norm(ours - filterpy_positions, axis=-1)
    assert gap.shape == (150,)
    worst = int(np.argmax(gap))
    assert gap[worst] <= TOL_M, f"step {worst + 1}: {gap[worst]:.3g} m apart"


def test_another_tpm_does_not_agree(make_imm, episode, filterpy_positions) -> None:
    # The tolerance can tell TPMs apart: the agreement above is not vacuous.
    ours = _imm_gym_positions(make_imm, episode, _tpm(0.99))
    assert np.linalg.norm(ours - filterpy_positions, axis=-1).max() > TOL_M
