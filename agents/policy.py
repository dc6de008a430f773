"""A trained agent as a policy with the ``predict`` protocol of the evaluation tool.

A trained agent is a directory (a "run" or the shipped ``pretrained/``) holding

* ``model.zip`` — the stable-baselines3 model (PPO or RecurrentPPO), needed to resume training,
  and ``policy.pt`` — the policy network alone (no optimizer state: a third of the size), enough
  to act;
* ``env.json`` — the environment overrides it was trained with (action mode, features...);
* ``vecnormalize.json`` — the observation normalizer's running mean/variance (optional);
* ``agent.json`` — the algorithm name and the frame-stack depth.

:class:`LearnedPolicy` applies the normalizer and then the frame stack itself (the order of
SB3's ``VecFrameStack(VecNormalize(env))``), so a model runs through
:func:`imm_gym.evaluation.rollout.rollout` like any baseline.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

ALGOS = ("ppo", "recurrent-ppo")


class LearnedPolicy:
    """Wraps an SB3 model with its observation normalizer and frame stack.

    Args:
        model: a loaded SB3 model.
        env_overrides: the :class:`~imm_gym.EnvConfig` fields it was trained with.
        obs_mean, obs_var: the normalizer's statistics of one observation, or None.
        clip_obs, epsilon: the normalizer's clipping and epsilon.
        frame_stack: number of consecutive observations the model sees.
        recurrent: whether the model keeps an LSTM state.
        critic_dims: entries of each frame that only its critic reads (ground truth in
            training, :mod:`agents.asymmetric`); they are zeros here, which the actor ignores.
    """

    name = "learned"

    def __init__(
        self,
        model: Any,
        env_overrides: dict[str, Any],
        obs_mean: NDArray[np.float64] | None = None,
        obs_var: NDArray[np.float64] | None = None,
        clip_obs: float = 10.0,
        epsilon: float = 1e-8,
        frame_stack: int = 1,
        recurrent: bool = False,
        critic_dims: int = 0,
    ) -> None:
        self.model = model
        self.env_overrides = env_overrides
        self.obs_mean, self.obs_var = obs_mean, obs_var
        self.clip_obs, self.epsilon = clip_obs, epsilon
        self.frame_stack = frame_stack
        self.recurrent = recurrent
        self.critic_dims = critic_dims

    def normalize(self, obs: NDArray[Any]) -> NDArray[np.float32]:
        if self.obs_mean is None or self.obs_var is None:
            return obs.astype(np.float32)
        z = (obs - self.obs_mean) / np.sqrt(self.obs_var + self.epsilon)
        return np.clip(z, -self.clip_obs, self.clip_obs).astype(np.float32)

    def predict(
        self,
        observation: NDArray[Any],
        state: Any = None,
        episode_start: NDArray[np.bool_] | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray[Any], Any]:
        obs = np.asarray(observation, dtype=np.float64)
        single = obs.ndim == 1
        obs = obs[None] if single else obs
        if self.critic_dims:
            obs = np.concatenate([obs, np.zeros((obs.shape[0], self.critic_dims))], axis=-1)
        N, d = obs.shape
        start = np.ones(N, bool) if episode_start is None else np.asarray(episode_start, bool)
        stack, lstm = (None, None) if state is None else state
        x = self.normalize(obs)
        if stack is None:
            stack = np.zeros((N, self.frame_stack, d), dtype=np.float32)
        # as SB3's VecFrameStack over VecNormalize: normalized frames, oldest first, zeros
        # before the first frame of an episode
        stack = np.roll(stack, -1, axis=1)
        stack[start] = 0.0
        stack[:, -1] = x
        x = stack.reshape(N, -1)
        if self.recurrent:
            actions, lstm = self.model.predict(
                x, state=lstm, episode_start=start, deterministic=deterministic
            )
        else:
            actions, _ = self.model.predict(x, deterministic=deterministic)
        actions = np.clip(actions, -1.0, 1.0)
        return (actions[0] if single else actions), (stack, lstm)


def load_agent(path: str | Path) -> LearnedPolicy:
    """Load a trained agent from its directory (or from its ``model.zip``)."""
    path = Path(path)
    directory = path.parent if path.suffix in (".zip", ".pt") else path
    if not (directory / "agent.json").is_file():
        raise FileNotFoundError(f"no trained agent at {str(directory)!r} (agent.json missing)")
    meta = json.loads((directory / "agent.json").read_text())
    algo = meta.get("algo", "ppo")
    if algo == "recurrent-ppo":
        # sb3-contrib's recurrent policy does not save its LSTM size with the policy alone
        from sb3_contrib import RecurrentPPO

        model = RecurrentPPO.load(directory / "model.zip", device="cpu")
    else:
        from stable_baselines3.common.policies import ActorCriticPolicy

        policy_file = directory / "policy.pt"
        if not policy_file.is_file():
            raise FileNotFoundError(f"no trained agent at {str(directory)!r} (policy.pt missing)")
        policy_cls = ActorCriticPolicy
        if meta.get("critic_dims", 0):
            from agents.asymmetric import AsymmetricActorCriticPolicy

            policy_cls = AsymmetricActorCriticPolicy
        model = policy_cls.load(str(policy_file), device="cpu")
    env_overrides = json.loads((directory / "env.json").read_text())
    if "obs_features" in env_overrides:
        env_overrides["obs_features"] = tuple(env_overrides["obs_features"])
    norm_file = directory / "vecnormalize.json"
    mean = var = None
    clip_obs, eps = 10.0, 1e-8
    if norm_file.is_file():
        norm = json.loads(norm_file.read_text())
        mean, var = np.array(norm["mean"]), np.array(norm["var"])
        clip_obs, eps = norm["clip_obs"], norm["epsilon"]
    return LearnedPolicy(
        model,
        env_overrides,
        mean,
        var,
        clip_obs,
        eps,
        frame_stack=int(meta.get("frame_stack", 1)),
        recurrent=algo == "recurrent-ppo",
        critic_dims=int(meta.get("critic_dims", 0)),
    )
