"""PPO on Ray RLlib (new API stack): ``python train.py --engine rllib`` (README, "Scaling out").

Each RLlib env runner steps one :class:`RLlibVectorEnv`: the project's natively batched vector
env (one :class:`~imm_gym.sim.core.TrackingCore` for its ``n_envs`` sub-envs) that returns no
per-step ``info`` (RLlib splits an info dict into one dict per sub-env every step: at 64 sub-envs
that halves its sampling rate). The learner runs on the driver.

Seeds are the project's, not RLlib's (RLlib seeds runner ``w`` with ``seed + w`` and sub-env
``i`` with that plus ``i``, so runner 1's sub-env 1 and runner 2's sub-env 0 would replay the same
targets): when a runner builds its env, :func:`assign_seeds` asks the run's :class:`SeedLedger`
(a named Ray actor) for the runner's generation ``g`` (0, then 1, ... each time that runner
index builds an env again, e.g. after Ray restarted it) and gives sub-env ``i`` of runner ``w``
the seed :func:`~imm_gym.seeding.rllib_seed` ``(seed, w, i, g)``, disjoint across runners,
sub-envs, restarts and from every evaluation and validation seed. Each sub-env continues its
streams across its episodes.

The hyperparameter entry (``agents/hyperparams/ppo.yml``) maps onto RLlib's PPO
(:func:`ppo_config`): ``n_envs`` sub-envs per runner, ``n_steps`` the rollout fragment,
``n_steps * n_envs`` samples per runner and iteration, ``batch_size`` the minibatch,
``n_epochs``, ``gamma``, ``gae_lambda``, ``learning_rate`` (``lin_X``: a linear schedule to 0),
``clip_range``, ``ent_coef``, ``vf_coef``, ``max_grad_norm``, the ``net_arch`` (the same sizes
for actor and critic), the activation and ``log_std_init``; ``normalize`` is RLlib's
``MeanStdFilter`` connector on observations, ``frame_stack`` the :class:`FrameStack` connectors
(the env-to-module and the learner pipelines; oldest frame first, zeros before an episode's
first frame, as SB3's ``VecFrameStack``). Not ported (:data:`NOT_PORTED`, said when training and
recorded in ``training.json``): the asymmetric critic (``critic_state``), the weight average
(``swa_start``), the reward normalization of ``VecNormalize``, the advantages' normalization per
minibatch (RLlib normalizes over the iteration's batch) and SB3's orthogonal initialization
(``ortho_init``, on by default); refused: settings RLlib's PPO has no equivalent for
(:func:`ppo_config`). A mixture of trackers (``env_mixture``) trains as with SB3: every runner's
sub-envs are split among the parts by their shares.

:func:`export_agent` writes the trained policy in the project's agent format (``agent.json``,
``policy.safetensors``, ``env.json``, ``vecnormalize.json``: data, no pickles) as the SB3
``MlpPolicy`` that computes the same actions, so ``python -m imm_gym.evaluate --policy DIR`` and
:func:`agents.policy.load_agent` take it like any trained agent.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from agents.training import jsonable
from imm_gym.envs import PRESETS
from imm_gym.envs.vector import TPMAdaptVectorEnv
from imm_gym.seeding import rllib_seed
from imm_gym.sim.mixture import MixtureCore
from imm_gym.validation import ConfigError

#: The name the env creator is registered under (:func:`ray.tune.registry.register_env`).
ENV_NAME = "imm_gym-rllib"
#: Hyperparameters RLlib's PPO trains without, and what is done instead.
NOT_PORTED = {
    "critic_state": "the critic sees the actor's observation (no asymmetric critic)",
    "swa_start": "no weight average: the agent is the validated best (or the last) policy",
    "normalize": "observations only: rewards are not normalized (VecNormalize's norm_reward)",
    "normalize_advantage": "over each iteration's whole batch (RLlib's advantage estimation), "
    "not over each minibatch as SB3",
    "ortho_init": "the layers start from PyTorch's default initialization, not SB3's orthogonal "
    "one (gains sqrt(2), 0.01 for the action head, 1 for the value head)",
}
#: SB3 activation names (:data:`agents.schema.ACTIVATIONS`) RLlib's default module has too.
ACTIVATIONS = {"tanh": "tanh", "relu": "relu", "elu": "elu", "silu": "silu"}
#: RLlib's ``MeanStdFilter``: ``(x - mean) / (std + SMALL)``, clipped to ``±CLIP``.
FILTER_SMALL, FILTER_CLIP = 1e-6, 10.0


class RLlibVectorEnv(TPMAdaptVectorEnv):
    """:class:`~imm_gym.envs.vector.TPMAdaptVectorEnv` with the project's seeds and no infos.

    Args:
        num_envs: sub-envs (RLlib's ``num_envs_per_env_runner``).
        env_id: the registered id whose preset is the base configuration.
        env_kwargs: EnvConfig fields over the preset (the hyperparameters' ``env_kwargs``).
        mixture: the hyperparameters' ``env_mixture``: further configurations (each over the
            preset), each on its share of the sub-envs
            (:class:`~imm_gym.sim.mixture.MixtureCore`, as the SB3 adapter does).

    The first :meth:`reset` seeds sub-env ``i`` with ``seeds[i]`` given by
    :meth:`assign_seeds` (RLlib's own seed is ignored); later resets continue each sub-env's
    streams.
    """

    def __init__(
        self,
        num_envs: int,
        env_id: str,
        env_kwargs: dict[str, Any] | None = None,
        mixture: Sequence[Mapping[str, Any]] = (),
    ) -> None:
        super().__init__(num_envs, config={**PRESETS[env_id], **(env_kwargs or {})})
        if mixture:
            self.core = MixtureCore.of(self.config, mixture, PRESETS[env_id], num_envs)
        self.seeds: list[int] | None = None
        self._seeded = False

    def assign_seeds(self, seeds: list[int]) -> None:
        """The sub-envs' seeds, used by the next (first) reset."""
        if len(seeds) != self.num_envs:
            raise ValueError(f"{self.num_envs} seeds needed, got {len(seeds)}")
        self.seeds, self._seeded = list(seeds), False

    def reset(
        self, *, seed: Any = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        if self.seeds is None:
            raise RuntimeError("RLlibVectorEnv reset before assign_seeds (see agents.rllib)")
        first = not self._seeded
        self._seeded = True
        obs, _ = super().reset(seed=self.seeds if first else None, options=options)
        return obs, {}

    def step(
        self, actions: NDArray[Any]
    ) -> tuple[
        NDArray[np.float32], NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_], dict
    ]:
        obs, reward, terminated, truncated, _ = super().step(actions)
        return obs, reward, terminated, truncated, {}


def make_env(config: dict[str, Any]) -> RLlibVectorEnv:
    """The env creator registered as :data:`ENV_NAME`: RLlib calls it with the algorithm's
    ``env_config`` (``env_id``, ``env_kwargs``, ``env_mixture``) and ``num_envs``."""
    return RLlibVectorEnv(
        int(config["num_envs"]),
        config["env_id"],
        config.get("env_kwargs"),
        config.get("env_mixture", ()),
    )


class SeedLedger:
    """The seeds of one training run's sub-envs, handed out as runners build their envs (a named
    Ray actor, :func:`start_ledger`); it keeps every assignment for the record."""

    def __init__(self, seed: int) -> None:
        self.seed = seed
        self.generations: dict[int, int] = {}
        self.assignments: list[dict[str, Any]] = []

    def assign(self, runner: int, num_envs: int, node: str) -> list[int]:
        """Seeds of the ``num_envs`` sub-envs of the env runner ``runner`` (on ``node``)."""
        generation = self.generations.get(runner, 0)
        self.generations[runner] = generation + 1
        seeds = [rllib_seed(self.seed, runner, i, generation) for i in range(num_envs)]
        self.assignments.append(
            {"runner": runner, "generation": generation, "node": node, "seeds": seeds}
        )
        return seeds

    def records(self) -> list[dict[str, Any]]:
        """Every assignment: runner, generation, node id and seeds."""
        return self.assignments


def start_ledger(seed: int) -> tuple[Any, str]:
    """A :class:`SeedLedger` actor for training seed ``seed`` and its (unique) name."""
    import ray

    name = f"imm_gym_seed_ledger_{seed}_{uuid.uuid4().hex[:8]}"
    actor = ray.remote(num_cpus=0)(SeedLedger).options(name=name).remote(seed)
    return actor, name


def assign_seeds(*, env_runner: Any, env: Any, **kwargs: Any) -> None:
    """RLlib's ``on_environment_created`` callback: the runner's seeds from the run's ledger."""
    import ray

    ledger = ray.get_actor(env_runner.config.env_config["seed_ledger"])
    node = ray.get_runtime_context().get_node_id()
    runner = int(env_runner.worker_index or 0)
    env.assign_seeds(ray.get(ledger.assign.remote(runner, env.num_envs, node)))


def _frame_stack_connector(frames: int, learner: bool) -> Any:
    """A :class:`FrameStack` connector piece (built lazily: RLlib is imported only here)."""
    from ray.rllib.connectors.connector_v2 import ConnectorV2
    from ray.rllib.core.columns import Columns

    class FrameStack(ConnectorV2):
        """The last ``frames`` observations of a flat Box, oldest first, concatenated:
        ``o_{t-n+1} | ... | o_t`` with zero frames before the episode's first (SB3's
        ``VecFrameStack``). RLlib's own ``FrameStacking`` needs images (a trailing axis of 1).
        """

        def recompute_output_observation_space(
            self, input_observation_space: gym.Space, input_action_space: gym.Space
        ) -> gym.Space:
            space = input_observation_space
            return gym.spaces.Box(
                np.tile(space.low, frames), np.tile(space.high, frames), dtype=space.dtype
            )

        def __call__(
            self, *, rl_module: Any, batch: dict[str, Any], episodes: list[Any], **kwargs: Any
        ) -> Any:
            if learner:
                for episode in self.single_agent_episode_iterator(
                    episodes, agents_that_stepped_only=False
                ):
                    n = len(episode)
                    obs = np.asarray(
                        episode.get_observations(
                            indices=slice(-frames + 1, n), neg_index_as_lookback=True, fill=0.0
                        )
                    )
                    windows = np.lib.stride_tricks.sliding_window_view(obs, frames, axis=0)
                    stacked = np.swapaxes(windows, 1, 2).reshape(n, -1)
                    self.add_n_batch_items(
                        batch, Columns.OBS, stacked, num_items=n, single_agent_episode=episode
                    )
            else:
                for episode in self.single_agent_episode_iterator(episodes):
                    obs = episode.get_observations(indices=slice(-frames, None), fill=0.0)
                    self.add_batch_item(
                        batch,
                        Columns.OBS,
                        np.concatenate(list(obs)).astype(np.float32),
                        single_agent_episode=episode,
                    )
            return batch

    return FrameStack()


def iteration_samples(params: dict[str, Any], env_runners: int) -> int:
    """The samples of one PPO iteration (RLlib's ``train_batch_size_per_learner``): ``n_steps *
    n_envs`` from each sampling runner (the driver where ``env_runners`` is 0)."""
    return int(params.get("n_steps", 2048)) * int(params["n_envs"]) * max(env_runners, 1)


def check_params(params: dict[str, Any], env_runners: int) -> None:
    """Refuse the hyperparameters RLlib's PPO has no equivalent for, or that its configuration
    check refuses, before any work (a pure function: no Ray).

    Args:
        params: the hyperparameter entry.
        env_runners: remote env runners (``--env-runners``; 0: the driver samples).

    Raises:
        ConfigError: a ``lin_`` clip range, ``clip_range_vf``, ``target_kl``, gSDE, no advantage
            normalization, different actor and critic sizes, an activation RLlib lacks, a policy
            other than ``MlpPolicy``; a minibatch (``batch_size``) larger than an iteration's
            samples (``n_steps * n_envs * max(env_runners, 1)``, RLlib's
            ``train_batch_size_per_learner``).
    """
    batch, minibatch = iteration_samples(params, env_runners), int(params.get("batch_size", 64))
    if minibatch > batch:
        raise ConfigError(
            f"--engine rllib: batch_size {minibatch} (the minibatch) is above the {batch} samples "
            f"of an iteration (n_steps {params.get('n_steps', 2048)} x n_envs {params['n_envs']} "
            f"x {max(env_runners, 1)} sampling runner(s), --env-runners {env_runners}): lower "
            "batch_size, or raise n_steps, n_envs or --env-runners"
        )
    refused = {
        "clip_range": isinstance(params.get("clip_range"), str),
        "clip_range_vf": params.get("clip_range_vf") is not None,
        "target_kl": params.get("target_kl") is not None,
        "use_sde": bool(params.get("use_sde")),
        "normalize_advantage": params.get("normalize_advantage") is False,
        "policy": params.get("policy", "MlpPolicy") != "MlpPolicy",
    }
    kwargs = params.get("policy_kwargs", {})
    arch = kwargs.get("net_arch", {"pi": [64, 64], "vf": [64, 64]})
    pi, vf = (arch["pi"], arch["vf"]) if isinstance(arch, dict) else (arch, arch)
    refused["net_arch"] = pi != vf
    refused["activation_fn"] = kwargs.get("activation_fn", "tanh") not in ACTIVATIONS
    bad = [k for k, v in refused.items() if v]
    if bad:
        values = {k: params.get(k, kwargs.get(k)) for k in bad}
        raise ConfigError(
            f"--engine rllib: RLlib's PPO has no equivalent for {values}; change them with "
            "--config or train with --engine sb3"
        )


def ppo_config(
    params: dict[str, Any], env_id: str, seed: int, env_runners: int, ledger: str
) -> Any:
    """RLlib's ``PPOConfig`` from a checked hyperparameter entry (module docstring).

    Args:
        params: the entry (:func:`agents.training.load_hyperparams`, with ``--config`` and
            ``--timesteps`` applied).
        env_id: the registered id whose preset the env starts from.
        seed: the training seed (the torch initialisation and the ledger's seeds).
        env_runners: remote env runners (0: the driver samples).
        ledger: the name of the run's :class:`SeedLedger`.

    Raises:
        ConfigError: a setting RLlib's PPO has no equivalent for or refuses
            (:func:`check_params`).
    """
    check_params(params, env_runners)
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.connectors.env_to_module.mean_std_filter import MeanStdFilter
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
    from ray.tune.registry import register_env

    kwargs = params.get("policy_kwargs", {})
    arch = kwargs.get("net_arch", {"pi": [64, 64], "vf": [64, 64]})
    pi = arch["pi"] if isinstance(arch, dict) else arch
    register_env(ENV_NAME, make_env)
    frames = int(params.get("frame_stack", 1))
    n_envs, n_steps = int(params["n_envs"]), int(params.get("n_steps", 2048))
    lr = params.get("learning_rate", 3e-4)
    if isinstance(lr, str):  # lin_X: X at step 0 down to 0 at the budget
        lr = [[0, float(lr[4:])], [int(params["n_timesteps"]), 0.0]]

    def env_to_module(env: Any = None, spaces: Any = None, device: Any = None) -> list[Any]:
        pieces = [MeanStdFilter(clip_by_value=FILTER_CLIP)] if params.get("normalize") else []
        return pieces + ([_frame_stack_connector(frames, False)] if frames > 1 else [])

    def learner(obs_space: Any = None, act_space: Any = None) -> list[Any]:
        return [_frame_stack_connector(frames, True)] if frames > 1 else []

    return (
        PPOConfig()
        .environment(
            ENV_NAME,
            env_config={
                "env_id": env_id,
                "env_kwargs": jsonable(params.get("env_kwargs", {})),
                "env_mixture": jsonable(params.get("env_mixture", [])),
                "seed_ledger": ledger,
            },
        )
        .env_runners(
            num_env_runners=env_runners,
            num_envs_per_env_runner=n_envs,
            gym_env_vectorize_mode="vector_entry_point",
            rollout_fragment_length=n_steps,
            num_cpus_per_env_runner=1,
            episode_lookback_horizon=max(frames, 1),
            env_to_module_connector=env_to_module,
            # no timeout: a runner's first sample compiles the numba kernels (one to three
            # minutes where they are not cached), past which RLlib's 60 s would drop the samples
            sample_timeout_s=None,
        )
        .training(
            train_batch_size_per_learner=iteration_samples(params, env_runners),
            minibatch_size=int(params.get("batch_size", 64)),
            num_epochs=int(params.get("n_epochs", 10)),
            gamma=float(params.get("gamma", 0.99)),
            lambda_=float(params.get("gae_lambda", 0.95)),
            lr=lr,
            clip_param=float(params.get("clip_range", 0.2)),
            vf_clip_param=float("inf"),
            entropy_coeff=float(params.get("ent_coef", 0.0)),
            vf_loss_coeff=float(params.get("vf_coef", 0.5)),
            grad_clip=float(params.get("max_grad_norm", 0.5)),
            grad_clip_by="global_norm",
            use_kl_loss=False,
        )
        .rl_module(
            model_config=DefaultModelConfig(
                fcnet_hiddens=list(pi),
                fcnet_activation=ACTIVATIONS[kwargs.get("activation_fn", "tanh")],
                vf_share_layers=False,
                free_log_std=True,
                head_fcnet_hiddens=[],
            )
        )
        .callbacks(on_environment_created=assign_seeds)
        .learners(num_learners=0, learner_connector=learner)
        .debugging(seed=seed, log_level="ERROR")
    )


def set_log_std(algo: Any, value: float) -> None:
    """Set the policy's state-independent log standard deviation (SB3's ``log_std_init``) on the
    learner and push the weights to the env runners."""
    import torch

    def update(learner: Any) -> None:
        with torch.no_grad():
            for module in learner.module.values():
                module.pi.log_std.fill_(value)

    algo.learner_group.foreach_learner(update)
    algo.env_runner_group.sync_weights(from_worker_or_learner_group=algo.learner_group)


def not_ported(params: dict[str, Any]) -> dict[str, str]:
    """The hyperparameters of ``params`` set but not ported, with what is done instead."""
    set_ = {
        "critic_state": bool(params.get("critic_state")),
        "swa_start": params.get("swa_start") is not None,
        "normalize": bool(params.get("normalize")),
        "normalize_advantage": bool(params.get("normalize_advantage", True)),  # SB3's default
        "ortho_init": bool(params.get("policy_kwargs", {}).get("ortho_init", True)),
    }
    return {k: v for k, v in NOT_PORTED.items() if set_[k]}


def sb3_state(weights: dict[str, Any]) -> dict[str, Any]:
    """RLlib's default PPO module weights as the state dict of SB3's ``MlpPolicy``:
    ``encoder.actor_encoder.net.mlp.j`` -> ``mlp_extractor.policy_net.j``, the critic's likewise
    to ``value_net``, ``pi.net.mlp.0`` -> ``action_net``, ``pi.log_std`` -> ``log_std``,
    ``vf.net.mlp.0`` -> ``value_net``."""
    import torch

    prefixes = {
        "encoder.actor_encoder.net.mlp.": "mlp_extractor.policy_net.",
        "encoder.critic_encoder.net.mlp.": "mlp_extractor.value_net.",
        "pi.net.mlp.0.": "action_net.",
        "vf.net.mlp.0.": "value_net.",
    }
    out = {"log_std": torch.as_tensor(np.asarray(weights["pi.log_std"]))}
    for name, value in weights.items():
        for old, new in prefixes.items():
            if name.startswith(old):
                out[new + name[len(old) :]] = torch.as_tensor(np.asarray(value))
    return out


def normalizer_stats(algo: Any) -> dict[str, Any] | None:
    """The observation filter as ``vecnormalize.json`` (None without one): ``LearnedPolicy``'s
    ``(x - mean) / sqrt(var + epsilon)`` equals the filter's ``(x - mean) / (std + 1e-6)`` with
    ``epsilon = 1e-12`` and ``var = (std + 1e-6)^2 - 1e-12``."""
    from ray.rllib.connectors.env_to_module.mean_std_filter import MeanStdFilter

    pipeline = algo.env_runner_group.local_env_runner._env_to_module
    pieces = [p for p in pipeline.connectors if isinstance(p, MeanStdFilter)]
    if not pieces:
        return None
    stat = pieces[0]._filters[None].running_stats
    return filter_as_normalizer(stat.mean, stat.std, stat.n)


def filter_as_normalizer(mean: Any, std: Any, count: float) -> dict[str, Any]:
    """RLlib's running mean and standard deviation (float32) as ``vecnormalize.json``:
    ``var = (std + 1e-6)^2 - 1e-12``, floored at 0 (an entry that never varies, ``std = 0``,
    would otherwise round to about -5e-21, which the loader refuses)."""
    denominator = (np.asarray(std, dtype=np.float32) + np.float32(FILTER_SMALL)).astype(np.float64)
    return {
        "mean": np.asarray(mean, dtype=np.float64).tolist(),
        "var": np.maximum(denominator**2 - FILTER_SMALL**2, 0.0).tolist(),
        "count": float(count),
        "clip_obs": FILTER_CLIP,
        "epsilon": FILTER_SMALL**2,
    }


def export_agent(
    algo: Any,
    directory: Path,
    params: dict[str, Any],
    env_id: str,
    extra: dict[str, Any],
) -> None:
    """Write the trained policy in the project's agent format (module docstring).

    Args:
        algo: the RLlib PPO algorithm.
        directory: the agent directory (created).
        params: the hyperparameter entry it was trained with.
        env_id: the registered id; extra: more ``agent.json`` entries (seed, num_timesteps).
    """
    from agents.network import build_policy, policy_spec, save_weights
    from agents.policy import write_env_file
    from imm_gym.sim.actions import action_size
    from imm_gym.sim.env_config import EnvConfig
    from imm_gym.sim.features import observation_size

    env_kwargs = jsonable(params.get("env_kwargs", {}))
    config = EnvConfig.build({**PRESETS[env_id], **env_kwargs})
    M = len(config.bank)
    frames = int(params.get("frame_stack", 1))
    obs_size = observation_size(config.obs_features, M, config.sensor.dim_z)
    kwargs = params.get("policy_kwargs", {})
    arch = kwargs.get("net_arch", {"pi": [64, 64], "vf": [64, 64]})
    hidden = list(arch["pi"] if isinstance(arch, dict) else arch)
    spec = {
        "class": "MlpPolicy",
        "observation_size": frames * obs_size,
        "action_size": action_size(config.action_mode, M),
        "net_arch": {"pi": hidden, "vf": hidden},
        "activation_fn": kwargs.get("activation_fn", "tanh"),
        "log_std_init": float(kwargs.get("log_std_init", 0.0)),
        "ortho_init": False,
        "use_sde": False,
    }
    policy = build_policy(spec, f"{directory}: RLlib export")
    weights = algo.learner_group.get_weights()["default_policy"]
    policy.load_state_dict(sb3_state(weights))
    directory.mkdir(parents=True, exist_ok=True)
    save_weights(policy, directory)
    write_env_file(directory, env_kwargs)
    stats = normalizer_stats(algo)
    norm_file = directory / "vecnormalize.json"
    if stats is not None:
        norm_file.write_text(json.dumps(stats))
    elif norm_file.exists():
        norm_file.unlink()
    meta = {
        "algo": "ppo",
        "frame_stack": frames,
        "critic_dims": 0,
        "env_id": env_id,
        "normalize": stats is not None,  # the loader then requires vecnormalize.json exactly
        **extra,
        "policy": policy_spec(policy),
    }
    (directory / "agent.json").write_text(json.dumps(meta, indent=2))


#: Iterations in a row that sample nothing after which training stops (RLlib waits for samples
#: without a timeout: a slow first step compiles the kernels, but runners that keep failing
#: would otherwise train forever).
IDLE_ITERATIONS = 10


def env_steps(result: dict[str, Any], previous: int = 0) -> int:
    """Environment steps sampled so far, from a ``train()`` result; ``previous`` (the count
    before the iteration) where the result holds none, as after an iteration that sampled
    nothing (every remote runner failed: RLlib then reports no env runner metrics)."""
    from ray.rllib.utils.metrics import ENV_RUNNER_RESULTS, NUM_ENV_STEPS_SAMPLED_LIFETIME

    return int(result.get(ENV_RUNNER_RESULTS, {}).get(NUM_ENV_STEPS_SAMPLED_LIFETIME, previous))
