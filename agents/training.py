"""PPO on the natively batched environment: hyperparameters, environment stack, save/load.

Hyperparameters live in ``agents/hyperparams/ppo.yml`` in rl-zoo3's format, keyed by environment
id (``n_envs``, ``n_timesteps``, ``policy``, ``normalize``, ``frame_stack``, ``env_kwargs``,
``policy_kwargs`` and the algorithm's own arguments). The environment stack is
``VecFrameStack(VecNormalize(VecMonitor(TPMAdaptSB3VecEnv)))`` — one batched core, no subprocesses.

Seeds: training slot ``i`` of run seed ``s`` starts its streams from ``TRAIN_SEED_BASE + 10_000 s
+ i`` and continues them across episodes; the validation runs that pick the best checkpoint use
seeds ``VALIDATION_SEED_BASE + r``; evaluation uses seeds below 10 million, so held-out scenarios
are neither trained on nor used for model selection.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

HYPERPARAMS = Path(__file__).parent / "hyperparams"
TRAIN_SEED_BASE = 100_000_000
VALIDATION_SEED_BASE = 50_000_000
ALGO_FILES = {"ppo": "ppo.yml", "recurrent-ppo": "recurrent_ppo.yml"}

#: Keys of a hyperparameter entry that configure the environment stack, not the algorithm.
_STACK_KEYS = (
    "n_envs",
    "n_timesteps",
    "policy",
    "normalize",
    "frame_stack",
    "env_kwargs",
    "critic_state",
    "swa_start",
)


def set_threads(n: int = 1) -> None:
    """One BLAS/torch thread per process: on 2 cores the env and the learner share the machine.

    Small MLP batches gain nothing from more threads, and oversubscription slows both down.
    """
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(n))
    import torch

    torch.set_num_threads(n)


def load_hyperparams(env_id: str, algo: str = "ppo", path: Path | None = None) -> dict[str, Any]:
    """The hyperparameter entry of ``env_id`` (rl-zoo3 YAML); ``policy_kwargs`` evaluated."""
    import yaml

    if algo not in ALGO_FILES:
        raise ValueError(f"algo must be one of {list(ALGO_FILES)}, got {algo!r}")
    file = path or HYPERPARAMS / ALGO_FILES[algo]
    table = yaml.safe_load(file.read_text())
    if env_id not in table:
        raise ValueError(f"{file.name} has no entry for {env_id!r}; entries: {sorted(table)}")
    params = dict(table[env_id])
    if isinstance(params.get("policy_kwargs"), str):
        params["policy_kwargs"] = _eval_policy_kwargs(params["policy_kwargs"])
    return params


def _eval_policy_kwargs(text: str) -> dict[str, Any]:
    """rl-zoo3 writes ``policy_kwargs`` as a Python expression such as ``dict(net_arch=[64])``."""
    import torch

    namespace = {"dict": dict, "nn": torch.nn, "__builtins__": {}}
    return dict(eval(text, namespace))


def make_training_env(
    env_id: str,
    n_envs: int,
    seed: int,
    env_kwargs: dict[str, Any],
    normalize: bool,
    frame_stack: int,
    gamma: float,
    critic_state: bool = False,
) -> Any:
    """The vectorized training environment (see the module docstring); ``critic_state`` appends
    ground truth for an asymmetric critic (:mod:`agents.asymmetric`)."""
    from stable_baselines3.common.vec_env import VecFrameStack, VecMonitor, VecNormalize

    from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv

    venv = TPMAdaptSB3VecEnv(
        num_envs=n_envs, env_id=env_id, critic_state=critic_state, **env_kwargs
    )
    venv.seed(TRAIN_SEED_BASE + 10_000 * seed)
    env: Any = VecMonitor(venv)
    if normalize:
        env = VecNormalize(env, norm_obs=True, norm_reward=True, gamma=gamma)
    if frame_stack > 1:
        env = VecFrameStack(env, frame_stack)
    return env


def find_normalizer(env: Any) -> Any | None:
    """The ``VecNormalize`` layer of a wrapped VecEnv, if any."""
    from stable_baselines3.common.vec_env import VecEnvWrapper, VecNormalize

    while isinstance(env, VecEnvWrapper):
        if isinstance(env, VecNormalize):
            return env
        env = env.venv
    return None


def save_agent(
    directory: Path,
    model: Any,
    env: Any,
    env_kwargs: dict[str, Any],
    algo: str,
    frame_stack: int,
    extra: dict[str, Any] | None = None,
) -> None:
    """Write ``model.zip``, ``policy.pt``, ``env.json``, ``vecnormalize.json``, ``agent.json``."""
    directory.mkdir(parents=True, exist_ok=True)
    model.save(directory / "model.zip")
    model.policy.save(str(directory / "policy.pt"))
    (directory / "env.json").write_text(json.dumps(jsonable(env_kwargs), indent=2))
    norm = find_normalizer(env)
    if norm is not None:
        stats = {
            "mean": np.asarray(norm.obs_rms.mean).tolist(),
            "var": np.asarray(norm.obs_rms.var).tolist(),
            "count": float(norm.obs_rms.count),
            "clip_obs": float(norm.clip_obs),
            "epsilon": float(norm.epsilon),
        }
        (directory / "vecnormalize.json").write_text(json.dumps(stats))
    meta = {"algo": algo, "frame_stack": frame_stack, **(extra or {})}
    (directory / "agent.json").write_text(json.dumps(meta, indent=2))


def jsonable(value: Any) -> Any:
    """Tuples as lists, recursively (for JSON)."""
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    return value


def algo_kwargs(params: dict[str, Any]) -> dict[str, Any]:
    """The algorithm's own arguments from a hyperparameter entry; rl-zoo3's ``lin_X`` strings
    (``learning_rate``, ``clip_range``) become :func:`linear_schedule` ``(X)``."""
    kwargs = {k: v for k, v in params.items() if k not in _STACK_KEYS}
    for key in ("learning_rate", "clip_range"):
        value = kwargs.get(key)
        if isinstance(value, str):
            if not value.startswith("lin_"):
                raise ValueError(f"{key} must be a number or 'lin_<number>', got {value!r}")
            kwargs[key] = linear_schedule(float(value[4:]))
    return kwargs


def linear_schedule(initial: float) -> Any:
    """``f(progress_remaining) = progress_remaining * initial``: from ``initial`` at the start of
    training down to 0 at its end (SB3 passes the remaining fraction, 1 -> 0)."""

    def schedule(progress_remaining: float) -> float:
        return progress_remaining * initial

    return schedule


class WeightAverage:
    """Stochastic weight averaging (Izmailov et al. 2018) of the policy over training: the
    running mean ``θ̄_n = θ̄_{n-1} + (θ_n − θ̄_{n-1}) / n`` of the weights after every update
    from step ``start`` on. PPO's iterates keep wandering at a constant learning rate; their mean
    averages the wander out instead of betting on one iterate.

    Args:
        start: the first training step whose post-update weights enter the mean.
    """

    FILE = "swa.pt"

    def __init__(self, start: int) -> None:
        self.start = start
        self.average: dict[str, Any] = {}
        self.snapshots = 0
        self.last_update = -1

    def update(self, model: Any) -> None:
        """Add ``model.policy``'s weights once per PPO update (``model._n_updates``), from
        ``start`` on; calling it again before the next update does nothing."""
        import torch

        if model.num_timesteps < self.start or model._n_updates == self.last_update:
            return
        self.snapshots += 1
        with torch.no_grad():
            for name, value in model.policy.state_dict().items():
                if name not in self.average or not value.is_floating_point():
                    self.average[name] = value.detach().clone()  # integer buffers: indices
                else:
                    self.average[name] += (value - self.average[name]) / self.snapshots
        self.last_update = model._n_updates

    def apply(self, model: Any) -> None:
        """Load the averaged weights into ``model.policy``."""
        if not self.snapshots:
            raise RuntimeError(f"no weights averaged: training ended before step {self.start}")
        model.policy.load_state_dict(self.average)

    def save(self, directory: Path) -> None:
        import torch

        if self.snapshots:
            state = {
                "average": self.average,
                "snapshots": self.snapshots,
                "last_update": self.last_update,
            }
            torch.save(state, directory / self.FILE)

    def load(self, directory: Path) -> None:
        """Continue the mean saved beside a checkpoint (if averaging had begun there)."""
        import torch

        file = directory / self.FILE
        if file.is_file():
            state = torch.load(file, weights_only=True)
            self.average = state["average"]
            self.snapshots = int(state["snapshots"])
            self.last_update = int(state["last_update"])


def validation_armse(
    model: Any,
    env: Any,
    env_id: str,
    env_kwargs: dict[str, Any],
    frame_stack: int,
    algo: str,
    runs: int,
    critic_dims: int = 0,
) -> float:
    """Position ARMSE of the live ``model`` (deterministic actions) on ``runs`` validation runs
    of ``env_id``'s scenario source, seeds ``VALIDATION_SEED_BASE + r``: the score that selects
    the checkpoint to keep, on scenarios disjoint from training and from the held-out evaluation.
    """
    from agents.policy import LearnedPolicy
    from imm_gym.envs import PRESETS
    from imm_gym.evaluation.rollout import evaluation_config, rollout, score
    from imm_gym.sim.env_config import EnvConfig

    norm = find_normalizer(env)
    overrides = {k: tuple(v) if isinstance(v, list) else v for k, v in env_kwargs.items()}
    policy = LearnedPolicy(
        model,
        overrides,
        None if norm is None else np.asarray(norm.obs_rms.mean),
        None if norm is None else np.asarray(norm.obs_rms.var),
        10.0 if norm is None else float(norm.clip_obs),
        1e-8 if norm is None else float(norm.epsilon),
        frame_stack=frame_stack,
        recurrent=algo == "recurrent-ppo",
        critic_dims=critic_dims,
    )
    config = evaluation_config(EnvConfig.build(PRESETS[env_id]), overrides)
    return float(score(rollout(policy, config, runs, VALIDATION_SEED_BASE))["armse_pos"])
