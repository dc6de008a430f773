"""What a better maneuver detector is worth to the turn-rate prior, scenario by scenario.

The ``turn-rate-prior`` baseline leans the share ``v`` of a fixed prior's jumps toward where the
bank's models place an estimated turn rate (:class:`imm_gym.sim.detectors.TurnRateBelief`,
:func:`imm_gym.sim.stay_bank.detector_tpm_rows`)::

    Pi = r I + (1 - r) 1 q^T,   q = (1 - v) / M + v b(omega),   r = (s - 1/M) / (1 - 1/M).

This runs that prior, on the same runs (common random numbers), led by kinds of turn rate:

* ``true, d late``: the target's own turn rate over step ``k - d`` (``d = 0``: the step
  being predicted, which no causal detector has) — a privileged detector, the head-room;
* ``tracker (env)``: the env's ``turn_rate`` detector, the heading rate of the tracker's own
  combined estimate smoothed by :data:`~imm_gym.sim.detectors.TURN_RATE_FACTOR` (closed loop:
  the prior steers the estimate it reads) — what the baseline runs;
* ``CT-omega EKF``: the turn rate estimated by an EKF of the coordinated-turn model with the
  turn rate in its state (:class:`imm_gym.tracking.hetero.HeteroModel` ``"ct"``, yaw
  acceleration noise ``--yaw-noise``) run on the same measurements beside the tracker (open
  loop; left out where the conditions vary per run: it runs one sampling period and sensor);
* ``learned (MLP)`` (``--learned-runs N``): a detector learned by supervision — an MLP fitted
  to the true turn rate's belief from a window of an unsteered uniform-TPM IMM's quantities, on
  N runs of the random family (:func:`train_detector`; open loop).

For each detector it prints the best (stay, share) of the grid by position ARMSE (m), with its
mode accuracy: picked on the evaluation's own runs, so each row is its detector's best case::

    python examples/detector_headroom.py --runs 100 --seed 0 --scenario random --scenario paper
    python examples/detector_headroom.py --env-config examples/broad.yaml   # your own tracker
    python examples/detector_headroom.py --learned-runs 5000    # and a detector learned by
                                                                # supervision

The priors run through :mod:`imm_gym.evaluation.priors` (``set``-mode logits, exact above the
floor).
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from imm_gym import EnvConfig, TrackingCore
from imm_gym.cli.evaluate import suite_configs
from imm_gym.evaluation.priors import prior_core, run_priors
from imm_gym.sim.config_file import read_env_config
from imm_gym.sim.detectors import TURN_RATE_FACTOR, TurnRateBelief, model_turn_rates
from imm_gym.sim.features import heading_rate
from imm_gym.sim.stay_bank import detector_tpm_rows
from imm_gym.tracking.hetero import HeteroIMM, HeteroModel

Array = NDArray[np.float64]

STAYS = (1 / 3, 0.4, 0.5, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995)
SHARES = (0.25, 0.5, 0.75, 1.0)
#: The EKF's speed noise (m/s²) and the standard deviation of its first turn rate (rad/s).
EKF_SPEED_NOISE = 0.1
EKF_TURN_RATE_STD = np.radians(3.0)


def true_turn_rates(truth: Array, T: float | Array) -> Array:
    """``(R, K)`` the target's turn rate over each step ``k`` (from state ``k`` to ``k + 1`` of
    ``truth (R, K + 1, 4)``, ``[x, y, vx, vy]``): the heading change over the sampling period
    ``T`` (one, or one per run ``(R,)``)."""
    heading = np.unwrap(np.arctan2(truth[..., 3], truth[..., 2]), axis=1)
    return np.diff(heading, axis=1) / np.reshape(T, (-1, 1))


def ekf_turn_rates(core: TrackingCore, runs: int, yaw_noise: float) -> Array:
    """``(R, K + 1)`` the CT-omega EKF's turn rate after each measurement of the first ``runs``
    slots (column 0: its prior, 0), started from the tracker's first estimate."""
    ekf = HeteroIMM([HeteroModel("ct", (EKF_SPEED_NOISE, yaw_noise))], core.imm.sensor,
                    T=float(core.config.source.T))
    state = ekf.init(core.state_a.x[:runs, 0], core.state_a.P[:runs, 0], np.ones(1))
    state.P[:, 0, 4, 4] = EKF_TURN_RATE_STD**2
    rates = np.zeros((runs, core.horizon + 1))
    one = np.ones((runs, 1, 1))
    for k in range(1, core.horizon + 1):
        state, _ = ekf.step(state, one, core.z[:runs, k], core.detected[:runs, k], check=False,
                            allow_failure=True)
        rates[:, k] = np.nan_to_num(state.x[:, 0, 4])
    return rates


