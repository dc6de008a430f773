"""Single-core step throughput of imm_gym's environments, with FilterPy for reference.

What is measured (all on one CPU core: the BLAS/OpenMP/numba thread pools are limited to one
thread before numpy is imported), default ``imm_gym/TPMAdapt-v0`` config (randomized scenario
family, 150-step episodes, M = 3 SVD-UKF bank, shadow IMM with a fixed TPM, ``advantage`` reward)
unless stated:

1. Scalar env, ``gymnasium.make("imm_gym/TPMAdapt-v0")`` (its default wrappers: order enforcing
   and the passive env checker) and the same env's ``.unwrapped``, with zero actions and with
   uniform random actions in [-1, 1] (drawn before timing). A repeat runs whole episodes —
   ``reset()`` then ``step(a)`` until ``terminated or truncated`` — and the time per env step is
   the repeat's time (resets included) over the env steps it took. The cost of watching: the
   same env made with ``render_mode="rgb_array"`` (random actions), once stepping only (the
   picture's histories recorded at every step) and once calling ``render()`` after every
   ``reset`` and ``step`` (one frame each); without a render mode nothing is recorded or drawn.
2. Native vector env, ``gymnasium.make_vec(id, num_envs=N, vectorization_mode=
   "vector_entry_point")`` for N = 1, 64, 1024 in seven configurations: parallel bank B off / on
   (``parallel=True``) x shadow tracker on (default: ``shadow="fixed"``, ``reward="advantage"``) /
   off (``shadow="none", reward="error"``), and the stay bank (one classical IMM per stay of
   the evidence grid beside the banks, the ``stay`` action centred on its evidence; leaned by
   the turn-rate or the learned detector). The timed
   call is ``venv.step(actions)``; a repeat runs whole cycles of 151 batch steps (150 steps of
   an episode + the ``NEXT_STEP`` autoreset step, so each repeat holds its share of resets).
3. stable-baselines3 adapter ``imm_gym.envs.sb3.TPMAdaptSB3VecEnv(num_envs=N)`` for N = 64, 1024,
   timed call ``venv.step(actions)`` (same-step resets), whole cycles of 150 batch steps.
4. FilterPy ``IMMEstimator`` over three UKFs, one tracker, ``predict(); update(z)`` on the
   paper scenario — ``bench_imm.filterpy_episode`` (``bench_imm.py`` is imported from this
   directory), so set up and timed exactly as there. Its repeats take turns with those of the
   four scalar-env rows without a render mode (one repeat of each in every round, as
   ``bench_kernel.py``'s calls do), so that a change in the machine's speed hits both sides of
   the speed-up alike; the render rows are timed after, against the same FilterPy median.

The vector fronts step with random actions by default (``--vec-actions zero`` for zeros). Each
configuration is warmed up first (the numba kernels compile on their first call), then timed
with ``time.perf_counter`` over repeats (garbage collection off while timing, as ``timeit``
does); a repeat lasts at least ``MIN_REPEAT_S`` in whole episodes / cycles (one with
``--quick``), and configurations whose repeat is longer than ``LONG_REPEAT_S`` (N = 1024) run
``--long-repeats`` repeats instead of ``--repeats``. ``--quick`` keeps N = 1024 for the
headline configuration only. Reported figures are medians over the repeats: microseconds per
batch step (one ``step`` call over all N sub-envs) and env-steps per second (N x batch steps /
time; the vector env's autoreset steps count as steps). The process CPU time per step is shown
next to the wall time: on a shared machine the wall time also holds the time spent waiting for a
core, so compare the two (and the load averages printed at the end) before trusting a row.

Headline checks, the aims of issue #19: (1) vector env, N = 1024, parallel on, shadow default
(banks A + B + shadow), at least 250,000 env-steps/s; (2) the scalar env through
``gymnasium.make`` at least 40x faster than one FilterPy IMM-UKF step (the ratio of the medians
of interleaved repeats, wall time). The verdicts are on wall time; the CPU time is shown beside.

Run from the repository root::

    python benchmarks/bench_env.py                 # full run (~1.5 min; ~2 min under load)
    python benchmarks/bench_env.py --quick         # ~15 s: 3 repeats of one episode / cycle
    python benchmarks/bench_env.py --repeats 9 --json /tmp/bench_env.json
"""

