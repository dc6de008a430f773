"""Monte-Carlo evaluation of TPM policies (command line: ``python -m imm_gym.evaluate``).

Every policy is scored on the same R runs — same targets, same sensor noise (common random
numbers, :mod:`imm_gym.montecarlo`) — and reported in the layout of the paper's Table 2 (position
ARMSE overall / X / Y, velocity ARMSE X / Y), with NIS/NEES consistency, mode-identification
accuracy and the clairvoyant bound.

Example::

    python -m imm_gym.evaluate --policy fixed --scenario paper --runs 100 --seed 0 --json out.json

The JSON file has the layout ``{"policies": {NAME: {"armse_pos": ..., "armse_pos_x": ...,
"armse_pos_y": ..., "armse_vel_x": ..., "armse_vel_y": ..., ...}}, "clairvoyant": {...},
"meta": {...}}``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .clairvoyant import clairvoyant_filter
from .config import ConfigError, from_dict
from .imm import IMM
from .metrics import consistency, mode_accuracy, nees, tracking_errors, true_model_index
from .models import MotionModel, paper_bank
from .montecarlo import Batch, draw_batch
from .scenarios import RandomFamily, Scenario, paper_scenario
from .sensors import Sonar
from .tpm import stay_tpm

Array = NDArray[np.float64]

#: The paper's Table 2 (ARMSE; m and m/s), for side-by-side printing on the paper scenario.
PAPER_TABLE2 = {
    "paper: classical IMM": {
        "armse_pos": 18.3600,
        "armse_pos_x": 11.4543,
        "armse_pos_y": 14.4556,
        "armse_vel_x": 1.0437,
        "armse_vel_y": 1.6767,
    },
    "paper: TIP-IMM": {
        "armse_pos": 17.0247,
        "armse_pos_x": 10.6614,
        "armse_pos_y": 13.3926,
        "armse_vel_x": 1.0190,
        "armse_vel_y": 1.6014,
    },
}

#: Stay probability of the paper preset's fixed TPM (SPEC §6).
PAPER_STAY = 0.995


@dataclass(frozen=True)
class PolicyRun:
    """A policy's estimates over a batch: ``x (R, K, n)``, ``P (R, K, n, n)``,
    ``mode_probs (R, K, M)``, ``nis (R, K)`` and the detection mask ``(R, K)``."""

    x: Array
    P: Array
    mode_probs: Array
    nis: Array
    detected: NDArray[np.bool_]


def run_fixed_tpm(batch: Batch, imm: IMM, tpm: Array) -> PolicyRun:
    """Classical IMM: the same TPM at every step."""
    det = batch.measurements.detected[:, 1:]
    res = imm.run(batch.measurements.z[:, 1:], tpm, batch.x0, batch.P0, detected=det)
    return PolicyRun(res.x, res.P, res.mode_probs, res.nis, det)


PolicyRunner = Callable[[Batch, IMM], PolicyRun]


def builtin_policies(n_models: int) -> dict[str, PolicyRunner]:
    """Policies available by name."""
    return {
        "fixed": lambda batch, imm: run_fixed_tpm(batch, imm, stay_tpm(n_models, PAPER_STAY)),
    }


def score(
    run: PolicyRun, batch: Batch, models: Sequence[MotionModel], dim_z: int
) -> dict[str, Any]:
    """Table-2 errors, consistency and mode accuracy of one policy on a batch."""
    truth = batch.truth.states[:, 1:]
    out: dict[str, Any] = tracking_errors(run.x, truth)
    out["nis"] = consistency(run.nis, dim_z, mask=run.detected)
    out["nees"] = consistency(nees(run.x, run.P, truth), 4)
    out["mode_accuracy"] = mode_accuracy(run.mode_probs, true_model_index(batch.truth, models))
    return out


def load_source(name: str) -> Scenario | RandomFamily:
    """``paper``, ``random`` or a JSON file holding a :class:`Scenario` (``segments`` list...)."""
    if name == "paper":
        return paper_scenario()
    if name == "random":
        return RandomFamily()
    path = Path(name)
    if not path.is_file():
        raise ConfigError(
            f"--scenario must be 'paper', 'random' or a JSON file; {name!r} is neither"
        )
    data = json.loads(path.read_text())
    if "segments" in data:
        data = {**data, "segments": tuple(data["segments"])}
    return from_dict(Scenario, data, f"scenario file {name}")


def evaluate(
    policies: Sequence[str],
    source: Scenario | RandomFamily,
    runs: int,
    seed: int,
    filter: str = "ukf",
    clairvoyant: bool = True,
) -> dict[str, Any]:
    """Score ``policies`` on R common-random-number runs of ``source``; see the module docstring."""
    sensor = Sonar()
    models = paper_bank()
    imm = IMM(models, sensor, filter=filter)
    available = builtin_policies(len(models))
    unknown = [p for p in policies if p not in available]
    if unknown:
        raise ConfigError(f"unknown policy {unknown}; available: {sorted(available)}")
    batch = draw_batch(source, sensor, runs, seed)
    results: dict[str, Any] = {"policies": {}}
    for name in policies:
        results["policies"][name] = score(available[name](batch, imm), batch, models, sensor.dim_z)
    if clairvoyant:
        xs, _ = clairvoyant_filter(
            batch.truth,
            batch.measurements.z[:, 1:],
            sensor,
            models,
            batch.x0,
            batch.P0,
            filter,
            batch.measurements.detected[:, 1:],
        )
        results["clairvoyant"] = tracking_errors(xs, batch.truth.states[:, 1:])
    results["meta"] = {
        "runs": runs,
        "seed": seed,
        "steps": batch.horizon,
        "filter": filter,
        "versions": _versions(),
    }
    return results


def _versions() -> dict[str, str]:
    import scipy

    from . import __version__

    return {
        "imm_gym": __version__,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "python": platform.python_version(),
    }


TABLE_COLUMNS = (
    ("armse_pos", "pos (m)"),
    ("armse_pos_x", "X (m)"),
    ("armse_pos_y", "Y (m)"),
    ("armse_vel_x", "vel X (m/s)"),
    ("armse_vel_y", "vel Y (m/s)"),
)


def print_table(results: dict[str, Any], scenario: str) -> None:
    """Print the Table-2 layout with rich."""
    from rich.console import Console
    from rich.table import Table

    meta = results["meta"]
    table = Table(
        title=f"ARMSE on scenario '{scenario}', {meta['runs']} runs, seed {meta['seed']}, "
        f"{meta['steps']} steps, {meta['filter'].upper()}"
    )
    table.add_column("policy")
    for _, label in TABLE_COLUMNS:
        table.add_column(label, justify="right")
    for label in ("NIS in 95%", "NEES in 95%", "mode acc."):
        table.add_column(label, justify="right")
    for name, r in results["policies"].items():
        table.add_row(
            name,
            *(f"{r[k]:.4f}" for k, _ in TABLE_COLUMNS),
            f"{100 * r['nis']['inside']:.1f}%",
            f"{100 * r['nees']['inside']:.1f}%",
            f"{100 * r['mode_accuracy']:.1f}%",
        )
    if "clairvoyant" in results:
        c = results["clairvoyant"]
        table.add_row("clairvoyant (bound)", *(f"{c[k]:.4f}" for k, _ in TABLE_COLUMNS), "", "", "")
    if scenario == "paper":
        for name, r in PAPER_TABLE2.items():
            table.add_row(name, *(f"{r[k]:.4f}" for k, _ in TABLE_COLUMNS), "", "", "", style="dim")
    Console(width=None if sys.stdout.isatty() else 150).print(table)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m imm_gym.evaluate",
        description="Monte-Carlo evaluation of TPM policies with common random numbers.",
    )
    parser.add_argument(
        "--policy",
        action="append",
        required=True,
        help="policy to evaluate (repeatable); available: fixed",
    )
    parser.add_argument("--scenario", default="paper", help="paper | random | a scenario JSON file")
    parser.add_argument("--runs", type=int, default=100, help="Monte-Carlo runs (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="run r uses seed + r (default 0)")
    parser.add_argument("--filter", choices=("ukf", "ekf"), default="ukf")
    parser.add_argument("--json", type=Path, help="write the results to this JSON file")
    parser.add_argument("--no-clairvoyant", action="store_true", help="skip the clairvoyant bound")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error(f"--runs must be >= 1, got {args.runs}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    try:
        source = load_source(args.scenario)
        results = evaluate(
            args.policy, source, args.runs, args.seed, args.filter, not args.no_clairvoyant
        )
    except ConfigError as err:
        parser.error(str(err))
    results["meta"]["scenario"] = args.scenario
    results["meta"]["command"] = " ".join(["python -m imm_gym.evaluate", *sys.argv[1:]])
    print_table(results, args.scenario)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