#: The learned detector: steps of the uniform IMM's quantities it reads, training epochs, batch.
WINDOW = 20
EPOCHS = 8
BATCH = 1024


def uniform_imm_features(overrides: Mapping[str, Any], runs: int, seed: int) -> Array:
    """``(R, K, WINDOW * (2 M + 2))`` what the learned detector reads before each step ``k``:
    the last :data:`WINDOW` steps (through measurement ``k``) of a classical IMM at the uniform
    TPM on the runs' measurements — its mode
    probabilities, its models' log-likelihoods relative to the best (clipped to -20, / 10), its
    NIS (clipped to 50, / 10) and the heading rate of its estimate in units of the bank's
    fastest turn (clipped to ±3); zeros before the first measurement. No action steers it;
    every input is in the tracker's units."""
    core = prior_core(overrides, 1, runs, seed)
    omegas = model_turn_rates(core.config.bank)
    if omegas is None:
        raise ValueError("the learned detector needs a linear bank (CV and CT models)")
    M, K = core.M, core.horizon
    scale = np.abs(omegas).max() or 1.0
    uniform = np.full((runs, M, M), 1.0 / M)
    steps = np.zeros((runs, K + 1, 2 * M + 2))
    velocity = core.state_a.x[:, 0, 2:4].copy()

    def rows(k: int, info: dict[str, Any] | None) -> Array:
        nonlocal velocity
        if info is not None:
            loglik = info["loglik"] - info["loglik"].max(axis=1, keepdims=True)
            rate = heading_rate(velocity, info["estimate"][:, 2:4], core.sampling_period)
            velocity = info["estimate"][:, 2:4].copy()
            steps[:, k] = np.column_stack([
                info["mode_probs"], np.clip(loglik, -20.0, 0.0) / 10.0,
                np.clip(info["nis"], 0.0, 50.0) / 10.0, np.clip(rate / scale, -3.0, 3.0),
            ])
        return uniform

    run_priors(core, 1, rows)
    last = np.arange(K)[:, None] - np.arange(WINDOW)  # (K, WINDOW): step k's window
    window = steps[:, np.clip(last, 0, None)]  # (R, K, WINDOW, F)
    return np.nan_to_num(window).reshape(runs, K, -1)


def true_beliefs(overrides: Mapping[str, Any], runs: int, seed: int) -> Array:
    """``(R, K, M)`` the belief of the true turn rate of each step (what the detector learns)."""
    core = prior_core(overrides, 1, runs, seed)
    omegas = model_turn_rates(core.config.bank)
    rate = true_turn_rates(core.truth, core.sampling_period)
    return TurnRateBelief(omegas)(rate.ravel()).reshape(runs, core.horizon, -1)