from __future__ import annotations

import os

import harness

os.environ.update(harness.ONE_THREAD)  # single core: before numpy (and numba) are imported

import argparse
import math
import operator
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import bench_imm  # from this directory (the script's directory is on sys.path)
import gymnasium as gym
import numpy as np
import stable_baselines3
from rich.console import Console
from rich.table import Column

from imm_gym import IMM, Sonar, draw_batch, paper_bank, paper_scenario
from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv

ENV_ID = "imm_gym/TPMAdapt-v0"
TARGET_VEC_ENV_STEPS_PER_S = 250_000.0
TARGET_SPEEDUP_VS_FILTERPY = 40.0
N_VECTOR = (1, 64, 1024)
N_SB3 = (64, 1024)
# (label, keyword overrides of the default config)
VECTOR_CONFIGS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("parallel off, shadow on", {}),
    ("parallel off, shadow off", {"shadow": "none", "reward": "error"}),
    ("parallel on,  shadow on", {"parallel": True}),
    ("parallel on,  shadow off", {"parallel": True, "shadow": "none", "reward": "error"}),
    # the stay bank: seven more classical IMMs per slot (imm_gym/sim/stay_bank.py)
    (
        "stay bank, shadow on",
        {"action_mode": "stay", "stay_base": "evidence", "obs_features": ("stay_bank_evidence",)},
    ),
    # ...its priors and the base leaning toward the turn-rate detector (imm_gym/sim/detectors.py)
    (
        "stay bank, turn-rate lean",
        {"action_mode": "stay", "stay_base": "evidence", "detector": "turn_rate",
         "detector_share": 0.5, "obs_features": ("stay_bank_evidence",)},
    ),
    # ...toward the learned detector: one more IMM per slot and its network
    # (imm_gym/sim/learned_detector.py)
    (
        "stay bank, learned lean",
        {"action_mode": "stay", "stay_base": "evidence", "detector": "learned",
         "detector_share": 0.5, "obs_features": ("stay_bank_evidence",)},
    ),
)
HEADLINE_VECTOR = ("parallel on,  shadow on", 1024)
FP_KEY = ("FilterPy", "-")  # the FilterPy reference among the interleaved scalar cases
QUICK_MAX_N = 64  # --quick: larger N only for the headline configuration
MIN_REPEAT_S = 0.3  # a repeat runs whole episodes / cycles until at least this long (not --quick)
LONG_REPEAT_S = 1.0  # repeats longer than this use --long-repeats
WARMUP_STEPS = 10

Array = np.ndarray


@dataclass
class Result:
    """Timing of one configuration."""

    # "gymnasium.make", ".unwrapped", "make rgb_array", "make rgb_array + render()", "make_vec",
    # "SB3 VecEnv", "FilterPy"
    front: str
    config: str
    actions: str
    n_envs: int
    us_per_step: float  # median microseconds per batch step (one step call over N sub-envs)
    env_steps_per_s: float  # N / median time per batch step
    us_per_step_min: float
    us_per_step_max: float
    cpu_us_per_step: float  # median process-CPU microseconds per batch step
    repeats: int
    units_per_repeat: int  # whole episodes (scalar) or cycles (vector) per repeat
    batch_steps_timed: int
    episode_ends: int  # terminated or truncated sub-env episodes seen while timing
    per_repeat_us: list[float] = field(default_factory=list)
    per_repeat_cpu_us: list[float] = field(default_factory=list)

    @property
    def us_per_env_step(self) -> float:
        return self.us_per_step / self.n_envs

    @property
    def steps_per_episode(self) -> float:
        """Mean env steps per finished episode (nan when none finished)."""
        if not self.episode_ends:
            return math.nan
        return self.batch_steps_timed * self.n_envs / self.episode_ends


