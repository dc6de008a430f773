"""Training throughput: RLlib PPO with 1 and 2 env runners beside SB3 ``train.py``.

    .venv-ray/bin/python benchmarks/bench_ray.py                 # ~1.5 minutes on 2 cores
    .venv-ray/bin/python benchmarks/bench_ray.py --iterations 4 --sb3-steps 100000

Every row trains the default entry of ``agents/hyperparams/ppo.yml`` (64 sub-envs per runner,
4,096 samples per runner and update) and prints env-steps/s over whole iterations (sampling and
the PPO update), after one warm-up iteration. For RLlib, the share of an iteration spent
sampling (``timers/env_runner_sampling_timer``) and updating (``timers/learner_update_timer``);
"with infos" steps the env that returns the per-step info dicts of
:class:`~imm_gym.envs.vector.TPMAdaptVectorEnv`, as a plain vector env would. The last row steps
the vector env alone with random actions: the ceiling of one process. Every row's env is the one
RLlib's runners build from the entry (:func:`agents.rllib.ppo_config`'s ``env_config``: its
``env_mixture`` too). Output: a Markdown table (README, "Scaling out").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from agents import rllib
from agents.training import DEFAULT_ENTRY, load_hyperparams, set_threads
from imm_gym.envs.vector import TPMAdaptVectorEnv


class WithInfos(rllib.RLlibVectorEnv):
    """The runner's env returning the per-step infos it normally drops."""

    def step(self, actions: Any) -> Any:
        return TPMAdaptVectorEnv.step(self, actions)


def make_with_infos(config: dict[str, Any]) -> WithInfos:
    """The env creator of the "with infos" rows (:func:`agents.rllib.make_env`'s env, infos
    kept)."""
    return WithInfos(
        int(config["num_envs"]),
        config["env_id"],
        config.get("env_kwargs"),
        config.get("env_mixture", ()),
    )


def bench_rllib(params: dict[str, Any], runners: int, infos: bool, iterations: int) -> dict:
    """env-steps/s of ``iterations`` RLlib PPO iterations and the sampling / update shares."""
    from ray.tune.registry import register_env

    _ledger, name = rllib.start_ledger(0)  # the handle keeps the ledger alive
    config = rllib.ppo_config(params, DEFAULT_ENTRY, 0, runners, name)
    if infos:
        register_env(rllib.ENV_NAME, make_with_infos)
    algo = config.build_algo()
    try:
        steps = rllib.env_steps(algo.train())  # warm-up: compilation, first weights
        start, sample, learn = time.perf_counter(), 0.0, 0.0
        for _ in range(iterations):
            result = algo.train()
            sample += result["timers"]["env_runner_sampling_timer"]
            learn += result["timers"]["learner_update_timer"]
        seconds = time.perf_counter() - start
        done = rllib.env_steps(result, steps) - steps
    finally:
        algo.stop()
    return {
        "fps": done / seconds,
        "sample": sample / iterations,
        "learn": learn / iterations,
        "iteration": seconds / iterations,
    }


def bench_sb3(steps: int) -> float:
    """env-steps/s of ``python train.py`` (SB3, one process) over ``steps`` steps."""
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [
                sys.executable,
                str(Path(__file__).resolve().parents[1] / "train.py"),
                "--timesteps",
                str(steps),
                "--no-eval",
                "--no-progress",
                "--validate-every",
                "0",
                "--checkpoint-every",
                str(10 * steps),
                "--out",
                tmp,
            ],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        stats = json.loads((Path(tmp) / "seed_0" / "training.json").read_text())
    return float(stats["fps"])


def bench_env(params: dict[str, Any], steps: int) -> float:
    """env-steps/s of the vector env alone (a runner's env: ``n_envs`` sub-envs, random
    actions)."""
    env_config = rllib.ppo_config(params, DEFAULT_ENTRY, 0, 1, "unused").env_config
    env = rllib.make_env({**env_config, "num_envs": int(params["n_envs"])})
    env.assign_seeds(list(range(env.num_envs)))
    env.reset()
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, *env.action_space.shape)).astype(np.float32)
    env.step(actions[0])  # compilation
    start = time.perf_counter()
    for a in actions[1:]:
        env.step(a)
    return (steps - 1) * env.num_envs / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--iterations", type=int, default=8, help="timed RLlib iterations")
    parser.add_argument("--sb3-steps", type=int, default=300_000, help="SB3 training steps")
    args = parser.parse_args()
    if args.iterations < 1 or args.sb3_steps < 1:
        parser.error(
            f"--iterations and --sb3-steps must be >= 1, got {args.iterations} and {args.sb3_steps}"
        )
    import ray  # after the arguments: --help works without Ray

    set_threads(1)
    params, _ = load_hyperparams(DEFAULT_ENTRY)
    ray.init(include_dashboard=False, log_to_driver=False)
    rows = []
    for runners, infos in ((1, False), (2, False), (1, True), (2, True)):
        r = bench_rllib(params, runners, infos, args.iterations)
        share = r["sample"] / (r["sample"] + r["learn"])
        rows.append(
            (
                f"RLlib PPO, {runners} env runner{'s' if runners > 1 else ''}"
                + (", with infos" if infos else ""),
                f"{r['fps']:,.0f}",
                f"{r['iteration']:.2f} s per iteration: sampling {100 * share:.0f} %, "
                f"update {100 * (1 - share):.0f} %",
            )
        )
    ray.shutdown()
    rows.append(
        ("SB3 `train.py` (1 process)", f"{bench_sb3(args.sb3_steps):,.0f}", "env + net + update")
    )
    rows.append(("vector env alone, random actions", f"{bench_env(params, 2000):,.0f}", "ceiling"))
    print("| engine | env-steps/s | where the time goes |")
    print("|---|---:|---|")
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