def train_detector(
    overrides: Mapping[str, Any], runs: int, seed: int, epochs: int = EPOCHS
) -> torch.nn.Module:
    """An MLP (two hidden layers of 128, tanh) fitted by cross-entropy to the true turn rate's
    belief from :func:`uniform_imm_features`, on runs ``seed .. seed + runs - 1`` of
    ``overrides`` (Adam, rate 1e-3, batches of :data:`BATCH`; ``torch.manual_seed(seed)``):
    it learns the belief's expectation given what the IMM saw."""
    torch.manual_seed(seed)
    x = torch.tensor(uniform_imm_features(overrides, runs, seed), dtype=torch.float32)
    y = torch.tensor(true_beliefs(overrides, runs, seed), dtype=torch.float32)
    x, y = x.reshape(-1, x.shape[-1]), y.reshape(-1, y.shape[-1])
    net = torch.nn.Sequential(
        torch.nn.Linear(x.shape[1], 128), torch.nn.Tanh(), torch.nn.Linear(128, 128),
        torch.nn.Tanh(), torch.nn.Linear(128, y.shape[1]),
    )
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-3)
    for _ in range(epochs):
        for batch in torch.randperm(len(x)).split(BATCH):
            loss = -(y[batch] * torch.log_softmax(net(x[batch]), -1)).sum(-1).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    return net


def learned_beliefs(net: torch.nn.Module, overrides: Mapping[str, Any], runs: int,
                    seed: int) -> Array:
    """``(R, K, M)`` the detector's beliefs before each step of runs ``seed .. seed + runs -
    1``."""
    x = torch.tensor(uniform_imm_features(overrides, runs, seed), dtype=torch.float32)
    with torch.no_grad():
        return torch.softmax(net(x), -1).double().numpy()