# ---------------------------------------------------------------------------------------------
# Timing
# ---------------------------------------------------------------------------------------------


def bench(
    front: str,
    config: str,
    actions: str,
    n: int,
    block: harness.Block,
    warmup: Callable[[], float],
    unit_steps: int,
    repeats: int,
    long_repeats: int,
    min_repeat_s: float,
) -> Result:
    """Warm up, size the repeats, then time repeats of whole episodes / cycles.

    ``warmup()`` runs (and compiles) a few steps and returns the estimated seconds per step;
    ``unit_steps`` is the number of steps of one episode / cycle.
    """
    m = harness.measure(
        warmup, block, unit_steps, repeats, min_repeat_s, long_repeats, LONG_REPEAT_S
    )
    return result(front, config, actions, n, m)


def result(front: str, config: str, actions: str, n: int, m: harness.Measurement) -> Result:
    """The :class:`Result` of a measurement of ``n`` sub-envs."""
    return Result(
        front=front,
        config=config,
        actions=actions,
        n_envs=n,
        us_per_step=m.us_per_step,
        env_steps_per_s=n / m.median_s,
        us_per_step_min=m.us_per_step_min,
        us_per_step_max=m.us_per_step_max,
        cpu_us_per_step=m.cpu_us_per_step,
        repeats=m.repeats,
        units_per_repeat=m.units,
        batch_steps_timed=m.steps,
        episode_ends=m.ends,
        per_repeat_us=m.per_repeat_us,
        per_repeat_cpu_us=m.per_repeat_cpu_us,
    )


def action_pool(space: gym.spaces.Box, kind: str, length: int, seed: int) -> list[Array]:
    """``length`` actions (one per step of an episode / cycle), zero or uniform on the box."""
    if kind == "zero":
        zero = np.zeros(space.shape, dtype=space.dtype)
        return [zero] * length
    rng = np.random.default_rng(seed)
    return list(rng.uniform(space.low, space.high, (length, *space.shape)).astype(space.dtype))


# ---------------------------------------------------------------------------------------------
# Scalar env
# ---------------------------------------------------------------------------------------------


def scalar_case(
    env: gym.Env, pool: list[Array], seed: int, render: bool = False
) -> tuple[Callable[[], float], harness.Block]:
    """Warm-up and timed block (whole episodes, resets included) of a scalar env; ``render``:
    ``env.render()`` after every ``reset`` and ``step``."""
    P = len(pool)
    reset, step = env.reset, env.step
    if render:

        def reset(**kwargs: Any) -> Any:
            out = env.reset(**kwargs)
            env.render()
            return out

        def step(action: Array) -> Any:
            out = env.step(action)
            env.render()
            return out

    def warmup() -> float:
        reset(seed=seed)
        for i in range(WARMUP_STEPS):
            step(pool[i])
        reset()

        def loop() -> None:
            for i in range(WARMUP_STEPS):
                step(pool[i])

        return harness.timed(loop)[0] / WARMUP_STEPS

    def block(episodes: int) -> harness.Sample:
        count = [0]

        def loop() -> None:
            steps = 0
            for _ in range(episodes):
                reset()
                i = 0
                while True:
                    _, _, terminated, truncated, _ = step(pool[i % P])
                    i += 1
                    if terminated or truncated:
                        break
                steps += i
            count[0] = steps

        seconds, cpu = harness.timed(loop)
        return harness.Sample(seconds, cpu, count[0], episodes)

    return warmup, block


# ---------------------------------------------------------------------------------------------
# Vector envs (Gymnasium native and SB3)
# ---------------------------------------------------------------------------------------------


