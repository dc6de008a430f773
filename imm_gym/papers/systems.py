r"""Seed 002's and seed 003's evaluations: their banks, sensors, scenarios and metrics.

* **seed 002** — the NCV/CT/CTRA IMM-EKF (:class:`~imm_gym.tracking.hetero.HeteroBank`, Table
  I: TPM 0.90 / 0.05, ``mu_0 = (0.90, 0.08, 0.02)``) on
  :class:`~imm_gym.scenarios.profiles.DrivingFamily`, a position+velocity sensor
  (``sigma_p = 0.5`` m, ``sigma_v = 0.5`` m/s), ``T = 0.1`` s. Metrics:
  :func:`~imm_gym.evaluation.metrics.trajectory_metrics` (position RMSE / MAE / max / FDE, velocity
  and yaw RMSE) and NIS / NEES (dof 4) with the share inside the 95 % χ² bound and the mean.
* **seed 003** — a CV / CA / CT(+6.75°/s, the profile's turn rate) linear bank on
  ``[x, y, vx, vy, ax, ay]`` (Kalman filters in the same engine), position+velocity measurements
  at ``T = 0.1`` s, a family around the 43 s trajectory of §4
  (:func:`~imm_gym.scenarios.profiles.maneuver_profile`) for training and held-out evaluation
  (:class:`ManeuverFamily`; the runs draw from it, not the trajectory itself). The
  noise values the extraction lost are filled: ``Q_CV = diag(1e-3, 1e-3, 1e-2, 1e-2)`` with
  ``q_acc = 1e-2``, ``Q_CA = diag(1e-3, 1e-3, 1e-2, 1e-2, 1e-1, 1e-1)``, ``Q_CT = Q_CV``,
  ``sigma_p = 1`` m, ``sigma_v = 0.5`` m/s, TPM 0.90 / 0.05, uniform ``mu_0``.

Track initiation (both): position and velocity from the first measurement, ``P_0 = R`` (converted
into each model's space; what the measurement lacks, turn rate and accelerations, starts at 0 with
variances 0.2 and 1.0); the first measurement only initiates, the K following steps are scored.
**Not seed 002's initialization** (its §III-B): its filters start at the first ground-truth point
with ``P_0,NCV = diag(0.5, 0.5, 1.0, 1.0)``, ``P_0,CT = diag(0.5, 0.5, 1.0, 0.1, 0.2)``,
``P_0,CTRA = diag(0.5, 0.5, 1.0, 0.1, 0.2, 1.0)``; ours starts from what a tracker has, so the
seed-002 figures include the start from a noisy measurement (seed 003 does not state its own).
Run ``r`` of a batch seeded ``s`` draws its trajectory and its noise from
:func:`imm_gym.seeding.streams` with seed ``s + r``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from imm_gym.evaluation.metrics import consistency, nees, trajectory_metrics
from imm_gym.scenarios.profiles import (
    MANEUVER_TURN_RATE,
    DrivingFamily,
    ManeuverFamily,
)
from imm_gym.seeding import streams
from imm_gym.sim.episodes import Batch
from imm_gym.tracking.hetero import HeteroBank, HeteroIMM, linear_models
from imm_gym.tracking.imm import IMMResult, run
from imm_gym.tracking.models import MotionModel
from imm_gym.tracking.sensors import PositionSensor
from imm_gym.tracking.tpm import stay_tpm
from imm_gym.validation import ConfigError, check_int

Array = NDArray[np.float64]

#: Seed 002 Table II / III (their single MATLAB trajectory).
HETERO_EKF_PAPER = {
    "pos_rmse": 0.3117,
    "pos_mae": 0.2794,
    "pos_max": 0.6722,
    "fde": 0.2429,
    "vel_rmse": 0.5428,
    "yaw_rmse_deg": 2.1614,
    "nis_inside": 0.9416,
    "nis_mean": 4.3941,
    "nees_inside": 0.8729,
    "nees_mean": 5.5006,
}


def hetero_ekf_sensor() -> PositionSensor:
    """Seed 002's position+velocity sensor (Table I)."""
    return PositionSensor(sigma_pos=0.5, sigma_vel=0.5)


def bbsca_sensor() -> PositionSensor:
    """Seed 003's position+velocity sensor (noise values filled, see the module docstring)."""
    return PositionSensor(sigma_pos=1.0, sigma_vel=0.5)


def bbsca_models() -> tuple[MotionModel, ...]:
    """Seed 003's CV / CA / CT bank (noise values filled, see the module docstring)."""
    q4 = (1e-3, 1e-3, 1e-2, 1e-2)
    return (
        MotionModel("cv", q=q4, q_acc=1e-2),
        MotionModel("ca", q=(*q4, 1e-1, 1e-1)),
        MotionModel("ct", math.degrees(MANEUVER_TURN_RATE), q=q4, q_acc=1e-2),
    )


