"""Wall time of the Monte-Carlo evaluation of every baseline, one core.

Times ``imm_gym.cli.evaluate.evaluate`` on the paper scenario (100 runs) for each baseline alone and
for all of them together (the best fixed TPM includes its search over 12 stay probabilities on
100 training runs), plus the clairvoyant bound. Import and the numba kernel's first load are timed
separately. Run from the repository root::

    python benchmarks/bench_evaluate.py [--runs 100] [--scenario paper]
"""

from __future__ import annotations

import os

import harness

os.environ.update(harness.ONE_THREAD)  # single core: before numpy (and numba) are imported

import argparse
import time

POLICIES = ("fixed", "tip-imm", "best-fixed", "amp-imm", "window")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--scenario", default="paper")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    from imm_gym.cli.evaluate import evaluate

    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    evaluate(["fixed"], args.scenario, 2, 0, clairvoyant=False)  # first kernel load
    t_warm = time.perf_counter() - t0
    table = harness.table(
        f"Evaluation wall time, scenario {args.scenario}, {args.runs} runs, 1 core",
        "what",
        harness.right("seconds"),
    )
    table.add_row("import imm_gym.cli.evaluate", f"{t_import:.2f}")
    table.add_row("first kernel load (numba cache)", f"{t_warm:.2f}")
    for name in POLICIES:
        t0 = time.perf_counter()
        evaluate([name], args.scenario, args.runs, 0, clairvoyant=False)
        table.add_row(name, f"{time.perf_counter() - t0:.2f}")
    t0 = time.perf_counter()
    evaluate(list(POLICIES), args.scenario, args.runs, 0)
    table.add_row("all five + clairvoyant bound", f"{time.perf_counter() - t0:.2f}")
    harness.make_console(width=100).print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
