"""Asymmetric actor-critic: a value network that also sees ground truth, an actor that does not.

The environment appends :meth:`imm_gym.sim.core.TrackingCore.critic_state` (each tracker's error and
the coming true model) to every observation frame when trained with ``critic_state: true``
(:class:`imm_gym.envs.sb3.TPMAdaptSB3VecEnv`). :class:`AsymmetricActorCriticPolicy` feeds the whole
stacked observation to the value network and only the first ``frame - critic_dims`` entries of
each frame to the policy network, so the actor's output does not depend on ground truth: at
evaluation those entries are zeros (:class:`agents.policy.LearnedPolicy`). The critic only
shapes the advantages ``A_t`` of PPO's policy gradient; a critic that knows how far each tracker
is off the target predicts the returns with less noise (Pinto et al., "Asymmetric Actor Critic
for Image-Based Robot Learning", 2017).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import pairwise
from typing import Any

import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from torch import nn


def actor_index(features: int, frame_stack: int, critic_dims: int) -> list[int]:
    """Positions of the actor's inputs in a stacked observation of ``frame_stack`` frames of
    ``features / frame_stack`` entries each, the last ``critic_dims`` of every frame excluded."""
    frame = features // frame_stack
    if frame * frame_stack != features or not 0 <= critic_dims < frame:
        raise ValueError(
            f"{features} features do not split into {frame_stack} frames with "
            f"{critic_dims} critic-only entries each"
        )
    return [f * frame + j for f in range(frame_stack) for j in range(frame - critic_dims)]


def mlp(sizes: Sequence[int], activation: type[nn.Module]) -> nn.Sequential:
    """Linear layers of ``sizes`` (input first), each followed by ``activation``."""
    layers: list[nn.Module] = []
    for n_in, n_out in pairwise(sizes):
        layers += [nn.Linear(n_in, n_out), activation()]
    return nn.Sequential(*layers)


class AsymmetricMlpExtractor(nn.Module):
    """SB3's ``MlpExtractor`` contract (``latent_dim_pi``/``_vf``, ``forward_actor``/``_critic``)
    with separate inputs: the policy network reads ``features[:, index]``, the value network all
    of ``features``."""

    def __init__(
        self,
        feature_dim: int,
        index: list[int],
        pi: list[int],
        vf: list[int],
        activation_fn: type[nn.Module],
    ) -> None:
        super().__init__()
        self.register_buffer("index", torch.as_tensor(index, dtype=torch.long))
        self.policy_net = mlp([len(index), *pi], activation_fn)
        self.value_net = mlp([feature_dim, *vf], activation_fn)
        self.latent_dim_pi = pi[-1] if pi else len(index)
        self.latent_dim_vf = vf[-1] if vf else feature_dim

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self.policy_net(features.index_select(1, self.index))

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.value_net(features)


class AsymmetricActorCriticPolicy(ActorCriticPolicy):
    """``MlpPolicy`` whose actor skips the last ``critic_dims`` entries of each of the
    ``frame_stack`` observation frames (``net_arch`` as ``dict(pi=[...], vf=[...])``)."""

    def __init__(self, *args: Any, critic_dims: int = 0, frame_stack: int = 1, **kwargs: Any):
        self.critic_dims, self.frame_stack = critic_dims, frame_stack
        super().__init__(*args, **kwargs)

    def _build_mlp_extractor(self) -> None:
        arch = self.net_arch
        pi, vf = (arch["pi"], arch["vf"]) if isinstance(arch, dict) else (arch, arch)
        index = actor_index(self.features_dim, self.frame_stack, self.critic_dims)
        self.mlp_extractor = AsymmetricMlpExtractor(
            self.features_dim, index, list(pi), list(vf), self.activation_fn
        ).to(self.device)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(critic_dims=self.critic_dims, frame_stack=self.frame_stack)
        return data
