"""Single-core throughput of the environments, with one FilterPy IMM-UKF step for scale.

What is measured (one CPU core; thread pools limited before numpy is imported):

1. the scalar env through ``gymnasium.make("imm_gym/TPMAdapt-v0")`` (Gymnasium's default wrappers)
   and its ``.unwrapped`` env, default configuration (bank A + shadow tracker), random actions,
   whole 150-step episodes including the resets;
2. the native vector env ``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")`` at
   N = 1, 64 and 1024, with the parallel bank off/on and the shadow tracker on/off
   (``shadow="none", reward="error"``);
3. the stable-baselines3 adapter ``TPMAdaptVecEnv`` at N = 64 and 1024;
4. one FilterPy ``IMMEstimator`` step with three UKFs (the setup of ``bench_imm.py``).

Figures are medians over ``--repeats`` repeats of env steps per second (N x batch steps / s) and
microseconds per batch step. Run from the repository root::

    python benchmarks/bench_env.py            # ~1-2 min
    python benchmarks/bench_env.py --quick    # ~20 s
"""

from __future__ import annotations

import os

os.environ["OMP_NUM_THREADS"] = "1"
os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ["MKL_NUM_THREADS"] = "1"
os.environ["NUMBA_NUM_THREADS"] = "1"

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_imm

import imm_gym  # noqa: F401  (registers the ids)
from imm_gym import Sonar, paper_bank, paper_scenario
from imm_gym.envs.sb3 import TPMAdaptVecEnv
from imm_gym.imm import IMM
from imm_gym.montecarlo import draw_batch

ENV_ID = "imm_gym/TPMAdapt-v0"
HORIZON = 150
VECTOR_CONFIGS = {
    "bank A + shadow (default)": {},
    "bank A only": {"shadow": "none", "reward": "error"},
    "banks A+B + shadow": {"parallel": True},
    "banks A+B": {"parallel": True, "shadow": "none", "reward": "error"},
}


def time_scalar(env: Any, episodes: int, rng: np.random.Generator) -> float:
    """Seconds per env step over whole episodes (resets included)."""
    env.reset(seed=0)
    actions = rng.uniform(-1, 1, (HORIZON, 9)).astype(np.float32)
    steps = 0
    t0 = time.perf_counter()
    for _ in range(episodes):
        for a in actions:
            _, _, term, trunc, _ = env.step(a)
            steps += 1
            if term or trunc:
                break
        env.reset()
    return (time.perf_counter() - t0) / steps


def time_vector(step: Any, reset: Any, n: int, batch_steps: int, rng: np.random.Generator) -> float:
    """Seconds per batch step (autoresets included)."""
    reset()
    actions = rng.uniform(-1, 1, (8, n, 9)).astype(np.float32)
    t0 = time.perf_counter()
    for k in range(batch_steps):
        step(actions[k % 8])
    return (time.perf_counter() - t0) / batch_steps


def median(samples: list[float]) -> float:
    return statistics.median(samples)


def run(args: argparse.Namespace) -> dict[str, Any]:
    rng = np.random.default_rng(0)
    repeats = 3 if args.quick else args.repeats
    episodes = 1 if args.quick else 3
    rows: list[dict[str, Any]] = []

    for label, env in (
        ("scalar env, gymnasium.make", gym.make(ENV_ID)),
        ("scalar env, .unwrapped", gym.make(ENV_ID).unwrapped),
    ):
        time_scalar(env, 1, rng)  # warm up (numba cache load)
        t = median([time_scalar(env, episodes, rng) for _ in range(repeats)])
        rows.append(
            {
                "what": label,
                "config": "bank A + shadow (default)",
                "n": 1,
                "us_per_step": t * 1e6,
                "env_steps_per_s": 1 / t,
            }
        )

    sizes = (1, 64) if args.quick else (1, 64, 1024)
    for name, kwargs in VECTOR_CONFIGS.items():
        for n in sizes:
            venv = gym.make_vec(
                ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", **kwargs
            )
            steps = max(20, min(300, 30_000 // n))
            time_vector(venv.step, lambda v=venv: v.reset(seed=0), n, 5, rng)
            t = median(
                [
                    time_vector(venv.step, lambda v=venv: v.reset(seed=0), n, steps, rng)
                    for _ in range(repeats)
                ]
            )
            rows.append(
                {
                    "what": "vector env",
                    "config": name,
                    "n": n,
                    "us_per_step": t * 1e6,
                    "env_steps_per_s": n / t,
                }
            )

    for n in (64,) if args.quick else (64, 1024):
        sb3 = TPMAdaptVecEnv(num_envs=n)
        steps = max(20, min(300, 30_000 // n))
        time_vector(sb3.step, sb3.reset, n, 5, rng)
        t = median([time_vector(sb3.step, sb3.reset, n, steps, rng) for _ in range(repeats)])
        rows.append(
            {
                "what": "SB3 VecEnv adapter",
                "config": "bank A + shadow (default)",
                "n": n,
                "us_per_step": t * 1e6,
                "env_steps_per_s": n / t,
            }
        )

    imm = IMM(paper_bank(), Sonar())
    batch = draw_batch(paper_scenario(), Sonar(), 1, 0)
    episode = bench_imm.filterpy_episode(
        imm.F, imm.Q, Sonar().R, batch.measurements.z[0], batch.x0[0], batch.P0[0]
    )
    episode(10)
    fp = median([episode(HORIZON) / HORIZON for _ in range(repeats)])
    return {"rows": rows, "filterpy_us_per_step": fp * 1e6, "load": os.getloadavg()[0]}


def render(results: dict[str, Any], console: Console) -> None:
    table = Table(title="Environment throughput, 1 core (medians)")
    for col in ("what", "configuration", "N", "µs / batch step", "env-steps/s"):
        table.add_column(col, justify="left" if col in ("what", "configuration") else "right")
    for r in results["rows"]:
        table.add_row(
            r["what"],
            r["config"],
            str(r["n"]),
            f"{r['us_per_step']:,.0f}",
            f"{r['env_steps_per_s']:,.0f}",
        )
    console.print(table)
    fp = results["filterpy_us_per_step"]
    scalar = results["rows"][0]["us_per_step"]
    big = [
        r
        for r in results["rows"]
        if r["what"] == "vector env" and r["n"] == 1024 and r["config"] == "banks A+B + shadow"
    ]
    console.print(
        f"FilterPy IMMEstimator (3 UKFs) step: {fp:,.0f} µs. Scalar env via "
        f"gymnasium.make: {scalar:,.0f} µs per step = {fp / scalar:.1f}x faster "
        "(aim: 10x)."
    )
    if big:
        console.print(
            f"Vector env N=1024, parallel bank on: {big[0]['env_steps_per_s']:,.0f} "
            "env-steps/s (aim: 50,000)."
        )
    console.print(f"load average at the end: {results['load']:.2f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    results = run(args)
    render(results, Console(width=120))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
