"""The compiled IMM kernel against an earlier revision of it, in one run, on one core.

What is measured: ``imm_gym.tracking.kernels.imm.imm_step`` (one IMM cycle of N trackers: M = 3
models CV, CT(+4°/s), CT(-4°/s), range-bearing sonar, SVD-UKF and EKF; at N = 1 its
``imm_step_one`` where the revision has one, the single-tracker cycle that ``IMM.step`` reaches
through ``checked_step_one``) called directly on the same inputs by this tree's kernel and by the
kernel of ``--baseline`` (default ``07f550f``, the last commit before the structure-of-arrays
kernel), at N = 1, 64, 1024 and 4096; and ``IMM.step`` at N = 1 (the Python entry: input checks,
output arrays, result objects). The baseline is the revision's
``imm_gym/tracking/kernels/imm.py`` with every imm_gym module it imports at module level, and
theirs in turn (``imm_gym/tracking/linalg.py``; since the single-tracker scratch,
``imm_gym/tracking/kernels/scratch.py``), all read with ``git show`` into a cache directory and
imported from there: no compiled code of the baseline comes from this tree. What it imports
inside a function (``sensor_spec``'s ``imm_gym.tracking.sensors``, not called here) is this
tree's, and its arguments are built by this tree's ``IMM.kernel_args``. The inputs are the paper
scenario's measurements after 20 steps of the tracker (realistic covariances); every call gets
the same inputs. Then this tree's UKF with Cholesky sigma points (``filter="ukf-cholesky"``)
against its SVD-UKF on the same inputs: µs per batch step, the speed-up and how far one step's
outputs move.

Reported per configuration: the median over ``--repeats`` repeats (the two kernels take turns
within each repeat; a repeat is as many calls as last about ``MIN_REPEAT_S``) of the µs per batch
step, wall and process-CPU time, M tracker-steps/s (N / µs), the ratio baseline / this tree,
and how far apart the two kernels' outputs are: ``max |Δ| / max |x|``, for each output array
the largest absolute difference divided by the largest magnitude in the reference's array (the
baseline's; the SVD-UKF's in the Cholesky table), the largest over the arrays (NaN in both
counts as equal) — a difference scaled by the array's largest entry, not each element's
relative difference (which a mode probability near 0 moved by rounding would make
meaningless) — and whether all of them are equal bit for bit. A change that only makes the
kernel faster must show 0 and "yes" against the revision it starts from. Against a revision
before c51bd7b (the default 07f550f among them) the SVD-UKF rows differ by 2.3e-5 to 3.8e-5 of
the largest entry (3.6e-5 at N = 1): c51bd7b draws the sigma points along the symmetric square
root ``U sqrt(S) Uᵀ`` instead of the columns of ``U sqrt(S)``, the same mean and covariance but
other points, so a range-bearing sensor's moments differ beyond rounding. The EKF rows differ
from 07f550f's by rounding only (at most ~1e-13 of the largest entry).

Run from the repository root (the baseline compiles on the first run with an empty cache: a few
minutes)::

    python benchmarks/bench_kernel.py
    python benchmarks/bench_kernel.py --quick --json /tmp/kernel.json
"""

from __future__ import annotations

import os

import harness

os.environ.update(harness.ONE_THREAD)  # single core: before numpy (and numba) are imported

import argparse
import importlib
import re
import subprocess
import sys
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from rich.console import Console

from imm_gym import IMM, Sonar, draw_batch, paper_bank, paper_scenario, stay_tpm
from imm_gym.tracking.kernels import imm as kernel

N_TRACKERS = (1, 64, 1024, 4096)
FILTERS = ("ukf", "ekf")
WARM_STEPS = 20
MIN_REPEAT_S = 0.2
CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "imm_gym_bench"


def baseline_kernel(rev: str) -> ModuleType:
    """The kernel module of revision ``rev`` (imported from a cache directory; its numba cache
    lives there too), with the imm_gym modules it imports at module level snapshotted from the
    same revision (:func:`_snapshot`)."""
    found = _git("rev-parse", "--verify", "--short=12", f"{rev}^{{commit}}")
    if found.returncode != 0:
        raise SystemExit(f"--baseline {rev!r}: not a revision of this repository")
    sha = found.stdout.strip()
    where = CACHE / f"kernel_{sha}"
    where.mkdir(parents=True, exist_ok=True)
    name = _snapshot(sha, "imm_gym.tracking.kernels.imm", where, {})
    sys.path.insert(0, str(where))
    return importlib.import_module(name)