def vector_case(
    step: Callable[[Array], tuple[Any, ...]],
    reset: Callable[[], Any],
    pool: list[Array],
    cycle: int,
    done_flags: Callable[[tuple[Any, ...]], Any],
) -> tuple[Callable[[], float], harness.Block]:
    """Warm-up and timed block (``cycle`` batch steps per unit) of a vector env.

    The env keeps running across repeats (autoresets inside the timed steps). ``done_flags(out)``
    picks the per-sub-env episode-end flag array(s) of a step's output (an ``itemgetter``); they
    are kept and counted after the clock stops.
    """
    P = len(pool)
    k = [0]  # next index into the action pool

    def warmup() -> float:
        reset()
        for i in range(WARMUP_STEPS):
            step(pool[i % P])

        def loop() -> None:
            for i in range(WARMUP_STEPS, 2 * WARMUP_STEPS):
                step(pool[i % P])

        seconds, _ = harness.timed(loop)
        k[0] = 2 * WARMUP_STEPS
        return seconds / WARMUP_STEPS

    def block(cycles: int) -> harness.Sample:
        steps = cycles * cycle
        start = k[0]
        flags: list[Any] = []
        append = flags.append

        def loop() -> None:
            for i in range(start, start + steps):
                append(done_flags(step(pool[i % P])))

        seconds, cpu = harness.timed(loop)
        k[0] = start + steps
        ends = sum(int(np.count_nonzero(np.logical_or.reduce(np.atleast_2d(f)))) for f in flags)
        return harness.Sample(seconds, cpu, steps, ends)

    return warmup, block


def make_vec(n: int, overrides: dict[str, Any]) -> Any:
    return gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", **overrides)


# ---------------------------------------------------------------------------------------------
# FilterPy (via bench_imm.py)
# ---------------------------------------------------------------------------------------------


def filterpy_case(seed: int) -> tuple[Callable[[], float], harness.Block, int]:
    """One FilterPy IMM-UKF tracker over the paper scenario, set up as ``bench_imm.py`` does.

    Whole 150-step episodes of ``predict(); update(z)`` by ``bench_imm.filterpy_episode`` (which
    times its loop, wall and process CPU time, building the three UKFs outside it).
    """
    sonar = Sonar()
    imm = IMM(paper_bank(), sonar)
    scenario = paper_scenario()
    horizon = scenario.horizon
    b = draw_batch(scenario, sonar, 1, seed)
    episode = bench_imm.filterpy_episode(
        imm.F, imm.Q, sonar.R, b.measurements.z[0], b.x0[0], b.P0[0]
    )
    warmup = harness.episode_warmup(episode, WARMUP_STEPS)
    return warmup, harness.episode_block(episode, horizon), horizon


# ---------------------------------------------------------------------------------------------
# Reporting
# ---------------------------------------------------------------------------------------------


def environment() -> dict[str, Any]:
    return {
        **bench_imm.environment(),
        "gymnasium": gym.__version__,
        "stable_baselines3": stable_baselines3.__version__,
    }


def _range(r: Result) -> str:
    return harness.range_cell(r.us_per_step_min, r.us_per_step_max)


