"""Any policy on recorded measurements (command line: ``python -m imm_gym.track``).

Example::

    python -m imm_gym.track --measurements radar.csv --policy pretrained --out tracks.csv
    python -m imm_gym.track --measurements radar.npz --policy tip-imm \\
        --env-config my_tracker.yaml --out tracks.npz

Runs :func:`imm_gym.sim.replay.run_policy` (the policy's whole observation pipeline, no truth) on
every recorded sequence and writes, per step, the estimate, its covariance, the mode
probabilities and the TPM used. ``--policy`` is a baseline's name, ``pretrained``,
``pretrained-per-model`` (a bank of any size) or a trained agent's directory, resolved as
``python -m imm_gym.evaluate`` resolves them (a tuned baseline such as ``best-fixed`` is tuned on
simulated runs of the configuration, seeds from ``--seed``: 0 to
:data:`~imm_gym.cli.arguments.MAX_SEED`, as for ``python -m imm_gym.evaluate``).
``--env-config FILE`` (YAML or JSON, :mod:`imm_gym.sim.config_file`) is a mapping of
EnvConfig fields: the sensor (whose components ``z`` are), the bank, the filter, the TPM settings,
the scenario (its sampling period); what it says an agent is trained as
(:data:`~imm_gym.sim.mixture.AGENT_FIELDS`: action mode, features, reward) is dropped, a detector
network it names kept, as ``python -m imm_gym.evaluate`` does (every policy's own settings apply:
a training file runs the rules too). A trained agent keeps its own settings and tracks with this
tracker; an agent whose observation or action size it does not give is refused, one trained on
another tracker is said on stderr.

Input (read by :mod:`imm_gym.cli.recordings`, whose docstring gives the layouts): a ``.csv``
or ``.npz`` file of one or more sequences of measurements; each sequence's first row initiates
the track and each later row is one filter step.

Without a velocity the track starts at zero velocity with standard deviation
:data:`~imm_gym.sim.replay.UNKNOWN_VELOCITY_STD`; ``--velocity VX VY`` gives one for every
sequence that has none. The sequences run as one batch (one per kind of start: ``x0``/``P0``,
a velocity, none), the shorter ones padded with missed detections and cut back — split where
the padding would more than double a batch's steps beyond ``PADDED_STEPS``. A network
policy's matrix products round by the batch's shape, so a sequence tracked beside others can
differ from itself tracked alone in the last bits (about 1e-7 m); the rules do not.
A configuration file that names a scenario other than ``random`` tracks at that scenario's
sampling period, said on stderr (``family`` beside it is refused: it would be ignored).

Output, by the suffix of ``--out`` (checked before any work, its missing directories made):

* ``.csv``: one row per filtered step, the sequences in the input's order: ``sequence, step``
  (1..K), ``x, y, vx, vy``, ``P00 .. P33`` (the covariance, row-major), ``mu0 .. mu{M-1}``,
  ``tpm00 .. tpm{M-1}{M-1}`` (row-major; ``tpm{i}_{j}`` for more than ten models),
  ``diverged`` (1 from the step the track diverged at: its estimate not finite or its position
  variance above ``divergence_cov``; such tracks are also named on stderr);
* ``.npz``: ``estimate (N, K, 4)``, ``covariance (N, K, 4, 4)``, ``mode_probs (N, K, M)``,
  ``tpm (N, K, M, M)``, ``x0``, ``P0``, ``diverged (N,)``, the sequences in the input's order
  (one sequence length only: sequences of several are refused before any work).
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from baselines import REGISTRY
from imm_gym.cli.arguments import MAX_SEED, output_problem, seed_problem
from imm_gym.cli.comparison import evaluated_config
from imm_gym.cli.policies import agent_overrides, make_policy
from imm_gym.cli.recordings import read_csv, read_npz
from imm_gym.cli.tables import models_differ_note
from imm_gym.sim.config_file import read_env_config
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.replay import TrackResult, run_policy
from imm_gym.validation import ConfigError

#: The padded steps (sequences x longest length) a batch of sequences may take whatever its
#: padding costs (:func:`batches`): a small file runs as one batch.
PADDED_STEPS = 100_000


def run(
    sequences: list[dict[str, Any]],
    policy: Any,
    config: EnvConfig,
    velocity: Sequence[float] | None,
    overrides: Mapping[str, Any],
) -> list[tuple[str, TrackResult]]:
    """:func:`run_policy` on the sequences: ``(name, result)`` per sequence (``N = 1``), in the
    input's order. Sequences that start alike (from ``x0``/``P0``, a velocity, or none) run in
    batches (:func:`batches`), the shorter ones padded with missed detections to their batch's
    longest and cut back to their own length (a step depends on none after it); a sequence's
    ``diverged_at`` counts its own steps only."""
    if not sequences:
        raise ConfigError("no measurements")
    started = []  # each sequence with --velocity where it gives no start of its own
    for seq in sequences:
        if seq.get("velocity") is None and velocity is not None and "x0" not in seq:
            seq = {**seq, "velocity": np.asarray(velocity, dtype=np.float64)}
        started.append(seq)
    results: dict[int, tuple[str, TrackResult]] = {}
    for kind in ("x0", "velocity", None):
        alike = [(i, seq) for i, seq in enumerate(started) if _start_kind(seq) == kind]
        for group in batches(alike, PADDED_STEPS):
            results.update(_run_batch(group, kind, policy, config, overrides))
    return [results[i] for i in range(len(sequences))]


def batches(
    sequences: list[tuple[int, dict[str, Any]]], floor: int
) -> list[list[tuple[int, dict[str, Any]]]]:
    """``sequences`` (index, sequence) in batches to run padded to each batch's longest: by
    length, longest first, a sequence joining the batch while the batch's padded steps stay
    within twice its own or ``floor`` — one batch for sequences of like lengths or a small file
    (a call per length ran 12x slower on real recordings), and a long recording beside many
    short ones not padded into gigabytes."""
    out: list[list[tuple[int, dict[str, Any]]]] = []
    steps = 0
    for item in sorted(sequences, key=lambda item: -item[1]["z"].shape[0]):
        n = item[1]["z"].shape[0]
        if out and (len(out[-1]) + 1) * out[-1][0][1]["z"].shape[0] <= max(2 * (steps + n), floor):
            out[-1].append(item)
            steps += n
        else:
            out.append([item])
            steps = n
    return out


def _run_batch(
    group: list[tuple[int, dict[str, Any]]],
    kind: str | None,
    policy: Any,
    config: EnvConfig,
    overrides: Mapping[str, Any],
) -> dict[int, tuple[str, TrackResult]]:
    """One batch of :func:`run`: its sequences' ``(name, result)`` by input index."""
    results: dict[int, tuple[str, TrackResult]] = {}
    longest = max(seq["z"].shape[0] for _, seq in group)
    z = np.full((len(group), longest, config.sensor.dim_z), np.nan)
    detected = np.zeros((len(group), longest), dtype=bool)
    for row, (_, seq) in enumerate(group):
        n = seq["z"].shape[0]
        z[row, :n] = seq["z"]
        detected[row, :n] = (
            np.all(np.isfinite(seq["z"]), axis=1) if seq.get("detected") is None
            else seq["detected"]
        )
    args: dict[str, Any] = {}
    if kind == "x0":
        args["x0"] = np.stack([seq["x0"] for _, seq in group])
        args["P0"] = np.stack([seq["P0"] for _, seq in group])
    elif kind == "velocity":
        args["velocity"] = np.stack([seq["velocity"] for _, seq in group])
    result = run_policy(z, policy, config, detected=detected, overrides=overrides, **args)
    for row, (i, seq) in enumerate(group):
        results[i] = (seq["name"], _cut(result, row, seq["z"].shape[0] - 1))
    return results