def detector_runs(
    overrides: dict[str, Any], delays: Sequence[int], runs: int, seed: int,
    yaw_noise: float = 0.01, beliefs: Mapping[str, Array] | None = None,
) -> dict[tuple[str, float, float], tuple[float, float]]:
    """``{(detector, stay, share): (ARMSE, mode accuracy)}`` of the turn-rate prior at every
    stay of :data:`STAYS` and share of :data:`SHARES` led by each detector (module docstring:
    ``"true, d late"`` for each of ``delays``, ``"tracker (env)"``, ``"CT-omega EKF"``), on runs
    ``seed .. seed + runs - 1``. Where the conditions vary per run (``vary``) the EKF, which
    runs one sampling period and one sensor, is left out. ``beliefs``: more detectors by name,
    their beliefs ``(runs, K, M)`` before each step given (:func:`learned_beliefs`)."""
    varied = EnvConfig.build(dict(overrides)).vary.active
    names = [f"true, {d} late" for d in delays] + ["tracker (env)"]
    names += [] if varied else ["CT-omega EKF"]
    given = dict(beliefs or {})
    names += list(given)
    combos = [(name, s, v) for name in names for s in STAYS for v in SHARES]
    core = prior_core(overrides, len(combos), runs, seed)
    omegas = model_turn_rates(core.config.bank)
    if omegas is None:
        raise ValueError("the turn-rate prior needs a linear bank (CV and CT models)")
    belief, T, K = TurnRateBelief(omegas), core.sampling_period, core.horizon
    true_rate = true_turn_rates(core.truth[:runs], T[:runs])
    ekf_rate = np.zeros((runs, K + 1)) if varied else ekf_turn_rates(core, runs, yaw_noise)
    kind = np.repeat([names.index(name) for name, _, _ in combos], runs)
    delay = np.array([*delays] + [0] * (len(names) - len(delays)))[kind]
    stays = np.repeat([s for _, s, _ in combos], runs)
    shares = np.repeat([v for _, _, v in combos], runs)
    run = np.tile(np.arange(runs), len(combos))
    tracker, ekf = kind == len(delays), kind == len(delays) + 1
    # the given detectors' slots and their beliefs, one per step (every prior of one detector
    # on the same runs)
    from_given = np.isin(kind, [names.index(name) for name in given])
    given_belief = np.zeros((core.n_envs, K, len(omegas)))
    for name, value in given.items():
        given_belief[kind == names.index(name)] = np.tile(value, (len(STAYS) * len(SHARES), 1, 1))
    # the env's detector: the heading rate of each slot's own estimate, smoothed
    smoothed = np.zeros(core.n_envs)
    velocity = core.state_a.x[:, 0, 2:4].copy()

    def rows(k: int, info: dict[str, Any] | None) -> Array:
        nonlocal smoothed, velocity
        if info is not None:
            estimate = info["estimate"][:, 2:4]
            smoothed = TURN_RATE_FACTOR * smoothed + (1.0 - TURN_RATE_FACTOR) * heading_rate(
                velocity, estimate, T
            )
            velocity = estimate.copy()
        late = k - delay
        rate = np.where(late >= 0, true_rate[run, np.clip(late, 0, K - 1)], 0.0)
        rate = np.where(tracker, smoothed, rate)
        rate = np.where(ekf, ekf_rate[run, k], rate)
        b = np.where(from_given[:, None], given_belief[:, k], belief(rate))
        return detector_tpm_rows(stays, b, shares)

    result = run_priors(core, len(combos), rows)
    return {combo: result.scores(c)[:2] for c, combo in enumerate(combos)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--suite", default="benchmark")
    p.add_argument("--scenario", action="append", help="a scenario of the suite (default: all "
                   "of them, unless --env-config is given)")
    p.add_argument("--env-config", type=Path, action="append", default=[], metavar="FILE",
                   help="a configuration file (YAML or JSON of EnvConfig fields): a column of its "
                   "own")
    p.add_argument("--delay", type=int, action="append",
                   help="steps the true turn rate is known late (default: 0 1 3 5 8)")
    p.add_argument("--yaw-noise", type=float, default=0.01,
                   help="the CT-omega EKF's yaw acceleration noise (rad/s²)")
    p.add_argument("--learned-runs", type=int, default=0, metavar="N",
                   help="add the learned detector, trained on N runs of the suite's random "
                   "family (0: leave it out; 5000 takes about a minute)")
    p.add_argument("--learned-seed", type=int, default=100_000,
                   help="the first of its training runs' seeds (and its torch seed)")
    args = p.parse_args()
    delays = args.delay or [0, 1, 3, 5, 8]
    suite = suite_configs(args.suite)
    chosen = args.scenario or ([] if args.env_config else list(suite))
    unknown = sorted(set(chosen) - set(suite))
    if unknown:
        p.error(f"--scenario must be among {list(suite)}, got {unknown}")
    configs = {name: suite[name] for name in chosen}
    configs.update({path.name: read_env_config(path) for path in args.env_config})
    net = None
    if args.learned_runs > 0:
        net = train_detector(suite["random"], args.learned_runs, args.learned_seed)
        print(f"learned detector: trained on the random family's runs {args.learned_seed}.."
              f"{args.learned_seed + args.learned_runs - 1}")
    print(f"runs {args.seed}..{args.seed + args.runs - 1}; position ARMSE (m) / mode accuracy "
          f"(stay, share) of each detector's best prior on these runs")
    table: dict[str, list[str]] = {}
    for column, overrides in enumerate(configs.values()):
        beliefs = {} if net is None else {
            "learned (MLP)": learned_beliefs(net, overrides, args.runs, args.seed)
        }
        scores = detector_runs(overrides, delays, args.runs, args.seed, args.yaw_noise, beliefs)
        for detector in dict.fromkeys(d for d, _, _ in scores):
            (armse, acc), s, v = min(
                (scores[(detector, s, v)], s, v) for s in STAYS for v in SHARES
            )
            cells = table.setdefault(detector, ["—"] * len(configs))
            cells[column] = f"{armse:.2f} / {100 * acc:.0f} % ({s:.3g}, {v:g})"
    print("| detector | " + " | ".join(configs) + " |")
    print("|---|" + "---|" * len(configs))
    for detector, cells in table.items():
        print(f"| {detector} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
