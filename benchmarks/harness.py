"""What the benchmark scripts share: one-thread pools, timing, tables, JSON output, flags.

A script pins the thread pools before numpy (or numba, gymnasium, ...) is first imported; this
module imports neither at import time, so it can be imported first::

    import os

    import harness

    os.environ.update(harness.ONE_THREAD)  # before numpy is imported

    import numpy as np

and runs its ``run(args, console)`` through :func:`main`, which also limits the already loaded
pools with threadpoolctl when that is installed.

Timing. A configuration is a ``warmup()`` that runs (and compiles) a few steps and returns the
seconds one step takes, and a ``block(units)`` that runs ``units`` whole episodes / cycles and
returns a :class:`Sample`. :func:`measure` warms up, sizes a repeat to the fewest whole units
lasting at least ``min_repeat_s`` (one unit when it is 0), times the repeats and keeps each
repeat's time per step, ``t_r = wall_r / steps_r`` (and the same for process-CPU time); the
reported figures are medians over the repeats. Configurations whose figures are divided by each
other are timed by :func:`measure_interleaved`, their repeats taking turns. Loops are timed by
:func:`timed`: wall time by ``time.perf_counter``, process-CPU time by ``time.process_time`` read
outside the wall-clock window, garbage collection off (as ``timeit`` does). The CPU time is
reported because the machine is shared: under load the wall time also holds the time the
process waited for a core.
"""

from __future__ import annotations

import argparse
import gc
import hashlib
import json
import math
import os
import platform
import statistics
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from rich.console import Console
from rich.table import Column, Table

try:  # Belt and braces: also pin already-loaded thread pools if threadpoolctl is available.
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover - depends on the environment
    threadpool_limits = None

#: Environment variables that limit the BLAS / OpenMP / numba thread pools to one thread; they
#: take effect only if set before numpy (and numba) are imported.
ONE_THREAD: dict[str, str] = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
}
#: The thread variables recorded in :func:`environment` (``thread_env``).
REPORTED_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
REPO_ROOT = Path(__file__).resolve().parents[1]
PIPE_WIDTH = 200  # console width when not printing to a terminal


# ---------------------------------------------------------------------------------------------
# Timing
# ---------------------------------------------------------------------------------------------


def timed(loop: Callable[[], None], gc_off: bool = True) -> tuple[float, float]:
    """Wall and process-CPU seconds taken by ``loop()``, with the garbage collector off (unless
    ``gc_off`` is false: a timing of whole program runs, collections included)."""
    gc_was_enabled = gc.isenabled()
    if gc_off:
        gc.disable()
    try:
        c0 = time.process_time()
        t0 = time.perf_counter()
        loop()
        t1 = time.perf_counter()
        return t1 - t0, time.process_time() - c0
    finally:
        if gc_was_enabled:
            gc.enable()


@dataclass(frozen=True)
class Sample:
    """One timed repeat: ``steps`` steps in ``wall_s`` (``cpu_s`` process CPU) seconds and
    ``ends`` episode ends."""

    wall_s: float
    cpu_s: float
    steps: int
    ends: int


# episode(steps) -> (wall, process-CPU) seconds spent in the timed loop of `steps` steps, as
# `timed` gives them (its set-up not timed)
Episode = Callable[[int], tuple[float, float]]
# block(units) -> the Sample of `units` whole episodes / cycles
Block = Callable[[int], Sample]
K = TypeVar("K")  # the key of a configuration in measure_interleaved


def episode_warmup(episode: Episode, steps: int) -> Callable[[], float]:
    """Warm-up of an :data:`Episode`: ``steps`` steps to compile / warm caches, then ``steps``
    more timed; returns the seconds per step of the second run."""

    def warmup() -> float:
        episode(steps)
        return episode(steps)[0] / steps

    return warmup


def episode_block(episode: Episode, horizon: int) -> Block:
    """Block of whole ``horizon``-step episodes: wall and process-CPU time = the sums over the
    episodes' timed loops (their set-up left out of both)."""

    def block(episodes: int) -> Sample:
        times = [episode(horizon) for _ in range(episodes)]
        wall = sum(t[0] for t in times)
        cpu = sum(t[1] for t in times)
        return Sample(wall, cpu, episodes * horizon, episodes)

    return block


@dataclass(frozen=True)
class Measurement:
    """Repeats of one configuration: seconds per step of each repeat, wall and process CPU."""

    units: int  # whole episodes / cycles per repeat
    per_step_s: list[float]
    cpu_per_step_s: list[float]
    steps: int  # steps timed over all repeats
    ends: int  # episode ends seen over all repeats

    @property
    def repeats(self) -> int:
        return len(self.per_step_s)

    @property
    def median_s(self) -> float:
        """Median over repeats of the wall seconds per step."""
        return statistics.median(self.per_step_s)

    @property
    def us_per_step(self) -> float:
        return self.median_s * 1e6

    @property
    def us_per_step_min(self) -> float:
        return min(self.per_step_s) * 1e6

    @property
    def us_per_step_max(self) -> float:
        return max(self.per_step_s) * 1e6

    @property
    def cpu_us_per_step(self) -> float:
        """Median over repeats of the process-CPU microseconds per step."""
        return statistics.median(self.cpu_per_step_s) * 1e6

    @property
    def per_repeat_us(self) -> list[float]:
        return [t * 1e6 for t in self.per_step_s]

    @property
    def per_repeat_cpu_us(self) -> list[float]:
        return [t * 1e6 for t in self.cpu_per_step_s]


