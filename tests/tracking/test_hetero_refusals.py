"""What the heterogeneous bank (:mod:`imm_gym.tracking.hetero`) refuses, each refusal naming the
setting: a bank, a model, the engine's construction and start, the tracker factory."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import ConfigError, PositionSensor, Sonar
from imm_gym.tracking.hetero import HeteroBank, HeteroIMM, HeteroModel, make_tracker

SENSOR = PositionSensor(sigma_pos=0.5, sigma_vel=0.5)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"models": ("ncv",)}, r"bank\.models must hold at least 2 models"),
        ({"initial_probs": (0.5, 0.3, 0.1)}, r"bank\.initial_probs must have 3 non-negative"),
        ({"initial_probs": (0.6, 0.3, 0.2)}, r"bank\.initial_probs must have 3 non-negative"),
        ({"turn_rate_var": 0.0}, r"bank\.turn_rate_var must be in \(0\.0, inf\)"),
        ({"accel_var": 0.0}, r"bank\.accel_var must be in \(0\.0, inf\)"),
        ({"sigma_ncv": -0.6}, r"bank\.sigma_ncv must be in \[0\.0, inf\)"),
        ({"sigma_ncv": float("nan")}, r"bank\.sigma_ncv"),
    ],
)
def test_a_bank_out_of_range_is_refused(kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        HeteroBank(**kwargs)


@pytest.mark.parametrize(
    ("kind", "sigma"), [("ncv", (-0.6,)), ("ct", (2.4, -0.6)), ("ctra", (float("inf"), 3.0))]
)
def test_a_model_with_a_negative_or_infinite_noise_is_refused(
    kind: str, sigma: tuple[float, ...]
) -> None:
    """A negative standard deviation squares to the same ``Q``: refused all the same, by name."""
    with pytest.raises(ConfigError, match=r"model\.sigma must be in \[0\.0, inf\)"):
        HeteroModel(kind, sigma)


def test_the_engine_refuses_a_bank_without_models() -> None:
    with pytest.raises(ConfigError, match="models must contain at least one motion model"):
        HeteroIMM([], SENSOR)


def test_the_start_refuses_a_covariance_not_positive_definite_and_negative_probabilities() -> None:
    imm = HeteroIMM(HeteroBank(), SENSOR, T=1.0)
    x0 = np.array([0.0, 0.0, 5.0, 0.0])
    for P0 in (np.diag([1.0, 1.0, 1.0, 0.0]), np.diag([1.0, -1.0, 1.0, 1.0])):
        with pytest.raises(ConfigError, match="P0 must be positive definite"):
            imm.init(x0, P0)
    with pytest.raises(ConfigError, match="mode_probs must be non-negative and sum to 1"):
        imm.init(x0, np.eye(4), np.array([-0.2, 0.6, 0.6]))


@pytest.mark.parametrize("name", ["ukf", "ukf-cholesky", "kf"])
def test_the_tracker_of_a_heterogeneous_bank_refuses_another_filter(name: str) -> None:
    """``make_tracker`` with a :class:`HeteroBank` and a filter other than the EKF: refused, not
    run as an EKF under the filter's name."""
    with pytest.raises(ConfigError, match=r"runs an EKF only \(filter 'ekf'\)"):
        make_tracker(HeteroBank(), Sonar(), name, 1.0)
    assert isinstance(make_tracker(HeteroBank(), Sonar(), "ekf", 1.0), HeteroIMM)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"q_scale": (1.0, 2.0)}, r"bank\.q_scale \(one entry per model\)"),
        ({"q_scale": (1.0, 2.0, 3.0, 4.0)}, r"bank\.q_scale \(one entry per model\)"),
        (
            {"initial_probs": (-0.5, 1.0, 0.5)},
            r"bank\.initial_probs\[0\] must be in \[0\.0, 1\.0\]",
        ),
        (
            {"initial_probs": (0.5, 1.5, -1.0)},
            r"bank\.initial_probs\[1\] must be in \[0\.0, 1\.0\]",
        ),
    ],
)
def test_a_bank_of_per_model_settings_of_the_wrong_length_or_sign_is_refused(
    kwargs: dict, match: str
) -> None:
    """One ``q_scale`` per model, and start probabilities each in [0, 1] even when they sum to
    1: refused when the bank is built, not when it first runs."""
    with pytest.raises(ConfigError, match=match):
        HeteroBank(**kwargs)


