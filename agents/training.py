"""PPO on the natively batched environment: hyperparameters, environment stack, save/load.

Hyperparameters live in ``agents/hyperparams/ppo.yml`` in rl-zoo3's format, keyed by environment
id (``n_envs``, ``n_timesteps``, ``policy``, ``normalize``, ``frame_stack``, ``env_kwargs``,
``env_mixture`` (further configurations and their shares of the slots: training across trackers),
``policy_kwargs`` and the algorithm's own arguments). They are data: every key is checked
against an allow-list (:data:`STACK_KEYS`, :data:`ALGO_KEYS`), ``policy_kwargs`` is structured
YAML (``net_arch`` as lists, ``activation_fn`` by name) and nothing is evaluated as Python. The
environment stack is
``VecFrameStack(VecNormalize(VecMonitor(TPMAdaptSB3VecEnv)))`` — one batched core, no subprocesses.

Seeds: :func:`seed_training_env` seeds training slot ``i`` of run seed ``s`` with
``TRAIN_SEED_BASE + 10_000 s + i`` once the algorithm is built (building ``PPO(seed=s)`` seeds
the environment with ``s + i``, held-out evaluation runs, and run seeds ``s`` and ``s + 1``
would share 63 of their 64 streams; the shipped agents were trained so, their first episode of
each slot a held-out run). Each slot continues its streams across episodes. The validation runs
that pick the best checkpoint use seeds ``VALIDATION_SEED_BASE + r``, never trained on.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from threadpoolctl import threadpool_limits

from agents.policy import MAX_FRAMES
from agents.schema import (
    MAX_INPUT,
    check_flag,
    check_number,
    check_policy_kwargs,
    check_sde,
    check_size,
)
from imm_gym.seeding import TRAIN_SEED_BASE, VALIDATION_SEED_BASE
from imm_gym.sim.mixture import check_mixture
from imm_gym.validation import ConfigError, load_yaml, shown

HYPERPARAMS = Path(__file__).parent / "hyperparams"
#: The training slots a run seed may have: run seed ``s``'s slot ``i`` is seeded with
#: ``TRAIN_SEED_BASE + SLOTS_PER_SEED s + i``, so that no two run seeds share a slot's streams.
SLOTS_PER_SEED = 10_000
#: The largest run seed ``s``: the algorithm seeds numpy's global generator with it
#: (``np.random.seed`` takes 0 to 2**32 - 1; RLlib's too). The seeds derived from it — the
#: training slots' ``TRAIN_SEED_BASE + 10_000 s + i`` (below 2**46, under
#: :data:`imm_gym.seeding.DETECTOR_SEED_BASE`), the constructor's ``s + i`` and RLlib's
#: :func:`imm_gym.seeding.rllib_seed` — go through ``numpy.random.SeedSequence``, which takes any
#: non-negative integer; the validation seeds do not depend on ``s``.
MAX_SEED = 2**32 - 1
ALGO_FILES = {"ppo": "ppo.yml", "recurrent-ppo": "recurrent_ppo.yml"}
#: The entry used for an environment id that has none in the hyperparameter file.
DEFAULT_ENTRY = "imm_gym/TPMAdapt-v0"
#: The policies each algorithm trains (``PerModelPolicy``: :mod:`agents.per_model`).
POLICIES = {"ppo": ("MlpPolicy", "PerModelPolicy"), "recurrent-ppo": ("MlpLstmPolicy",)}


def set_threads(n: int = 1) -> None:
    """One BLAS/torch thread per process: on 2 cores the env and the learner share the machine.

    Small MLP batches gain nothing from more threads, and oversubscription slows both down.
    """
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(n))
    # numpy's BLAS started its threads at import, before the variables: pinned where they run
    # (the learned detector's products would otherwise wait for a thread the learner holds)
    threadpool_limits(n)
    import torch

    torch.set_num_threads(n)


def read_yaml(file: Path) -> dict[str, Any]:
    """A YAML mapping of plain data (mappings, lists, strings, numbers, booleans, null), read
    as :func:`imm_gym.validation.load_yaml` reads it (YAML 1.2's scalars, no key twice).

    Raises:
        ConfigError: the file is not valid YAML or does not hold a mapping.
    """
    try:
        data = load_yaml(file.read_text())
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = "" if mark is None else f" at line {mark.line + 1}, column {mark.column + 1}"
        problem = getattr(err, "problem", None) or str(err).replace("\n", " ")
        raise ConfigError(f"{file}: not valid YAML ({problem}{where})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{file}: must hold a mapping, got {type(data).__name__}")
    return data


def load_hyperparams(
    env_id: str, algo: str = "ppo", path: Path | None = None
) -> tuple[dict[str, Any], str]:
    """The checked hyperparameter entry of ``env_id`` (rl-zoo3 YAML) and the entry's key:
    ``env_id``, or :data:`DEFAULT_ENTRY` if the file has no entry for it.

    Raises:
        ConfigError: the file or the entry is malformed (see :func:`check_hyperparams`).
    """
    if algo not in ALGO_FILES:
        raise ConfigError(f"algo must be one of {list(ALGO_FILES)}, got {algo!r}")
    file = path or HYPERPARAMS / ALGO_FILES[algo]
    table = read_yaml(file)
    entry = env_id if env_id in table else DEFAULT_ENTRY
    if entry not in table:
        raise ConfigError(f"{file}: no entry for {env_id!r} nor {DEFAULT_ENTRY!r}")
    return check_hyperparams(f"{file}: {entry}", table[entry], algo), entry


def _unit(where: str, value: Any) -> float:
    number = check_number(where, value)
    if not 0.0 < number <= 1.0:
        raise ConfigError(f"{where} must be in (0, 1], got {shown(value)}")
    return number


def _rate(where: str, value: Any) -> float | str:
    """A positive finite number, or rl-zoo3's ``lin_<number>`` (a linear schedule to 0 from a
    positive finite number: ``lin_inf`` would make every weight NaN), kept as is."""
    if isinstance(value, str) and value.startswith("lin_"):
        try:
            initial = float(value[4:])
        except ValueError:
            initial = math.nan
        if not 0 < initial < math.inf:
            raise ConfigError(
                f"{where} must be a number or 'lin_<number>', the number finite and > 0, got "
                f"{shown(value)}"
            )
        return value
    if isinstance(value, str) or not check_number(where, value) > 0:
        raise ConfigError(
            f"{where} must be a positive number or 'lin_<number>', got {shown(value)}"
        )
    return value


def _positive(where: str, value: Any) -> float:
    """A finite number above 0 (``max_grad_norm``: at or below 0 the clipped gradient vanishes
    or flips, and PPO climbs its loss; ``target_kl``: no update's KL is below 0)."""
    number = check_number(where, value)
    if not number > 0:
        raise ConfigError(f"{where} must be a finite number > 0, got {shown(value)}")
    return number


def _non_negative(where: str, value: Any) -> float:
    """A finite number >= 0 (``vf_coef``: below 0 the critic climbs its error)."""
    number = check_number(where, value)
    if not number >= 0:
        raise ConfigError(f"{where} must be a finite number >= 0, got {shown(value)}")
    return number


def _optional(check: Callable[[str, Any], Any]) -> Callable[[str, Any], Any]:
    return lambda where, value: None if value is None else check(where, value)


def _sde_sample_freq(where: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < -1:
        raise ConfigError(f"{where} must be an integer >= -1, got {shown(value)}")
    return value


def _timesteps(where: str, value: Any) -> int:
    number = check_number(where, value)
    if number < 1 or not number.is_integer():
        raise ConfigError(f"{where} must be a whole number >= 1, got {shown(value)}")
    return int(number)


def _swa_start(where: str, value: Any) -> float | None:
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if value is not None and not (number and 0 <= value < 1):
        raise ConfigError(f"{where} must be a fraction of the budget in [0, 1), got {shown(value)}")
    return value


def _n_envs(where: str, value: Any) -> int:
    """A count of training slots, at most :data:`SLOTS_PER_SEED` (a run seed's share of the
    training seeds)."""
    size = check_size(where, value)
    if size > SLOTS_PER_SEED:
        raise ConfigError(
            f"{where} must be in [1, {SLOTS_PER_SEED}] (a run seed's slots are seeded from "
            f"{SLOTS_PER_SEED} training seeds of its own), got {shown(value)}"
        )
    return size


def _frame_stack(where: str, value: Any) -> int:
    """A frame-stack depth an agent may be loaded with (:data:`agents.policy.MAX_FRAMES`)."""
    size = check_size(where, value)
    if size > MAX_FRAMES:
        raise ConfigError(
            f"{where} must be in [1, {MAX_FRAMES}] (the most frames an agent is loaded with), "
            f"got {shown(value)}"
        )
    return size


def _mapping(where: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ConfigError(f"{where} must be a mapping, got {shown(value)}")
    return value


#: Keys of a hyperparameter entry that configure the environment stack, with their checks.
STACK_KEYS: dict[str, Callable[[str, Any], Any]] = {
    "n_envs": _n_envs,
    "n_timesteps": _timesteps,
    "policy": lambda where, value: value,  # checked against the algorithm below
    "normalize": check_flag,
    "frame_stack": _frame_stack,
    "env_kwargs": _mapping,
    "env_mixture": lambda where, value: (check_mixture(where, value), value)[1],
    "critic_state": check_flag,
    "swa_start": _swa_start,
}

#: The algorithm's own arguments a hyperparameter entry may set, with their checks
#: (``policy_kwargs`` by :func:`agents.network.check_policy_kwargs`).
ALGO_KEYS: dict[str, Callable[[str, Any], Any]] = {
    "learning_rate": _rate,
    "n_steps": check_size,
    "batch_size": check_size,
    "n_epochs": check_size,
    "gamma": _unit,
    "gae_lambda": _unit,
    "clip_range": _rate,
    "clip_range_vf": _optional(_rate),
    "normalize_advantage": check_flag,
    "ent_coef": check_number,
    "vf_coef": _non_negative,
    "max_grad_norm": _positive,
    "use_sde": check_flag,
    "sde_sample_freq": _sde_sample_freq,
    "target_kl": _optional(_positive),  # None (null): no early stop, as SB3 allows
    "stats_window_size": check_size,
}


def check_hyperparams(where: str, params: Any, algo: str, complete: bool = True) -> dict[str, Any]:
    """A hyperparameter entry (or, with ``complete=False``, the part a ``--config`` file
    overrides) checked key by key; the result is plain data.

    Raises:
        ConfigError: not a mapping, an unknown key, a value of the wrong kind, a missing
            ``n_envs``/``n_timesteps``/``policy``, a policy the algorithm does not train,
            ``use_sde`` with a policy that cannot use it (:data:`agents.schema.NO_SDE`), or
            ``critic_state`` with a recurrent agent; the message names ``where`` and the key.
    """
    params = _mapping(where, params)
    known = [*STACK_KEYS, *ALGO_KEYS, "policy_kwargs"]
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise ConfigError(f"{where}: unknown hyperparameters {unknown}; allowed: {sorted(known)}")
    out: dict[str, Any] = {}
    for key, value in params.items():
        if key == "policy_kwargs":
            out[key] = check_policy_kwargs(where, value, algo == "recurrent-ppo")
        else:
            out[key] = {**STACK_KEYS, **ALGO_KEYS}[key](f"{where}: {key}", value)
    missing = [k for k in ("n_envs", "n_timesteps", "policy") if k not in params]
    if complete and missing:
        raise ConfigError(f"{where}: missing {missing}")
    if "policy" in out and out["policy"] not in POLICIES[algo]:
        raise ConfigError(
            f"{where}: policy must be one of {list(POLICIES[algo])} for {algo}, got "
            f"{shown(out['policy'])}"
        )
    if out.get("critic_state") and algo != "ppo":
        raise ConfigError(f"{where}: critic_state: true needs --algo ppo, got --algo {algo}")
    check_sde(f"{where}: use_sde", out.get("policy"), out.get("use_sde", False))
    return out


def check_policy(params: Mapping[str, Any], configs: Sequence[Any]) -> None:
    """The entry's policy (its hyperparameters merged: a ``--config`` file's over the entry's)
    against the configurations it trains on (every part's), before any work: a
    ``PerModelPolicy`` writes one action entry per model (the stay modes), without gSDE
    (``use_sde``: :data:`agents.schema.NO_SDE`).

    Raises:
        ConfigError: naming the key and what it allows.
    """
    from imm_gym.sim.actions import STAY_MODES

    check_sde("use_sde", params.get("policy"), params.get("use_sde", False))
    if params.get("policy") != "PerModelPolicy":
        return
    modes = sorted({cfg.action_mode for cfg in configs} - set(STAY_MODES))
    if modes:
        raise ConfigError(
            f"policy PerModelPolicy writes one action entry per model: action_mode must be one "
            f"of {list(STAY_MODES)}, got {modes[0]!r}"
        )


def check_input_size(params: Mapping[str, Any], config: Any) -> None:
    """The network's input — ``frame_stack`` frames of the observation of ``config`` (the
    agent's configuration; the parts of a mixture observe alike), each with the critic's ground
    truth where ``critic_state`` is set — within :data:`agents.schema.MAX_INPUT`, the largest
    input an agent is loaded with, before any training.

    Raises:
        ConfigError: naming ``frame_stack`` and the largest it may be for this observation.
    """
    from imm_gym.sim.core import critic_state_size
    from imm_gym.sim.features import observation_size

    M = len(config.bank)
    frame = observation_size(config.obs_features, M, config.sensor.dim_z)
    frame += critic_state_size(M) if params.get("critic_state") else 0
    frames = int(params.get("frame_stack", 1))
    if frames * frame > MAX_INPUT:
        raise ConfigError(
            f"frame_stack must be in [1, {MAX_INPUT // frame}] for frames of {frame} entries "
            f"(an agent's input is at most {MAX_INPUT} entries), got {frames}"
        )


def check_batches(params: Mapping[str, Any]) -> None:
    """Advantages normalized over a minibatch (``normalize_advantage``, on by default) need two
    samples or more in it and in the rollout: ``batch_size >= 2`` and ``n_envs * n_steps >= 2``
    (SB3 asserts both once the run directory exists), checked before any work.

    Raises:
        ConfigError: naming the key and what it allows.
    """
    if params.get("normalize_advantage") is False:
        return
    if params.get("batch_size", 64) < 2:
        raise ConfigError(
            f"batch_size must be >= 2 with normalize_advantage (the advantages are normalized "
            f"over a minibatch), got {params['batch_size']}"
        )
    rollout = params["n_envs"] * params.get("n_steps", 2048)
    if rollout < 2:
        raise ConfigError(
            f"n_envs * n_steps must be >= 2 with normalize_advantage (one rollout's samples), "
            f"got {params['n_envs']} * {params.get('n_steps', 2048)}"
        )


def seed_training_env(env: Any, seed: int) -> None:
    """Seed the next reset of training slot ``i`` of run seed ``seed`` with
    ``TRAIN_SEED_BASE + 10_000 seed + i`` (a VecEnv or a wrapper of one); again once the
    algorithm is built (:func:`build_algorithm`): SB3's constructor seeds the environment with
    its own seed, ``seed + i``, the held-out evaluation runs."""
    env.seed(TRAIN_SEED_BASE + SLOTS_PER_SEED * seed)


def build_algorithm(algo_cls: type, policy: Any, env: Any, seed: int, **kwargs: Any) -> Any:
    """``algo_cls(policy, env, seed=seed, device="cpu", **kwargs)`` (PPO, RecurrentPPO), its
    training slots then seeded from the training seeds (:func:`seed_training_env`: the
    constructor seeds them with the held-out ones)."""
    model = algo_cls(policy, env, seed=seed, device="cpu", **kwargs)
    seed_training_env(env, seed)
    return model


def make_training_env(
    env_id: str,
    n_envs: int,
    seed: int,
    env_kwargs: dict[str, Any],
    normalize: bool,
    frame_stack: int,
    gamma: float,
    critic_state: bool = False,
    mixture: Sequence[Mapping[str, Any]] = (),
    tie_models: bool = False,
) -> Any:
    """The vectorized training environment (see the module docstring); ``critic_state`` appends
    ground truth for an asymmetric critic (:mod:`agents.asymmetric`); ``mixture`` (the entry's
    ``env_mixture``) gives further configurations their share of the slots
    (:class:`~imm_gym.envs.sb3.TPMAdaptSB3VecEnv`); ``tie_models``: the normalizer keeps one
    statistic per feature entry over the models (a ``PerModelPolicy``'s,
    :class:`agents.per_model.TiedRunningMeanStd`)."""
    from stable_baselines3.common.vec_env import VecFrameStack, VecMonitor, VecNormalize

    from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv

    venv = TPMAdaptSB3VecEnv(
        num_envs=n_envs, env_id=env_id, critic_state=critic_state, mixture=mixture, **env_kwargs
    )
    seed_training_env(venv, seed)
    env: Any = VecMonitor(venv)
    if normalize:
        env = VecNormalize(env, norm_obs=True, norm_reward=True, gamma=gamma)
        if tie_models:
            from agents.per_model import TiedRunningMeanStd, frame_groups

            cfg = venv.config
            per_model, _ = frame_groups(
                cfg.obs_features, venv.core.M, cfg.sensor.dim_z, critic_state
            )
            env.obs_rms = TiedRunningMeanStd(per_model, env.obs_rms.mean.shape)
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
    """Write the acting files of :mod:`agents.policy`: ``policy.safetensors``, ``agent.json``
    (with the network's description and ``normalize``, whether the observations are
    normalized), ``env.json`` and, when they are, ``vecnormalize.json``."""
    from agents.network import policy_spec, save_weights
    from agents.policy import write_env_file

    directory.mkdir(parents=True, exist_ok=True)
    save_weights(model.policy, directory)
    write_env_file(directory, env_kwargs)
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
    else:  # an earlier agent's statistics in this directory would contradict the record
        (directory / "vecnormalize.json").unlink(missing_ok=True)
    meta = {
        "algo": algo,
        "frame_stack": frame_stack,
        "normalize": norm is not None,
        **(extra or {}),
        "policy": policy_spec(model.policy),
    }
    (directory / "agent.json").write_text(json.dumps(meta, indent=2))


def jsonable(value: Any) -> Any:
    """Tuples as lists, recursively (for JSON)."""
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    return value


def algo_kwargs(params: dict[str, Any]) -> dict[str, Any]:
    """The algorithm's own arguments from a hyperparameter entry, as SB3 takes them: rl-zoo3's
    ``lin_X`` strings (``learning_rate``, ``clip_range``, ``clip_range_vf``) become
    :func:`linear_schedule` ``(X)``, ``policy_kwargs``' activation its ``nn.Module`` class."""
    from agents.network import sb3_policy_kwargs

    kwargs = {k: v for k, v in params.items() if k not in STACK_KEYS}
    if "policy_kwargs" in kwargs:
        kwargs["policy_kwargs"] = sb3_policy_kwargs(kwargs["policy_kwargs"])
    for key in ("learning_rate", "clip_range", "clip_range_vf"):
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

    A checkpoint keeps ``average``, ``snapshots`` and ``last_update``
    (:mod:`agents.checkpoint`), so a resumed run continues the mean.
    """

    def __init__(self, start: int) -> None:
        self.start = start
        self.average: dict[str, Any] = {}
        self.snapshots = 0
        self.last_update = -1

    def update(self, model: Any) -> None:
        """Add ``model.policy``'s weights once per PPO update (``model._n_updates``), from
        ``start`` on; calling it again before the next update does nothing."""
        import torch

        if model._n_updates == 0 or model.num_timesteps < self.start:
            return  # the initial weights are no update's
        if model._n_updates == self.last_update:
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
