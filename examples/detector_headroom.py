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
* ``learned (env)``: the env's ``learned`` detector — a network's belief of the coming step's
  turn rate from a window of an unsteered uniform-TPM IMM's records
  (:mod:`imm_gym.sim.learned_detector`; the shipped network, or ``--detector-weights FILE``):
  what the ``learned-prior`` baseline runs.

For each detector it prints the best (stay, share) of the grid by position ARMSE (m), with its
mode accuracy: picked on the evaluation's own runs, so each row is its detector's best case::

    python examples/detector_headroom.py --runs 100 --seed 0 --scenario random --scenario paper
    python examples/detector_headroom.py --env-config examples/broad.yaml   # your own tracker

The priors run through :mod:`imm_gym.evaluation.priors` (``set``-mode logits, exact above the
floor ``P_MIN`` = 1e-4). At share 1 a belief on one model (the true turn rate on a model's own)
or two (a rate between them) leaves exact zeros in the prior's rows; those entries run at the
floor, the rest of the row shrunk to pay for them, as the ``turn-rate-prior`` baseline runs its
prior (its ``p_min`` is 1e-4 too): the share-1 rows printed are the floored prior's.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym import EnvConfig, TrackingCore
from imm_gym.cli.policies import cannot_run
from imm_gym.cli.suite import suite_configs
from imm_gym.evaluation.priors import prior_core, run_priors
from imm_gym.sim.config_file import read_env_config
from imm_gym.sim.detectors import (
    TURN_RATE_FACTOR,
    TurnRateBelief,
    model_turn_rates,
    true_turn_rates,
)
from imm_gym.sim.features import heading_rate
from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS, DetectorNetwork, LearnedDetector
from imm_gym.sim.stay_bank import detector_tpm_rows
from imm_gym.tracking.hetero import HeteroIMM, HeteroModel
from imm_gym.tracking.imm import IMMState
from imm_gym.validation import ConfigError

Array = NDArray[np.float64]

STAYS = (1 / 3, 0.4, 0.5, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995)
SHARES = (0.25, 0.5, 0.75, 1.0)
#: The EKF's speed noise (m/s²) and the standard deviation of its first turn rate (rad/s).
EKF_SPEED_NOISE = 0.1
EKF_TURN_RATE_STD = np.radians(3.0)


def ekf_turn_rates(core: TrackingCore, runs: int, yaw_noise: float) -> Array:
    """``(R, K + 1)`` the CT-omega EKF's turn rate after each measurement of the first ``runs``
    slots (column 0: its prior, 0), started from the position and velocity of the tracker's
    first estimate (``[x, y, vx, vy]``, without a CA bank's accelerations)."""
    ekf = HeteroIMM([HeteroModel("ct", (EKF_SPEED_NOISE, yaw_noise))], core.imm.sensor,
                    T=float(core.config.source.T))
    state = ekf.init(core.state_a.x[:runs, 0, :4], core.state_a.P[:runs, 0, :4, :4], np.ones(1))
    state.P[:, 0, 4, 4] = EKF_TURN_RATE_STD**2
    rates = np.zeros((runs, core.horizon + 1))
    one = np.ones((runs, 1, 1))
    for k in range(1, core.horizon + 1):
        state, _ = ekf.step(state, one, core.z[:runs, k], core.detected[:runs, k], check=False,
                            allow_failure=True)
        rates[:, k] = np.nan_to_num(state.x[:, 0, 4])
    return rates


def detector_runs(
    overrides: dict[str, Any], delays: Sequence[int], runs: int, seed: int,
    yaw_noise: float = 0.01, weights: str | Path | None = None,
) -> dict[tuple[str, float, float], tuple[float, float]]:
    """``{(detector, stay, share): (ARMSE, mode accuracy)}`` of the turn-rate prior at every
    stay of :data:`STAYS` and share of :data:`SHARES` led by each detector (module docstring:
    ``"true, d late"`` for each of ``delays``, ``"tracker (env)"``, ``"CT-omega EKF"``,
    ``"learned (env)"`` with the network ``weights``, by default the shipped one), on runs
    ``seed .. seed + runs - 1``. Where the conditions vary per run (``vary``) the EKF, which
    runs one sampling period and one sensor, is left out."""
    varied = EnvConfig.build(dict(overrides)).vary.active
    names = [f"true, {d} late" for d in delays] + ["tracker (env)"]
    names += ([] if varied else ["CT-omega EKF"]) + ["learned (env)"]
    combos = [(name, s, v) for name in names for s in STAYS for v in SHARES]
    slots = prior_core(overrides, len(combos), runs, seed)
    core = slots.core
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
    learned = kind == names.index("learned (env)")
    # the env's detector: the heading rate of each slot's own estimate, smoothed
    smoothed = np.zeros(core.n_envs)
    velocity = core.state_a.x[:, 0, 2:4].copy()
    # the learned one: its unsteered IMM once per run (slots 0 .. runs - 1 are runs 0 ..)
    network = learned_network(core, runs, omegas, weights)

    def rows(k: int, info: dict[str, Any] | None) -> Array:
        nonlocal smoothed, velocity
        if info is not None:
            estimate = info["estimate"][:, 2:4]
            smoothed = TURN_RATE_FACTOR * smoothed + (1.0 - TURN_RATE_FACTOR) * heading_rate(
                velocity, estimate, T
            )
            velocity = estimate.copy()
            network.step(core.z[:runs, k], core.detected[:runs, k], first(core.state_a, runs),
                         T[:runs])
        late = k - delay
        rate = np.where(late >= 0, true_rate[run, np.clip(late, 0, K - 1)], 0.0)
        rate = np.where(tracker, smoothed, rate)
        rate = np.where(ekf, ekf_rate[run, k], rate)
        b = np.where(learned[:, None], network.belief[run], belief(rate))
        return detector_tpm_rows(stays, b, shares)

    result = run_priors(slots, rows)
    return {combo: result.scores(c)[:2] for c, combo in enumerate(combos)}


def learned_network(
    core: TrackingCore, runs: int, omegas: Array, weights: str | Path | None
) -> LearnedDetector:
    """The learned detector of the core's first ``runs`` slots, started from their posteriors
    (under varied conditions, at their sampling periods and sensors)."""
    args = core.batch_kernel_args
    if args is not None and args[0].shape[0] > 1:
        args = (*(a[:runs] for a in args[:3]), *args[3:])
    detector = LearnedDetector(core.imm, runs, args, omegas,
                               DetectorNetwork.load(weights or DEFAULT_WEIGHTS))
    detector.start(np.arange(runs), first(core.state_a, runs), args)
    return detector


def first(state: IMMState, runs: int) -> IMMState:
    """The posteriors of the first ``runs`` slots."""
    return IMMState(state.x[:runs], state.P[:runs], state.mu[:runs])


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--suite", default="benchmark")
    p.add_argument("--scenario", action="append", help="a scenario of the suite (default: all "
                   "of them, unless --env-config is given)")
    p.add_argument("--env-config", type=Path, action="append", default=[], metavar="FILE",
                   help="a configuration file (YAML or JSON of EnvConfig fields): a column of its "
                   "own, headed by the path as given")
    p.add_argument("--delay", type=int, action="append",
                   help="steps the true turn rate is known late (default: 0 1 3 5 8)")
    p.add_argument("--yaw-noise", type=float, default=0.01,
                   help="the CT-omega EKF's yaw acceleration noise (rad/s²)")
    p.add_argument("--detector-weights", type=Path, metavar="FILE",
                   help="the learned detector's network (default: the shipped one)")
    args = p.parse_args(argv)
    if args.runs < 1:
        p.error(f"--runs must be >= 1, got {args.runs}")
    if args.seed < 0:
        p.error(f"--seed must be >= 0, got {args.seed}")
    delays = args.delay or [0, 1, 3, 5, 8]
    if min(delays) < 0:
        p.error(f"--delay must be >= 0 (steps late; below 0 the detector sees the future), got "
                f"{min(delays)}")
    if not 0.0 <= args.yaw_noise < math.inf:
        p.error(f"--yaw-noise must be a finite number >= 0 (rad/s²), got {args.yaw_noise}")
    try:
        suite = suite_configs(args.suite)
    except ConfigError as err:
        p.error(str(err))
    chosen = args.scenario or ([] if args.env_config else list(suite))
    unknown = sorted(set(chosen) - set(suite))
    if unknown:
        p.error(f"--scenario must be among {list(suite)}, got {unknown}")
    if len({str(path) for path in args.env_config}) < len(args.env_config):
        p.error(f"--env-config given a file twice: {[str(path) for path in args.env_config]}")
    configs = {name: suite[name] for name in chosen}
    for path in args.env_config:
        try:  # keyed by the path as given: files of one name in other folders are two columns
            configs[str(path)] = read_env_config(path)
        except ConfigError as err:
            p.error(f"--env-config: {err}")
    try:
        DetectorNetwork.load(args.detector_weights or DEFAULT_WEIGHTS)
    except ConfigError as err:
        p.error(f"--detector-weights: {err}")
    weights = str(args.detector_weights or DEFAULT_WEIGHTS)  # the learned rows' network
    for name, overrides in configs.items():  # every column's, before the first one's runs
        try:
            base = EnvConfig.build({**overrides, "detector_weights": weights})
        except ConfigError as err:
            p.error(f"{name}: {err}")
        # the baselines whose priors the rows run, checked as evaluate checks them
        for row, policy in (("tracker (env)", "turn-rate-prior"),
                            ("learned (env)", "learned-prior")):
            reason = cannot_run(policy, base, args.seed)
            if reason:
                p.error(f"{name}: the turn-rate prior ({policy}, the {row!r} row) cannot run on "
                        f"this configuration: {reason}")
    print(f"runs {args.seed}..{args.seed + args.runs - 1}; position ARMSE (m) / mode accuracy "
          f"(stay, share) of each detector's best prior on these runs")
    table: dict[str, list[str]] = {}
    for column, overrides in enumerate(configs.values()):
        scores = detector_runs(overrides, delays, args.runs, args.seed, args.yaw_noise,
                               args.detector_weights)
        for detector in dict.fromkeys(d for d, _, _ in scores):
            (armse, acc), s, v = min(
                (scores[(detector, s, v)], s, v) for s in STAYS for v in SHARES
            )
            cells = table.setdefault(detector, ["—"] * len(configs))
            accuracy = "—" if acc is None else f"{100 * acc:.0f} %"  # None: nothing to score
            cells[column] = f"{armse:.2f} / {accuracy} ({s:.3g}, {v:g})"
    print("| detector | " + " | ".join(configs) + " |")
    print("|---|" + "---|" * len(configs))
    for detector, cells in table.items():
        print(f"| {detector} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
