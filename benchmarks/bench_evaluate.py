"""Wall time of the Monte-Carlo evaluation of the five baselines of issue #19, one core.

Times ``imm_gym.cli.evaluate.evaluate`` on the paper scenario (100 runs) for each of them (fixed,
tip-imm, best-fixed, amp-imm, window) alone and for all of them together (the best fixed TPM
includes its search over 12 stay probabilities on 100 training runs), plus the clairvoyant bound:
the median over ``--repeats`` repeats (each timing in turn, so that a change in the machine's
speed hits them alike) with the smallest and largest. Import and the numba kernel's first load
are timed once, apart. The aim of issue #19 (checked for the paper scenario at 100 runs): all
five with the bound in at most 1 s. Run from the repository root::

    python benchmarks/bench_evaluate.py [--runs 100] [--scenario paper] [--repeats 5]
"""

from __future__ import annotations

import os

import harness

os.environ.update(harness.ONE_THREAD)  # single core: before numpy (and numba) are imported

import argparse
import time

import numpy as np

POLICIES = ("fixed", "tip-imm", "best-fixed", "amp-imm", "window")
ALL = "all five + clairvoyant bound"
AIM_S = 1.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--scenario", default="paper")
    harness.add_repeats(parser, "timed repeats of each evaluation (default 5)")
    args = parser.parse_args(argv)
    repeats = harness.count(args.repeats, False, 5, 5, "--repeats")
    t0 = time.perf_counter()
    from imm_gym.cli.evaluate import evaluate

    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    evaluate(["fixed"], args.scenario, 2, 0, clairvoyant=False)  # first kernel load
    t_warm = time.perf_counter() - t0
    calls = {name: ([name], False) for name in POLICIES}
    calls[ALL] = (list(POLICIES), True)
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeats):
        for name, (policies, clairvoyant) in calls.items():
            t0 = time.perf_counter()
            evaluate(policies, args.scenario, args.runs, 0, clairvoyant=clairvoyant)
            times[name].append(time.perf_counter() - t0)
    table = harness.table(
        f"Evaluation wall time, scenario {args.scenario}, {args.runs} runs, 1 core",
        "what",
        harness.right("seconds"),
        harness.range_column(),
        caption=f"median of {repeats} repeats (min – max); once: import, first kernel load",
    )
    table.add_row("import imm_gym.cli.evaluate", f"{t_import:.2f}", "")
    table.add_row("first kernel load (numba cache)", f"{t_warm:.2f}", "")
    for name, values in times.items():
        table.add_row(name, f"{np.median(values):.2f}", f"({min(values):.2f} – {max(values):.2f})")
    console = harness.make_console(width=100)
    console.print(table)
    if (args.scenario, args.runs) == ("paper", 100):  # what the aim is set for
        total = float(np.median(times[ALL]))
        console.print(
            f"{ALL}: {total:.2f} s (aim ≤ {AIM_S:.0f} s): {harness.verdict(total <= AIM_S)}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
