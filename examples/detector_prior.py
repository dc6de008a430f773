"""What a maneuver detector's share of a fixed switching prior's jumps is worth, scenario by
scenario of the benchmark suite.

A fixed TPM with the stay ``s`` spreads each row's jumps evenly, and on the suite's `paper` and
`random` scenarios the best of them is nearly uniform, whose mode probabilities say nothing (one
step's likelihoods barely tell the models apart). The prior of
:func:`imm_gym.sim.stay_bank.detector_tpm_rows` places the share ``v`` of the jumps by the mode
probabilities of the shadow IMM, a classical IMM at the tracker's own TPM that accumulates the
evidence: ``c = r mu + (1 - r) ((1 - v) / M + v mu_S)``. This runs both on the same runs (common
random numbers) for every stay of a grid and prints position ARMSE (m) / mode accuracy / mode-
probability total variation per step, and the best stay of each share::

    python examples/detector_prior.py --runs 100 --seed 0

The priors run through :mod:`imm_gym.evaluation.priors` (``set``-mode logits): a row whose
entries are all at least the floor ``P_MIN`` runs exactly, as the documented shares' do; an entry
below it (shares from about 0.96 with a confident belief) is raised to the floor and the rest of
its row shrinks.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

import numpy as np

from imm_gym.cli.suite import suite_configs
from imm_gym.evaluation.priors import prior_core, run_priors
from imm_gym.sim.stay_bank import detector_tpm_rows
from imm_gym.validation import ConfigError

STAYS = (1 / 3, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995)


def detector_runs(
    overrides: dict[str, Any], shares: tuple[float, ...], runs: int, seed: int
) -> dict[tuple[float, float], tuple[float, float, float]]:
    """``{(stay, share): (ARMSE, mode accuracy, TV)}`` of the prior at every stay of
    :data:`STAYS` and every share, on runs ``seed .. seed + runs - 1``."""
    combos = [(s, v) for s in STAYS for v in shares]
    slots = prior_core(overrides, len(combos), runs, seed)
    core = slots.core
    stays = np.repeat([s for s, _ in combos], runs)
    share = np.repeat([v for _, v in combos], runs)

    def rows(k: int, info: dict[str, Any] | None) -> np.ndarray:
        return detector_tpm_rows(stays, core.mu_s, share)

    result = run_priors(slots, rows)
    return {combo: result.scores(c) for c, combo in enumerate(combos)}


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--suite", default="benchmark")
    p.add_argument("--share", type=float, default=0.5, help="the detector's share v (0, 1]")
    args = p.parse_args(argv)
    if args.runs < 1:
        p.error(f"--runs must be >= 1, got {args.runs}")
    if args.seed < 0:
        p.error(f"--seed must be >= 0, got {args.seed}")
    if not 0.0 < args.share <= 1.0:
        p.error(f"--share must be in (0, 1] (the detector's share of the prior), got {args.share}")
    try:
        suite = suite_configs(args.suite)
    except ConfigError as err:
        p.error(str(err))
    shares = (0.0, args.share)
    print(f"runs {args.seed}..{args.seed + args.runs - 1}; position ARMSE (m) / mode accuracy / "
          f"TV per step; the shadow IMM at the tracker's TPM")
    print("| scenario | share | " + " | ".join(f"stay {s:.3g}" for s in STAYS) + " | best |")
    print("|---|---|" + "---|" * (len(STAYS) + 1))
    for name, overrides in suite.items():
        scores = detector_runs(overrides, shares, args.runs, args.seed)
        for v in shares:
            row = [scores[(s, v)] for s in STAYS]
            cells = [
                f"{e:.2f} / " + ("—" if a is None else f"{100 * a:.0f} %") + " / "
                + ("—" if tv is None else f"{tv:.2f}")  # None: nothing to score (all lost)
                for e, a, tv in row
            ]
            best = min(range(len(STAYS)), key=lambda i: row[i][0])
            print(f"| {name} | {v:g} | " + " | ".join(cells) + f" | {row[best][0]:.2f} "
                  f"(stay {STAYS[best]:.3g}) |", flush=True)


if __name__ == "__main__":
    main()
