"""The compiled kernels' entry points into numba's cache, in parallel
(``python -m imm_gym.precompile``).

The kernels compile on first use and are cached next to their source (``__pycache__``): the first
``IMM.step`` or env of one tracker and the first of N trackers each wait about two and a half
minutes on a laptop core, one after the other. This compiles both at once, one process per core,
so a fresh install (or a CI run) pays the compile once, in parallel::

    python -m imm_gym.precompile            # as many processes as cores
    python -m imm_gym.precompile --jobs 1   # one after the other

A cached kernel loads in well under a second, so running it again is cheap.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context

import numpy as np

from imm_gym.scenarios.segments import RandomFamily
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.sim.solo import SoloStep
from imm_gym.tracking.imm import IMM
from imm_gym.tracking.models import paper_bank
from imm_gym.tracking.sensors import Sonar
from imm_gym.tracking.tpm import stay_tpm


def _tracker_step(n_trackers: int) -> None:
    bank = paper_bank()
    imm = IMM(bank, Sonar())
    batch = draw_batch(RandomFamily(), Sonar(), n_trackers, 0)
    state = imm.init(batch.x0, batch.P0)
    detected = np.ones(n_trackers, dtype=bool)
    imm.step(state, stay_tpm(len(bank), 0.95), batch.measurements.z[:, 1], detected)


def _env_step(n_envs: int) -> None:
    core = TrackingCore(EnvConfig(), n_envs)
    core.reset(np.arange(n_envs), list(range(n_envs)))
    core.step(np.zeros((n_envs, core.action_dim)))


def _solo_step() -> None:
    core = TrackingCore(EnvConfig(), 1)
    core.reset(np.array([0]), [0])
    solo = SoloStep(core)
    solo.load(core)
    solo.step(np.zeros(core.action_dim))


def batch() -> None:
    """N trackers: ``IMM.step``'s :func:`~imm_gym.tracking.kernels.imm.imm_step`, then the
    vector env's :func:`~imm_gym.sim.kernels.env_step` around it."""
    _tracker_step(2)
    _env_step(2)


def single() -> None:
    """One tracker: ``IMM.step``'s :func:`~imm_gym.tracking.kernels.imm.checked_step_one`,
    then the core's :func:`~imm_gym.sim.kernels.env_step_one` and the scalar env's
    :func:`~imm_gym.sim.solo.solo_step` around it."""
    _tracker_step(1)
    _env_step(1)
    _solo_step()


#: The entry points, by name: each compiles (or loads) its kernels and what they call. The two
#: IMM cycles are the long compiles (about two and a half minutes each); each job builds one, then
#: the env step that calls it (seconds, the cycle then loads from the cache).
JOBS: dict[str, Callable[[], None]] = {"batch": batch, "single": single}


def _timed(name: str) -> tuple[str, float]:
    start = time.perf_counter()
    JOBS[name]()
    return name, time.perf_counter() - start


def precompile(names: Sequence[str], jobs: int, report: Callable[[str, float], None]) -> None:
    """Run the entry points ``names`` in ``jobs`` fresh processes (in this one for
    ``jobs == 1``), calling ``report(name, seconds)`` as each finishes."""
    if jobs == 1:
        for name in names:
            report(*_timed(name))
        return
    with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn")) as pool:
        for done in as_completed([pool.submit(_timed, name) for name in names]):
            report(*done.result())


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m imm_gym.precompile",
        description="Compile imm_gym's kernels into numba's cache, one process per entry point.",
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=os.cpu_count() or 1,
        help="processes at once (default: the number of cores)",
    )
    p.add_argument(
        "--only",
        choices=list(JOBS),
        action="append",
        help="compile this entry point only (repeatable, a repeat runs once; default: all)",
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs must be at least 1, got {args.jobs}")
    names = list(dict.fromkeys(args.only)) if args.only else list(JOBS)
    start = time.perf_counter()

    def report(name: str, seconds: float) -> None:
        print(f"{name}: {seconds:.1f} s", flush=True)

    precompile(names, min(args.jobs, len(names)), report)
    print(f"compiled {', '.join(names)} in {time.perf_counter() - start:.1f} s", flush=True)
    return 0