def measure(
    warmup: Callable[[], float],
    block: Block,
    unit_steps: int,
    repeats: int,
    min_repeat_s: float,
    long_repeats: int | None = None,
    long_repeat_s: float = math.inf,
) -> Measurement:
    """Warm up, size the repeats, then time repeats of whole episodes / cycles.

    ``unit_steps`` is the number of steps of one episode / cycle; a unit is estimated to last
    ``warmup() * unit_steps`` s, a repeat holds ``units = max(1, ceil(min_repeat_s / unit))``
    units (1 when ``min_repeat_s`` is 0), and ``long_repeats`` repeats are run instead of
    ``repeats`` when a repeat is estimated to last longer than ``long_repeat_s``.
    """
    per_unit = warmup() * unit_steps
    units = max(1, math.ceil(min_repeat_s / per_unit)) if min_repeat_s > 0 else 1
    if long_repeats is not None and units * per_unit > long_repeat_s:
        repeats = long_repeats
    samples = [block(units) for _ in range(repeats)]
    return Measurement(
        units=units,
        per_step_s=[s.wall_s / s.steps for s in samples],
        cpu_per_step_s=[s.cpu_s / s.steps for s in samples],
        steps=sum(s.steps for s in samples),
        ends=sum(s.ends for s in samples),
    )


def measure_interleaved(
    cases: dict[K, tuple[Callable[[], float], Block, int]],
    repeats: int,
    min_repeat_s: float,
    long_repeats: int | None = None,
    long_repeat_s: float = math.inf,
) -> dict[K, Measurement]:
    """:func:`measure` of several configurations whose repeats take turns.

    ``cases[name] = (warmup, block, unit_steps)``; each is warmed up and its repeat sized as
    :func:`measure` does, then every round times one repeat of each case in turn, so that a
    change in the machine's speed hits them alike and the ratio of two cases' medians compares
    like with like. Each timed repeat is preceded by its case's ``warmup()`` again, untimed, so
    that no case pays for the caches the case before it evicted (a scalar env's 2 ms episode
    right after a FilterPy episode took ~20 % longer). ``long_repeats`` repeats are run when any
    case's repeat is estimated to last longer than ``long_repeat_s``.
    """
    units: dict[K, int] = {}
    longest = 0.0
    for name, (warmup, _, unit_steps) in cases.items():
        per_unit = warmup() * unit_steps
        units[name] = max(1, math.ceil(min_repeat_s / per_unit)) if min_repeat_s > 0 else 1
        longest = max(longest, units[name] * per_unit)
    if long_repeats is not None and longest > long_repeat_s:
        repeats = long_repeats
    samples: dict[K, list[Sample]] = {name: [] for name in cases}
    for _ in range(repeats):
        for name, (warmup, block, _) in cases.items():
            warmup()
            samples[name].append(block(units[name]))
    return {
        name: Measurement(
            units=units[name],
            per_step_s=[s.wall_s / s.steps for s in done],
            cpu_per_step_s=[s.cpu_s / s.steps for s in done],
            steps=sum(s.steps for s in done),
            ends=sum(s.ends for s in done),
        )
        for name, done in samples.items()
    }