def _git(*args: str) -> subprocess.CompletedProcess[str]:
    """``git ARGS`` in the repository, its output captured as text (not checked)."""
    return subprocess.run(
        ["git", *args], cwd=harness.REPO_ROOT, check=False, capture_output=True, text=True
    )


# a module-level ``from imm_gym.x.y import ...`` (not one indented inside a function)
_MODULE_IMPORT = re.compile(r"^from (imm_gym(?:\.\w+)+) import", re.MULTILINE)


def _snapshot(sha: str, module: str, where: Path, done: dict[str, str]) -> str:
    """Write ``module`` of revision ``sha`` into ``where`` as ``base_<module>_<sha>.py``, its
    module-level imports of imm_gym modules rewritten to their snapshots (written the same way,
    recursively); returns the snapshot's module name. ``done``: modules already written."""
    name = done[module] = f"base_{module.replace('.', '_')}_{sha}"
    shown = _git("show", f"{sha}:{module.replace('.', '/')}.py")
    if shown.returncode != 0:
        raise SystemExit(f"baseline {sha}: cannot read {module} ({shown.stderr.strip()})")
    source = shown.stdout
    for dep in dict.fromkeys(_MODULE_IMPORT.findall(source)):
        snap = done.get(dep) or _snapshot(sha, dep, where, done)
        source = re.sub(
            rf"^from {re.escape(dep)} import", f"from {snap} import", source, flags=re.MULTILINE
        )
    target = where / f"{name}.py"
    if not target.exists() or target.read_text() != source:
        target.write_text(source)
    return name


def kernel_inputs(filt: str, n: int, seed: int) -> tuple[IMM, tuple, Any]:
    """An IMM, the ``imm_step`` arguments of step ``WARM_STEPS + 1`` of ``n`` paper-scenario
    trackers (outputs included), and the state they start from."""
    imm = IMM(paper_bank(), Sonar(), filter=filt)
    batch = draw_batch(paper_scenario(), Sonar(), n, seed)
    tpm = np.ascontiguousarray(np.broadcast_to(stay_tpm(3, 0.995), (n, 3, 3)))
    state = imm.init(batch.x0, batch.P0)
    for k in range(1, WARM_STEPS + 1):
        state, _ = imm.step(state, tpm, batch.measurements.z[:, k])
    M, dim = 3, imm.n
    outputs = (
        np.empty((n, M, dim)),
        np.empty((n, M, dim, dim)),
        *(np.empty((n, M)) for _ in range(4)),
        np.empty((n, M, 2)),
        np.empty(n),
        np.empty((n, dim)),
        np.empty((n, dim, dim)),
        np.empty(n, dtype=bool),
    )
    z = np.ascontiguousarray(batch.measurements.z[:, WARM_STEPS + 1])
    args = (
        state.x,
        state.P,
        state.mu,
        tpm,
        z,
        np.ones(n, dtype=bool),
        *imm.kernel_args,
        True,
        *outputs,
    )
    return imm, args, (state, tpm, z)


def square_root_rows(
    repeats: int, min_repeat_s: float, seed: int, console: Console
) -> tuple[list[dict[str, Any]], Any]:
    """This tree's kernel with Cholesky sigma points against its SVD-UKF, the same inputs (the
    SVD-UKF's state after the warm-up): a row per N and the rich table."""
    table = harness.table(
        "imm_step, M = 3, sonar, 1 core: UKF with Cholesky sigma points vs SVD-UKF (this tree)",
        harness.right("N"),
        harness.right("SVD µs"),
        harness.right("Cholesky µs"),
        harness.right("M steps/s"),
        harness.right("speed-up"),
        harness.right("CPU speed-up"),
        harness.right("max |Δ| / max |x|"),
        harness.right("max |Δ position| m"),
        caption=(
            f"median of {repeats} interleaved repeats; the outputs of one step from the same "
            "state (the two filters' sigma points differ by a rotation: equal for a linear "
            "sensor, apart at a higher order for the sonar)"
        ),
    )
    rows = []
    fkind = 11  # the filter code's place among imm_step's arguments
    for n in N_TRACKERS:
        console.print(f"[dim]timing ukf-cholesky N={n} ...[/dim]")
        _, svd_args, _ = kernel_inputs("ukf", n, seed)
        assert svd_args[fkind] == kernel.UKF
        chol_args = (
            *svd_args[:fkind], kernel.UKF_CHOLESKY, *svd_args[fkind + 1 : -11],
            *(a.copy() for a in svd_args[-11:]),
        )  # fmt: skip
        step = _cycle(kernel, n)
        step(*svd_args)
        step(*chol_args)
        diff = max_scaled_diff(list(chol_args[-11:]), svd_args[-11:])
        moved = float(np.abs(chol_args[-3][:, :2] - svd_args[-3][:, :2]).max())
        (t_svd, c_svd), (t_chol, c_chol) = median_times(
            {
                "svd": lambda a=svd_args, f=step: f(*a),
                "chol": lambda a=chol_args, f=step: f(*a),
            },
            repeats,
            min_repeat_s,
        ).values()
        rows.append(
            {"n": n, "svd_us": t_svd, "cholesky_us": t_chol, "svd_cpu_us": c_svd,
             "cholesky_cpu_us": c_chol, "max_abs_diff_over_max_abs": diff,
             "max_position_diff_m": moved}
        )  # fmt: skip
        table.add_row(
            str(n),
            f"{t_svd:,.1f}",
            f"{t_chol:,.1f}",
            f"{n / t_chol:.3f}",
            f"{t_svd / t_chol:.2f}×",
            f"{c_svd / c_chol:.2f}×",
            f"{diff:.1e}",
            f"{moved:.1e}",
        )
    return rows, table