def render(
    console: Console,
    scalar: list[Result],
    vector: list[Result],
    fp: Result,
    env: dict[str, Any],
    loadavg_end: float,
) -> dict[str, Any]:
    t1 = harness.table(
        f"Scalar env steps — {ENV_ID}, default config, 1 core",
        Column("front", no_wrap=True),
        "actions",
        harness.right("µs / env step"),
        harness.range_column(),
        harness.right("CPU µs / step"),
        harness.right("env-steps/s"),
        harness.right("repeats × episodes"),
        harness.right("steps / episode"),
        harness.right("speed-up vs FilterPy"),
        caption=(
            "medians over repeats of whole episodes, resets included; CPU = process CPU time; "
            "speed-up = FilterPy µs per IMM-UKF step / this row's µs per env step (wall); "
            "FilterPy's repeats taken in turn with the four rows without a render mode"
        ),
    )
    for r in [*scalar, fp]:
        if r is fp:
            t1.add_section()
        t1.add_row(
            r.front if r is not fp else f"{r.front} {r.config}",
            r.actions,
            f"{r.us_per_step:,.1f}",
            _range(r),
            f"{r.cpu_us_per_step:,.1f}",
            f"{r.env_steps_per_s:,.0f}",
            f"{r.repeats} × {r.units_per_repeat}",
            f"{r.steps_per_episode:.1f}",
            f"{fp.us_per_step / r.us_per_step:,.1f}×",
        )
    console.print(t1)

    kinds = sorted({r.actions for r in vector})
    t2 = harness.table(
        f"Vector env steps — {ENV_ID}, {'/'.join(kinds)} actions, 1 core",
        Column("front", no_wrap=True),
        Column("config", no_wrap=True),
        harness.right("N"),
        harness.right("µs / batch step"),
        harness.range_column(),
        harness.right("CPU µs / batch step"),
        harness.right("µs / env step"),
        harness.right("env-steps/s"),
        harness.right("repeats × cycles"),
        harness.right(f"vs {TARGET_VEC_ENV_STEPS_PER_S / 1000:.0f}k aim"),
        caption=(
            "medians over repeats of whole cycles (make_vec: 150 steps + 1 autoreset step; "
            "SB3: 150 steps, same-step resets); env-steps/s = N × batch steps / time; "
            "CPU = process CPU time"
        ),
    )
    previous = None
    for r in vector:
        key = (r.front, r.config)
        if previous is not None and key != previous:
            t2.add_section()
        previous = key
        t2.add_row(
            r.front,
            r.config,
            str(r.n_envs),
            f"{r.us_per_step:,.1f}",
            _range(r),
            f"{r.cpu_us_per_step:,.1f}",
            f"{r.us_per_env_step:,.2f}",
            f"{r.env_steps_per_s:,.0f}",
            f"{r.repeats} × {r.units_per_repeat}",
            f"{r.env_steps_per_s / TARGET_VEC_ENV_STEPS_PER_S:.2f}",
        )
    console.print(t2)

    config, n = HEADLINE_VECTOR
    hv = next(r for r in vector if r.front == "make_vec" and r.config == config and r.n_envs == n)
    ratio = hv.env_steps_per_s / TARGET_VEC_ENV_STEPS_PER_S
    cpu_rate = n / (hv.cpu_us_per_step * 1e-6)
    headline = harness.table(
        "Headline checks",
        "check",
        harness.right("wall time"),
        harness.right("CPU time"),
        harness.right("aim"),
        Column("met?", justify="center"),
        caption=(
            "verdicts on wall time; CPU time leaves out waiting for a core (not cache or "
            "hyper-thread sharing); (2): medians of the scalar env's and FilterPy's repeats, "
            "taken in turn (interleaved) in one round-robin"
        ),
    )
    headline.add_row(
        f"(1) make_vec N={n}, {config.replace('  ', ' ')}: env-steps/s",
        f"{hv.env_steps_per_s:,.0f}  ({ratio:.2f} of aim)",
        f"{cpu_rate:,.0f}  ({cpu_rate / TARGET_VEC_ENV_STEPS_PER_S:.2f})",
        f"≥ {TARGET_VEC_ENV_STEPS_PER_S:,.0f}",
        harness.verdict(ratio >= 1.0),
    )
    speedups: dict[str, dict[str, float]] = {}
    for r in scalar:
        if r.front != "gymnasium.make":
            continue
        s = fp.us_per_step / r.us_per_step
        s_cpu = fp.cpu_us_per_step / r.cpu_us_per_step
        speedups[r.actions] = {"wall": s, "cpu": s_cpu}
        headline.add_row(
            f"(2) gymnasium.make scalar env, {r.actions} actions, vs one FilterPy step",
            f"{s:,.1f}×  ({r.us_per_step:,.1f} vs {fp.us_per_step:,.1f} µs)",
            f"{s_cpu:,.1f}×  ({r.cpu_us_per_step:,.1f} vs {fp.cpu_us_per_step:,.1f} µs)",
            f"≥ {TARGET_SPEEDUP_VS_FILTERPY:.0f}×",
            harness.verdict(s >= TARGET_SPEEDUP_VS_FILTERPY),
        )
    console.print(headline)

    load0 = env["loadavg_at_start"][0] if env["loadavg_at_start"] else math.nan
    console.print(
        f"[dim]{env['processor']}; {env['cpus_available']} CPUs available; "
        f"{harness.thread_summary(env)}; numpy {env['numpy']}, gymnasium {env['gymnasium']}, "
        f"stable-baselines3 {env['stable_baselines3']}, filterpy {env['filterpy']}, "
        f"Python {env['python']}; load avg (1 min) at start {load0:.2f}, at end "
        f"{loadavg_end:.2f}[/dim]"
    )
    return {
        "vector_n1024_parallel_env_steps_per_s": hv.env_steps_per_s,
        "vector_n1024_parallel_vs_aim": ratio,
        "vector_n1024_parallel_env_steps_per_cpu_s": cpu_rate,
        "scalar_make_speedup_vs_filterpy": speedups,
    }