# ---------------------------------------------------------------------------------------------
# Machine and code
# ---------------------------------------------------------------------------------------------


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(
            ["git", *args],
            cwd=REPO_ROOT,
            capture_output=True,
            text=True,
            check=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip()


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def source_digest() -> str:
    """SHA-1 over the relative paths and contents of imm_gym's ``*.py`` files, subpackages
    included: identifies the code timed even in a dirty tree."""
    import imm_gym

    root = Path(imm_gym.__file__).resolve().parent
    h = hashlib.sha1()
    for f in sorted(root.rglob("*.py")):
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def loadavg() -> float:
    """1-minute load average (nan where the OS does not give one)."""
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan


def environment(**versions: str) -> dict[str, Any]:
    """Machine, thread settings, versions (numpy and ``versions``) and the code's git state."""
    import numpy as np

    status = _git("status", "--porcelain", "--", "imm_gym")
    return {
        "python": platform.python_version(),
        "numpy": np.__version__,
        **versions,
        "platform": platform.platform(),
        "processor": _cpu_model(),
        "cpus_available": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 0,
        "loadavg_at_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "thread_env": {k: os.environ.get(k) for k in REPORTED_THREAD_ENV},
        "threadpoolctl": threadpool_limits is not None,
        "git_commit": _git("rev-parse", "HEAD"),
        "imm_gym_dirty": None if status is None else bool(status),
        "imm_gym_source_sha1": source_digest(),
    }


def thread_summary(env: dict[str, Any]) -> str:
    """``OMP_NUM_THREADS=1, ...; threadpoolctl used`` from an :func:`environment` dict."""
    threads = ", ".join(f"{k}={v}" for k, v in env["thread_env"].items())
    return f"{threads}; threadpoolctl {'used' if env['threadpoolctl'] else 'not installed'}"


# ---------------------------------------------------------------------------------------------
# Output
# ---------------------------------------------------------------------------------------------


def make_console(width: int | None = None) -> Console:
    """A rich console ``width`` columns wide; by default the terminal's, or :data:`PIPE_WIDTH`
    in a pipe (so that rich does not wrap the tables at 80 columns)."""
    if width is not None:
        return Console(width=width)
    console = Console()
    return console if console.is_terminal else Console(width=PIPE_WIDTH)


def table(title: str, *columns: str | Column, caption: str | None = None) -> Table:
    """A rich table with these column headers / :class:`rich.table.Column` s."""
    return Table(*columns, title=title, caption=caption)


def right(header: str) -> Column:
    """A right-justified column (numbers)."""
    return Column(header, justify="right")


def range_column() -> Column:
    """The dim ``(min – max)`` column next to a median."""
    return Column("(min – max)", justify="right", style="dim", no_wrap=True)


def range_cell(lo: float, hi: float) -> str:
    """The ``(min – max)`` cell: smallest and largest value over the repeats."""
    return f"({lo:,.1f} – {hi:,.1f})"


def verdict(ok: bool) -> str:
    return "[green]yes[/green]" if ok else "[bold red]no[/bold red]"


def write_json(path: str, payload: dict[str, Any], console: Console | None = None) -> None:
    """Write ``payload`` as indented JSON, values JSON has no type for as their ``str`` (and say
    so on ``console``)."""
    Path(path).write_text(json.dumps(payload, indent=2, default=str) + "\n")
    if console is not None:
        console.print(f"[dim]wrote {path}[/dim]")


# ---------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------


def at_least(low: int) -> Callable[[str], int]:
    """An argparse ``type``: an integer ``>= low``; anything else is a usage error (exit 2)
    naming the flag and the allowed range."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"must be an integer >= {low}, got {text!r}"
            ) from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {value}")
        return value

    parse.__name__ = f"integer >= {low}"
    return parse


#: argparse ``type`` of a count (``--repeats``, ``--runs``, ...): an integer >= 1
positive_int = at_least(1)
#: argparse ``type`` of a seed: an integer >= 0
seed_int = at_least(0)


def add_repeats(parser: argparse.ArgumentParser, help: str) -> None:
    parser.add_argument("--repeats", type=positive_int, default=None, help=help)


def add_quick(parser: argparse.ArgumentParser, help: str) -> None:
    parser.add_argument("--quick", action="store_true", help=help)


def json_file(text: str) -> str:
    """An argparse ``type``: a file the results can be written to at the end of the run, its
    directory existing and writable and the path not a directory; anything else is a usage error
    (exit 2) when the arguments are parsed, not a traceback after the timings."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"must be a file to write, got the directory {text!r}")
    folder = path.parent
    if not folder.is_dir():
        raise argparse.ArgumentTypeError(
            f"the directory {str(folder)!r} of {text!r} does not exist"
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(
            f"the directory {str(folder)!r} of {text!r} is not writable"
        )
    return text


def add_json(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--json",
        metavar="FILE",
        type=json_file,
        default=None,
        help="also write the results as JSON (FILE's directory must exist and be writable)",
    )


def add_seed(parser: argparse.ArgumentParser, help: str) -> None:
    parser.add_argument("--seed", type=seed_int, default=0, help=help)


def count(value: int | None, quick: bool, full: int, quick_default: int, flag: str) -> int:
    """A repeat count: ``value`` if given, else ``quick_default`` / ``full`` (``--quick`` or
    not); exits unless it is at least 1 (a flag parsed with :data:`positive_int` already is)."""
    n = value if value is not None else (quick_default if quick else full)
    if n < 1:
        raise SystemExit(f"{flag} must be >= 1")
    return n


@contextmanager
def single_core() -> Iterator[None]:
    """Limit the loaded thread pools to one thread with threadpoolctl, if it is installed."""
    if threadpool_limits is None:
        yield
        return
    with threadpool_limits(limits=1):
        yield


def main(run: Callable[[argparse.Namespace, Console], int], args: argparse.Namespace) -> int:
    """``run(args, console)`` on one core (see :func:`single_core`); its exit status."""
    console = make_console()
    with single_core():
        return run(args, console)