def max_scaled_diff(ours: list[np.ndarray], base: tuple[np.ndarray, ...]) -> float:
    """``max |Δ| / max |x|``: for each output array the largest absolute difference of the two
    kernels' divided by the largest magnitude in ``base``'s array, the largest over the arrays
    (NaN where one is NaN and the other not counts as infinitely far; NaN in both as equal)."""
    out = 0.0
    for a, b in zip(ours, base, strict=True):
        a = a.astype(np.float64)
        b = b.astype(np.float64)
        if a.size == 0:
            continue
        both_nan = np.isnan(a) & np.isnan(b)
        if np.any(np.isnan(a) != np.isnan(b)):
            return float("inf")
        scale = 1e-300 + np.nanmax(np.abs(b), initial=0.0)
        d = np.where(both_nan, 0.0, np.abs(a - b)) / scale
        out = max(out, float(np.max(d)))
    return out


def time_calls(calls: dict[str, Any], repeats: int, min_repeat_s: float) -> dict[str, Any]:
    """Wall and process-CPU µs per call of each ``calls[name]()`` in each of ``repeats`` repeats
    (after two warm-up calls), the callables taking turns within every repeat so that a change in
    the machine's load hits them alike: ``{name: (wall list, cpu list)}``."""
    counts = {}
    for name, call in calls.items():
        call()
        call()
        t0 = time.perf_counter()
        call()
        counts[name] = max(1, int(min_repeat_s / max(time.perf_counter() - t0, 1e-7)))
    out: dict[str, Any] = {name: ([], []) for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            n = counts[name]
            wall, cpu = harness.timed(lambda c=call, n=n: _repeat(c, n))
            out[name][0].append(wall / n * 1e6)
            out[name][1].append(cpu / n * 1e6)
    return out


def _cycle(module: ModuleType, n: int) -> Any:
    """The entry a caller of ``module`` uses for ``n`` trackers of the benchmark's shape:
    ``imm_step_one`` at N = 1 where the revision has it, ``imm_step`` otherwise."""
    one = getattr(module, "imm_step_one", None)
    return one if n == 1 and one is not None else module.imm_step


def median_times(
    calls: dict[str, Any], repeats: int, min_repeat_s: float
) -> dict[str, tuple[float, float]]:
    """:func:`time_calls`' medians over the repeats: ``{name: (wall µs, CPU µs)}``, in the
    order of ``calls``."""
    times = time_calls(calls, repeats, min_repeat_s)
    return {
        name: (float(np.median(wall)), float(np.median(cpu)))
        for name, (wall, cpu) in times.items()
    }


def _repeat(call: Any, n: int) -> None:
    """``call()`` ``n`` times, each result dropped as a caller's loop would (kept in a list,
    ``IMM.step``'s thirteen fresh arrays a call, the garbage collector off, cost fresh memory:
    17 µs a step against 11 µs dropped, same day)."""
    for _ in range(n):
        call()


def run(args: argparse.Namespace, console: Console) -> int:
    repeats = harness.count(args.repeats, args.quick, 7, 3, "--repeats")
    min_repeat_s = 0.05 if args.quick else MIN_REPEAT_S
    env = harness.environment()
    console.print(f"[dim]loading the baseline kernel ({args.baseline}) ...[/dim]")
    base = baseline_kernel(args.baseline)
    table = harness.table(
        f"imm_step, M = 3, sonar, 1 core: baseline {args.baseline} vs this tree",
        "filter",
        harness.right("N"),
        harness.right("baseline µs"),
        harness.right("M steps/s"),
        harness.right("this tree µs"),
        harness.right("M steps/s"),
        harness.right("speed-up"),
        harness.right("CPU µs base"),
        harness.right("CPU µs"),
        harness.right("M steps/CPU s"),
        harness.right("CPU speed-up"),
        harness.right("max |Δ| / max |x|"),
        harness.right("bits equal"),
        caption=(
            f"median of {repeats} interleaved repeats; µs per batch step (one step of all N "
            "trackers): wall time, then process CPU time (leaves out waiting for a core); the "
            "baseline: the revision's kernel and the imm_gym modules it imports at module level "
            "(linalg, scratch), all from that revision"
        ),
    )
    rows = []
    for filt in FILTERS:
        for n in N_TRACKERS:
            console.print(f"[dim]timing {filt} N={n} ...[/dim]")
            _, call_args, _ = kernel_inputs(filt, n, args.seed)
            ours_out = [a.copy() for a in call_args[-11:]]
            base_args = (*call_args[:-11], *(a.copy() for a in call_args[-11:]))
            ours_step, base_step = _cycle(kernel, n), _cycle(base, n)
            ours_step(*call_args[:-11], *ours_out)
            base_step(*base_args)
            diff = max_scaled_diff(ours_out, base_args[-11:])
            same_bits = all(
                a.tobytes() == b.tobytes() for a, b in zip(ours_out, base_args[-11:], strict=True)
            )
            (t_base, c_base), (t_ours, c_ours) = median_times(
                {
                    "base": lambda a=base_args, f=base_step: f(*a),
                    "ours": lambda a=call_args, f=ours_step: f(*a),
                },
                repeats,
                min_repeat_s,
            ).values()
            rows.append(
                {
                    "filter": filt,
                    "n": n,
                    "baseline_us": t_base,
                    "us": t_ours,
                    "baseline_cpu_us": c_base,
                    "cpu_us": c_ours,
                    "max_abs_diff_over_max_abs": diff,
                    "bits_equal": same_bits,
                }
            )
            table.add_row(
                filt,
                str(n),
                f"{t_base:,.1f}",
                f"{n / t_base:.3f}",
                f"{t_ours:,.1f}",
                f"{n / t_ours:.3f}",
                f"{t_base / t_ours:.2f}×",
                f"{c_base:,.1f}",
                f"{c_ours:,.1f}",
                f"{n / c_ours:.3f}",
                f"{c_base / c_ours:.2f}×",
                f"{diff:.1e}",
                "yes" if same_bits else "NO",
            )
        table.add_section()
    console.print(table)
    square_root, square_root_table = square_root_rows(repeats, min_repeat_s, args.seed, console)
    console.print(square_root_table)
    imm, _, (state, tpm, z) = kernel_inputs("ukf", 1, args.seed)
    chol = IMM(paper_bank(), Sonar(), filter="ukf-cholesky")
    (step_us, step_cpu_us), (chol_us, _) = median_times(
        {
            "svd": lambda: imm.step(state, tpm, z),
            "chol": lambda: chol.step(state, tpm, z),
        },
        repeats,
        min_repeat_s,
    ).values()
    n1024 = next(r for r in rows if r["filter"] == "ukf" and r["n"] == 1024)
    console.print(
        f"IMM.step (SVD-UKF) at N = 1: {step_us:.1f} µs wall, {step_cpu_us:.1f} µs CPU (aim ≤ 10 "
        f"µs); kernel at N = 1024: {1024 / n1024['us']:.2f} M tracker-steps/s wall, "
        f"{1024 / n1024['cpu_us']:.2f} per CPU s (aim ≥ 1.0); IMM.step with Cholesky sigma "
        f"points at N = 1: {chol_us:.1f} µs wall"
    )
    console.print(
        f"[dim]{env['processor']}; {harness.thread_summary(env)}; load avg at start "
        f"{env['loadavg_at_start'][0] if env['loadavg_at_start'] else float('nan'):.2f}[/dim]"
    )
    if args.json is not None:
        harness.write_json(
            args.json,
            {
                "benchmark": "bench_kernel",
                "baseline": args.baseline,
                "repeats": repeats,
                "environment": env,
                "results": rows,
                "imm_step_n1_us": step_us,
                "imm_step_n1_cpu_us": step_cpu_us,
                "square_root": square_root,
                "imm_step_n1_cholesky_us": chol_us,
            },
            console,
        )
    return 0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    harness.add_repeats(p, "timed repeats per configuration, >= 1 (7; 3 quick)")
    harness.add_quick(p, "3 short repeats")
    harness.add_json(p)
    harness.add_seed(p, "draw_batch seed (default 0)")
    p.add_argument("--baseline", default="07f550f", help="git revision of the kernel to compare")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    return harness.main(run, parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