def _start_kind(seq: dict[str, Any]) -> str | None:
    if seq.get("x0") is not None:
        return "x0"
    return "velocity" if seq.get("velocity") is not None else None


def _cut(result: TrackResult, row: int, steps: int) -> TrackResult:
    """Sequence ``row`` of a batch's result, its first ``steps`` steps (``N = 1``)."""
    return TrackResult(
        result.estimate[row : row + 1, :steps], result.covariance[row : row + 1, :steps],
        result.mode_probs[row : row + 1, :steps], result.tpm[row : row + 1, :steps],
        result.x0[row : row + 1], result.P0[row : row + 1],
        np.minimum(result.diverged_at[row : row + 1], steps),
    )


def tpm_columns(M: int) -> list[str]:
    """The TPM's CSV columns, row-major: ``tpm{i}{j}``, or ``tpm{i}_{j}`` for banks of more
    than ten models (where ``tpm110`` would name both entry (1, 10) and (11, 0))."""
    sep = "_" if M > 10 else ""
    return [f"tpm{i}{sep}{j}" for i in range(M) for j in range(M)]


def write(path: Path, results: list[tuple[str, TrackResult]]) -> None:
    """Write the results as CSV or NPZ (see the module docstring), the sequences in the order
    given; missing parent directories are made."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".npz":
        lengths = sorted({r.estimate.shape[1] for _, r in results})
        if len(lengths) != 1:  # main checks it before the tracking
            raise ConfigError(f"{path}: an NPZ output holds sequences of one length only")
        arrays = {
            key: np.concatenate([getattr(r, key) for _, r in results])
            for key in ("estimate", "covariance", "mode_probs", "tpm", "x0", "P0", "diverged")
        }
        np.savez(path, **arrays)
        return
    M = results[0][1].mode_probs.shape[-1]
    header = ["sequence", "step", "x", "y", "vx", "vy"]
    header += [f"P{i}{j}" for i in range(4) for j in range(4)]
    header += [f"mu{i}" for i in range(M)] + tpm_columns(M) + ["diverged"]
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for name, r in results:
            for k in range(r.estimate.shape[1]):
                values = np.concatenate([
                    r.estimate[0, k], r.covariance[0, k].ravel(), r.mode_probs[0, k],
                    r.tpm[0, k].ravel(),
                ])
                writer.writerow([name, k + 1, *(repr(float(v)) for v in values),
                                 int(k >= r.diverged_at[0])])


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m imm_gym.track",
        description="Run a TPM policy on recorded measurements (no truth): estimates, "
        "covariances, mode probabilities and the TPM used at each step.",
    )
    parser.add_argument("--measurements", required=True, type=Path,
                        help="CSV (columns z0.., optional sequence, detected, vx, vy) or NPZ")
    parser.add_argument("--policy", required=True,
                        help="a baseline's name, 'pretrained', 'pretrained-per-model' or a trained "
                             "agent's directory")
    parser.add_argument("--env-config", type=Path, default=None,
                        help="YAML or JSON mapping of EnvConfig fields (sensor, bank, filter...)")
    parser.add_argument("--out", required=True, type=Path, help="output file: .csv or .npz")
    parser.add_argument("--velocity", type=float, nargs=2, metavar=("VX", "VY"), default=None,
                        help="initial velocity (m/s) of sequences that give none "
                        "(default: zero, standard deviation 30 m/s)")
    parser.add_argument("--seed", type=int, default=0,
                        help=f"seed of a tuned baseline's simulated training runs (0 to "
                        f"{MAX_SEED})")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """The command line; returns the exit status (2: a usage or input error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    problem = seed_problem(args.seed, 1)  # a tuned baseline's seeds, checked as evaluate's
    if problem:
        parser.error(problem)
    for name, path in (("--measurements", args.measurements), ("--out", args.out)):
        if path.suffix not in (".csv", ".npz"):
            parser.error(f"{name} must end in .csv or .npz, got {path}")
    problem = output_problem(args.out, "file")  # before any work, as evaluate's outputs
    if problem:
        parser.error(f"--out {str(args.out)!r}: {problem}")
    if args.out.resolve() == args.measurements.resolve() or (  # or a hard link to it
        args.out.exists() and args.measurements.exists()
        and os.path.samefile(args.out, args.measurements)
    ):
        parser.error(f"--out {str(args.out)!r} is the --measurements file: it would be "
                     "overwritten; give another output file")
    if args.velocity is not None and not np.all(np.isfinite(args.velocity)):
        parser.error(f"--velocity must be two finite numbers (m/s), got {args.velocity}")
    try:
        # as evaluate's: what the file says an agent is trained as is each policy's own
        overrides = {} if args.env_config is None else read_env_config(args.env_config)
        scenario = overrides.pop("scenario", "random")
        if "family" in overrides and scenario != "random":
            raise ConfigError(
                f"{args.env_config}: family applies to scenario 'random' only, and the "
                f"scenario ({_scenario_name(scenario)}) gives the sampling period: give one of "
                "them"
            )
        config = evaluated_config(scenario, overrides)
        if not args.measurements.is_file():
            what = (
                "is a directory" if args.measurements.is_dir()
                else "not a regular file" if args.measurements.exists()
                else "no such file"
            )
            raise ConfigError(f"{args.measurements}: {what}")
        sequences = (
            read_csv(args.measurements, config.sensor)
            if args.measurements.suffix == ".csv"
            else read_npz(args.measurements, config.sensor)
        )
        if not sequences:
            raise ConfigError(f"{args.measurements}: no measurements (no sequence)")
        odd = [where for seq in sequences for where in seq["implausible"]]
        if odd:
            print(f"warning: {len(odd)} detection(s) outside the sensor's units (it takes "
                  f"{config.sensor.measurement_units}; degrees, or a sign, likely), first at "
                  f"{odd[0]}: tracked as given", file=sys.stderr)
        lengths = sorted({s["z"].shape[0] - 1 for s in sequences})
        if args.out.suffix == ".npz" and len(lengths) > 1:
            raise ConfigError(
                f"--out {str(args.out)!r}: an NPZ output holds sequences of one length (its arrays "
                f"are (N, K, ...)); the input's have {', '.join(map(str, lengths))} steps: write "
                "a CSV"
            )
        policy, overrides, _ = make_policy(args.policy, config, args.seed)
        if args.policy not in REGISTRY:  # a trained agent: sizes checked, tracker config's
            overrides, notes = agent_overrides(policy, overrides, config)
            if notes["tracker_differs"]:
                fields = notes["tracker_differs"]
                verb = "differs" if len(fields) == 1 else "differ"
                print(f"{args.policy} was trained on another tracker (its {' and '.join(fields)} "
                      f"{verb}): it tracks with the configured one", file=sys.stderr)
            if "models_differ" in notes:
                print(models_differ_note(args.policy, notes["models_differ"]), file=sys.stderr)
        print(f"tracking at T = {config.source.T:g} s, the sampling period of the scenario "
              f"({_scenario_name(config.scenario)})", file=sys.stderr)
        results = run(sequences, policy, config, args.velocity, overrides)
        try:
            write(args.out, results)
        except OSError as err:  # checked up front; a full disk, say
            raise ConfigError(f"--out {str(args.out)!r}: cannot write ({err})") from None
    except ConfigError as err:
        parser.error(str(err))
    diverged = [(name, int(r.diverged_at[0]) + 1) for name, r in results if r.diverged[0]]
    if diverged:
        listed = ", ".join(f"{name!r} at step {k}" for name, k in diverged[:10])
        more = f" and {len(diverged) - 10} more" if len(diverged) > 10 else ""
        print(f"warning: {len(diverged)} track(s) diverged (estimate not finite or position "
              f"variance above divergence_cov, {config.divergence_cov:g} m²; column diverged "
              f"1 from then on): {listed}{more}", file=sys.stderr)
    print(f"{args.policy}: {len(results)} sequence(s) tracked -> {args.out}")
    return 0


def _scenario_name(scenario: Any) -> str:
    """A scenario as a user names it: ``'paper'``, or one a file gives in full."""
    return repr(scenario) if isinstance(scenario, str) else "the file's own"