def test_a_step_refuses_detection_flags_and_measurements_of_another_shape() -> None:
    imm = HeteroIMM(HeteroBank(), SENSOR, T=1.0)
    state = imm.init(np.tile([0.0, 0.0, 5.0, 0.0], (2, 1)), np.eye(4))
    tpm, z = np.full((3, 3), 1 / 3), np.zeros((2, 4))
    for detected in (np.ones(3, dtype=bool), np.ones(1, dtype=bool), np.ones((2, 1), dtype=bool)):
        with pytest.raises(ConfigError, match=r"detected must have shape \(2,\)"):
            imm.step(state, tpm, z, detected=detected)
    for bad in (np.zeros((2, 2)), np.zeros((1, 4)), np.zeros(4)):
        with pytest.raises(ConfigError, match=r"z must have shape \(2, 4\)"):
            imm.step(state, tpm, bad)


def test_the_start_refuses_a_state_of_another_shape_or_not_finite() -> None:
    """``x0`` is Cartesian ``(N, 4)`` with ``P0`` ``(N, 4, 4)`` or ``(4, 4)``, both finite: a 5- or
    6-component state, a covariance or a batch of covariances of another size or count, NaN or
    infinity are refused by name (a single 6 x 6 or 3 x 3 covariance was numpy's broadcast
    error)."""
    imm = HeteroIMM(HeteroBank(), SENSOR, T=1.0)
    shape = r"x0 must be \(N, 4\) Cartesian and P0 \(N, 4, 4\)"
    for x0, P0 in (
        (np.zeros((1, 5)), np.eye(5)[None]),
        (np.array([[0.0, 0.0, 5.0, 0.0, 0.0, 0.0]]), np.eye(4)[None]),
        (np.array([[0.0, 0.0, 5.0, 0.0]]), np.eye(6)[None]),
        (np.array([0.0, 0.0, 5.0, 0.0]), np.eye(6)),  # one covariance of another size
        (np.array([0.0, 0.0, 5.0, 0.0]), np.eye(3)),
        (np.tile([0.0, 0.0, 5.0, 0.0], (2, 1)), np.stack([np.eye(4)] * 3)),
    ):
        with pytest.raises(ConfigError, match=shape):
            imm.init(x0, P0)
    x0 = np.array([0.0, 0.0, 5.0, 0.0])
    for bad_x, bad_P in ((np.nan, 1.0), (np.inf, 1.0), (0.0, np.nan), (0.0, np.inf)):
        P0 = np.eye(4)
        P0[0, 0] = bad_P
        with pytest.raises(ConfigError, match="x0 and P0 must be finite"):
            imm.init(x0 + np.array([bad_x, 0.0, 0.0, 0.0]), P0)


@pytest.mark.parametrize(
    ("tpm", "match"),
    [
        (np.full((3, 3), 0.3), r"tpm rows must sum to 1"),
        (
            np.array([[1.2, -0.2, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
            r"tpm entries must be >= 0",
        ),
        (np.full((2, 2), 0.5), r"tpm must have shape \(\.\.\., 3, 3\)"),
        (np.full((3, 3), np.nan), r"tpm must be finite"),
    ],
)
def test_a_step_refuses_a_tpm_that_is_not_a_stochastic_matrix(tpm: np.ndarray, match: str) -> None:
    """The engine checks the TPM it mixes with: rows summing to 1, entries >= 0, one row and
    column per model, finite."""
    imm = HeteroIMM(HeteroBank(), SENSOR, T=1.0)
    state = imm.init(np.array([0.0, 0.0, 5.0, 0.0]), np.eye(4))
    with pytest.raises(ConfigError, match=match):
        imm.step(state, tpm, np.zeros((1, 4)))