def draw(
    family: DrivingFamily | ManeuverFamily, sensor: PositionSensor, runs: int, seed: int
) -> Batch:
    """Draw R runs seeded ``seed + r`` (trajectory stream, noise stream); the track starts from
    the first position+velocity measurement with ``P0 = R``."""
    runs = check_int("runs", runs, 1)
    seed = check_int("seed", seed, 0)
    if sensor.sigma_vel is None:
        raise ConfigError("the seed evaluations need a position+velocity sensor (sigma_vel)")
    scen, noise = zip(*(streams(seed + r) for r in range(runs)), strict=True)
    truth = family.truth(scen)
    meas = sensor.measure(truth.states, noise)
    P0 = np.broadcast_to(sensor.R, (runs, 4, 4)).copy()
    return Batch(truth, meas, meas.z[:, 0, :4].copy(), P0)


def run_bank(
    imm: HeteroIMM,
    batch: Batch,
    tpm: Array,
    q_scale: Array | None = None,
    r_scale: Array | None = None,
    repeat: int = 1,
) -> IMMResult:
    """Run ``imm`` with a fixed TPM over the batch (:func:`imm_gym.tracking.imm.run`, failures
    flagged), optionally ``repeat`` times side by side.

    With ``repeat = P`` the trackers are ``P x R`` (particle-major): tracker ``p R + r`` runs
    run ``r`` with ``q_scale[p R + r]`` and ``r_scale[p R + r]`` — how the tuner evaluates P
    particles at once.

    Args:
        q_scale: ``(P R, M)`` per-tracker factors on the models' ``Q``; r_scale: ``(P R,)``.
    """
    return run(
        imm,
        np.tile(batch.measurements.z[:, 1:], (repeat, 1, 1)),
        tpm,
        np.tile(batch.x0, (repeat, 1)),
        np.tile(batch.P0, (repeat, 1, 1)),
        detected=np.tile(batch.measurements.detected[:, 1:], (repeat, 1)),
        allow_failure=True,
        q_scale=q_scale,
        r_scale=r_scale,
    )


def score_run(result: IMMResult, batch: Batch, dim_z: int) -> dict[str, float | None]:
    """Seed 002's metrics of one bank run (``repeat = 1``; the NIS and NEES means and shares
    None where nothing counts)."""
    truth = batch.truth.states[:, 1:]
    out: dict[str, float | None] = trajectory_metrics(result.x, truth, batch.truth.heading[:, 1:])
    nis = consistency(result.nis, dim_z, mask=batch.measurements.detected[:, 1:])
    nes = consistency(nees(result.x, result.P, truth), 4)
    out.update(
        nis_inside=nis["inside"],
        nis_mean=nis["mean"],
        nis_bound=nis["bound"],
        nees_inside=nes["inside"],
        nees_mean=nes["mean"],
        failed=int(result.failed.sum()),
    )
    return out


def hetero_ekf_evaluation(
    runs: int = 100, seed: int = 0, bank: HeteroBank | None = None
) -> dict[str, object]:
    """The heterogeneous IMM-EKF on the seed-002-like family (see the module docstring).

    Args:
        runs, seed: runs ``seed .. seed + runs - 1``.
        bank: the bank (default :class:`~imm_gym.tracking.hetero.HeteroBank`, seed 002 Table I).
    """
    imm, family, sensor, tpm = system_setup("seed002", bank)
    batch = draw(family, sensor, runs, seed)
    result = run_bank(imm, batch, tpm)
    return {
        "metrics": score_run(result, batch, sensor.dim_z),
        "mean_mode_probs": result.mode_probs.mean(axis=(0, 1)).tolist(),
        "paper": HETERO_EKF_PAPER,
        "meta": {"runs": runs, "seeds": f"{seed}..{seed + runs - 1}", "steps": result.nis.shape[1]},
    }


def bbsca_imm(sensor: PositionSensor | None = None) -> HeteroIMM:
    """Seed 003's CV / CA / CT bank in the engine (Kalman filters: all models are linear)."""
    return HeteroIMM(linear_models(bbsca_models()), sensor or bbsca_sensor(), T=0.1)


SYSTEMS = ("seed002", "seed003")

def system_setup(
    name: str, bank: HeteroBank | None = None
) -> tuple[HeteroIMM, DrivingFamily | ManeuverFamily, PositionSensor, Array]:
    """``(imm, family, sensor, tpm)`` of ``seed002`` or ``seed003``.

    Args:
        bank: seed 002's heterogeneous bank (default Table I's); not used by ``seed003``.
    """
    if name == "seed002":
        sensor = hetero_ekf_sensor()
        bank = HeteroBank() if bank is None else bank
        imm = HeteroIMM(bank, sensor, T=0.1)
        return imm, DrivingFamily(), sensor, stay_tpm(len(bank), 0.90)
    if name == "seed003":
        sensor = bbsca_sensor()
        return bbsca_imm(sensor), ManeuverFamily(), sensor, stay_tpm(3, 0.9)
    raise ConfigError(f"scenario must be one of {list(SYSTEMS)}, got {name!r}")