# ---------------------------------------------------------------------------------------------
# Main
# ---------------------------------------------------------------------------------------------


def run(args: argparse.Namespace, console: Console) -> int:
    repeats = harness.count(args.repeats, args.quick, 5, 3, "--repeats")
    long_repeats = harness.count(args.long_repeats, args.quick, 3, 1, "--long-repeats")
    min_repeat_s = 0.0 if args.quick else MIN_REPEAT_S
    env_info = environment()
    t_start = time.perf_counter()

    common = {"repeats": repeats, "long_repeats": long_repeats, "min_repeat_s": min_repeat_s}

    # 1. scalar env without a render mode and the FilterPy reference, their repeats in turn
    made = gym.make(ENV_ID)
    horizon = made.unwrapped.core.horizon
    cases: dict[tuple[str, str], tuple[Callable[[], float], harness.Block, int]] = {}
    for front, env in (("gymnasium.make", made), (".unwrapped", made.unwrapped)):
        for kind in ("zero", "random"):
            pool = action_pool(env.action_space, kind, horizon, args.seed)
            cases[front, kind] = (*scalar_case(env, pool, args.seed), horizon)
    fp_warmup, fp_block, fp_horizon = filterpy_case(args.seed)
    cases[FP_KEY] = (fp_warmup, fp_block, fp_horizon)
    console.print(
        "[dim]timing scalar env gymnasium.make / .unwrapped, zero / random actions, and "
        "FilterPy IMMEstimator (UKF) N=1 (bench_imm.py), repeats in turn ...[/dim]"
    )
    measured = harness.measure_interleaved(
        cases, repeats, min_repeat_s, long_repeats, LONG_REPEAT_S
    )
    made.close()
    scalar = [
        result(front, "default", kind, 1, measured[front, kind])
        for front, kind in cases
        if (front, kind) != FP_KEY
    ]
    fp = result("FilterPy", "IMMEstimator, 3 UKFs (bench_imm.py)", "-", 1, measured[FP_KEY])

    # 2. the cost of watching
    for front, draws in (("make rgb_array", False), ("make rgb_array + render()", True)):
        console.print(f"[dim]timing scalar env {front} random actions ...[/dim]")
        env = gym.make(ENV_ID, render_mode="rgb_array")
        pool = action_pool(env.action_space, "random", horizon, args.seed)
        warmup, block = scalar_case(env, pool, args.seed, draws)
        scalar.append(bench(front, "default", "random", 1, block, warmup, horizon, **common))
        env.close()

    # 3. native vector env and SB3 adapter
    vector: list[Result] = []
    kind = args.vec_actions
    for config, overrides in VECTOR_CONFIGS:
        for n in N_VECTOR:
            if args.quick and n > QUICK_MAX_N and (config, n) != HEADLINE_VECTOR:
                continue
            console.print(f"[dim]timing make_vec {config} N={n} ...[/dim]")
            venv = make_vec(n, overrides)
            core = venv.unwrapped.core
            cycle = core.horizon + 1  # NEXT_STEP autoreset: one extra step per episode
            pool = action_pool(venv.action_space, kind, cycle, args.seed)
            warmup, block = vector_case(
                venv.step,
                lambda v=venv: v.reset(seed=args.seed),
                pool,
                cycle,
                operator.itemgetter(2, 3),  # terminated, truncated
            )
            vector.append(bench("make_vec", config, kind, n, block, warmup, cycle, **common))
            venv.close()
    for n in N_SB3:
        if args.quick and n > QUICK_MAX_N:
            continue
        console.print(f"[dim]timing SB3 TPMAdaptSB3VecEnv N={n} ...[/dim]")
        venv = TPMAdaptSB3VecEnv(num_envs=n)
        venv.seed(args.seed)
        cycle = venv.core.horizon  # same-step reset
        batched = gym.spaces.Box(-1.0, 1.0, (n, venv.core.action_dim), dtype=np.float32)
        pool = action_pool(batched, kind, cycle, args.seed)
        warmup, block = vector_case(venv.step, venv.reset, pool, cycle, operator.itemgetter(2))
        vector.append(
            bench(
                "SB3 VecEnv", "default (TPMAdaptSB3VecEnv)", kind, n, block, warmup, cycle, **common
            )
        )
        venv.close()

    elapsed = time.perf_counter() - t_start
    loadavg_end = harness.loadavg()
    headline = render(console, scalar, vector, fp, env_info, loadavg_end)
    console.print(f"[dim]timing took {elapsed:.0f} s[/dim]")

    if args.json is not None:
        payload = {
            "benchmark": "bench_env",
            "settings": {
                "env_id": ENV_ID,
                "repeats": repeats,
                "long_repeats": long_repeats,
                "quick": args.quick,
                "seed": args.seed,
                "vec_actions": kind,
                "horizon": horizon,
                "min_repeat_s": min_repeat_s,
                "long_repeat_s": LONG_REPEAT_S,
                "target_vec_env_steps_per_s": TARGET_VEC_ENV_STEPS_PER_S,
                "target_speedup_vs_filterpy": TARGET_SPEEDUP_VS_FILTERPY,
            },
            "environment": {**env_info, "loadavg_at_end": loadavg_end},
            "results": [
                {
                    **asdict(r),
                    "us_per_env_step": r.us_per_env_step,
                    "steps_per_episode": r.steps_per_episode,
                }
                for r in [*scalar, fp, *vector]
            ],
            "headline": headline,
            "elapsed_s": elapsed,
        }
        harness.write_json(args.json, payload, console)
    return 0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    harness.add_repeats(p, "timed repeats per configuration, >= 1 (5; 3 quick)")
    p.add_argument(
        "--long-repeats",
        type=harness.positive_int,
        default=None,
        help=(
            f"repeats of configurations whose repeat lasts > {LONG_REPEAT_S:g} s, >= 1 "
            "(3; 1 quick)"
        ),
    )
    harness.add_quick(
        p,
        "repeats of one episode / cycle each: 3 (--long-repeats' 1 only where one would last "
        f"> {LONG_REPEAT_S:g} s), N = 1024 for the headline configuration only",
    )
    p.add_argument(
        "--vec-actions",
        choices=("random", "zero"),
        default="random",
        help="actions of the vector fronts (default random)",
    )
    harness.add_json(p)
    harness.add_seed(p, "reset / action seed (default 0)")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    return harness.main(run, parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
