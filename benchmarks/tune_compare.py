"""BBSCA vs SCA vs the untuned bank: the innovation objective J on held-out runs.

For each optimizer seed, both optimizers tune the bank's Q and R factors on the same training runs
(seeds 1 000 000 ..) with the same budget (particles x (generations + 1) evaluations); the tuned
banks are then scored on held-out runs (seeds 0 ..). Prints a table; ``--json`` writes it.

    python benchmarks/tune_compare.py --bank seed003 --opt-seeds 0 1 2 3 4
"""

from __future__ import annotations

import argparse
import time

import harness
import numpy as np

from imm_gym.papers.systems import draw, run_bank, score_run, system_setup
from imm_gym.papers.tuning import OPTIMIZERS, TunerConfig, bank_objective, tune
from imm_gym.seeding import TRAIN_SEED_OFFSET
from imm_gym.validation import check_range


def decay_value(text: str) -> float:
    """An argparse ``type``: BBSCA's decay lambda, a real number in (0, inf) as ``TunerConfig``
    requires; anything else is a usage error (exit 2) naming the flag and the range."""
    try:
        return check_range("decay", float(text), 0.0, lo_open=True)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"must be a real number in (0.0, inf), got {text!r}"
        ) from None


def main() -> None:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--bank", default="seed003", choices=["seed002", "seed003"])
    parser.add_argument("--train-runs", type=harness.positive_int, default=10)
    parser.add_argument("--test-runs", type=harness.positive_int, default=50)
    parser.add_argument("--particles", type=harness.at_least(2), default=10)
    parser.add_argument("--generations", type=harness.positive_int, default=30)
    parser.add_argument("--opt-seeds", type=harness.seed_int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--decay", type=decay_value, default=4.0, help="BBSCA's r1 decay lambda")
    parser.add_argument("--methods", nargs="+", choices=OPTIMIZERS, default=["bbsca", "sca"])
    harness.add_json(parser)
    args = parser.parse_args()
    imm, family, sensor, tpm = system_setup(args.bank)
    train = draw(family, sensor, args.train_runs, TRAIN_SEED_OFFSET)
    test = draw(family, sensor, args.test_runs, 0)
    held_out = bank_objective(imm, test, tpm, sensor.sigma)
    M = imm.n_models

    def pos_rmse(theta: np.ndarray) -> float:
        s = 10.0**theta
        run = run_bank(imm, test, tpm, np.tile(s[:M], (test.n_runs, 1)), np.full(test.n_runs, s[M]))
        return score_run(run, test, sensor.dim_z)["pos_rmse"]

    zero = np.zeros(M + 1)
    rows: dict[str, list[dict[str, float]]] = {m: [] for m in args.methods}
    untuned = {"test_J": float(held_out(zero[None])[0]), "pos_rmse": pos_rmse(zero)}
    for seed in args.opt_seeds:
        for method in rows:
            cfg = TunerConfig(method, args.particles, args.generations, decay=args.decay, seed=seed)
            t0 = time.perf_counter()
            tuned, res = tune(imm, train, tpm, sensor.sigma, cfg, bank=args.bank)
            rows[method].append(
                {
                    "seed": seed,
                    "train_J": res.value,
                    "test_J": float(held_out(tuned.theta[None])[0]),
                    "pos_rmse": pos_rmse(tuned.theta),
                    "q_scale": list(tuned.q_scale),
                    "r_scale": tuned.r_scale,
                    "seconds": time.perf_counter() - t0,
                }
            )
            r = rows[method][-1]
            print(
                f"{method:5s} seed {seed}: train J {r['train_J']:.4f}  held-out J {r['test_J']:.4f}"
                f"  pos RMSE {r['pos_rmse']:.4f} m  ({r['seconds']:.0f} s)",
                flush=True,
            )
    print(
        f"\n{args.bank}: {args.train_runs} training runs, {args.test_runs} held-out runs, "
        f"{args.particles} particles x {args.generations} generations "
        f"({args.particles * (args.generations + 1)} evaluations each)"
    )
    print(f"untuned: held-out J {untuned['test_J']:.4f}, pos RMSE {untuned['pos_rmse']:.4f} m")
    for method, rs in rows.items():
        tj = np.array([r["test_J"] for r in rs])
        pr = np.array([r["pos_rmse"] for r in rs])
        print(
            f"{method}: held-out J {tj.mean():.4f} ± {tj.std():.4f} (min {tj.min():.4f}, max "
            f"{tj.max():.4f}), pos RMSE {pr.mean():.4f} ± {pr.std():.4f} m"
        )
    if set(rows) == {"bbsca", "sca"}:
        pairs = zip(rows["bbsca"], rows["sca"], strict=True)
        wins = sum(b["test_J"] < s["test_J"] for b, s in pairs)
        print(f"BBSCA below SCA on held-out J for {wins} of {len(args.opt_seeds)} optimizer seeds")
    if args.json is not None:
        harness.write_json(args.json, {"untuned": untuned, **rows, "args": vars(args)})


if __name__ == "__main__":
    main()
