r"""A policy with one network shared by the bank's models: it reads and acts on a bank of any size.

An MLP over the whole observation reads model ``j``'s entries by their position, so it acts
only on banks of the size it was trained on. :class:`PerModelActorCriticPolicy`'s actor is a
permutation-equivariant set network (Zaheer et al., "Deep Sets", 2017): every model ``j`` has a
token :math:`x_j` — its entries of the ``F`` stacked frames (probabilities, likelihoods,
innovations, memories and ``model_turn_rate``, which says which model it is:
:func:`imm_gym.sim.model_order.frame_layout`) — and every model reads the entries of no model
:math:`g` (the target's turn rate, the stay bank's evidence, ...):

.. math::
    e_j = \phi([x_j, g]), \qquad
    h_j = \psi([e_j, \tfrac{1}{M}\textstyle\sum_i e_i]), \qquad
    a_j = w^\top h_j + b,

with :math:`\phi` the first layer of ``net_arch.pi``, :math:`\psi` the others, and one log
standard deviation for every model. The same weights act on 2, 3 or 5 models, in any order.
The value network is an MLP over the whole stacked observation with the critic's ground truth
(:mod:`agents.asymmetric`); it is trained with the actor and never acts, so an agent moved to a
bank of another size (:func:`refit_state`) keeps the actor's weights and the critic's of its
training are not used.

The observation normalizer of this policy shares one mean and variance per feature entry over
the models (:class:`TiedRunningMeanStd`), so that its statistics hold for a bank of any size too
(:func:`refit_normalizer`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.running_mean_std import RunningMeanStd
from torch import nn

from agents.asymmetric import mlp
from imm_gym.sim.core import critic_state_size
from imm_gym.sim.model_order import frame_layout
from imm_gym.validation import ConfigError

#: Entries of the critic's ground truth that are no model's (two 4-d errors); the rest is the
#: coming model, one-hot (:meth:`imm_gym.sim.core.TrackingCore.critic_state`).
CRITIC_SHARED = critic_state_size(0)
#: Prefixes of the critic's tensors in the policy's state: its MLP and its value head.
VALUE_SIDE = ("mlp_extractor.value_net.", "value_net.")


def frame_groups(
    features: Sequence[str], n_models: int, dim_z: int, critic: bool
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """:func:`~imm_gym.sim.model_order.frame_layout` of one frame, with the critic's ground
    truth appended when ``critic``: its errors among the shared entries, its one-hot coming model
    as one more per-model column."""
    try:
        per_model, shared = frame_layout(features, n_models, dim_z)
    except (KeyError, ValueError) as err:
        raise ConfigError(f"a PerModelPolicy cannot read obs_features: {err}") from None
    if critic:
        size = per_model.size + shared.size
        shared = np.concatenate([shared, size + np.arange(CRITIC_SHARED)])
        one_hot = size + CRITIC_SHARED + np.arange(n_models)
        per_model = np.concatenate([per_model, one_hot[:, None]], axis=1)
    return per_model, shared


def stacked_index(
    features: Sequence[str], n_models: int, dim_z: int, frame_stack: int, critic_dims: int
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The actor's inputs in a stacked observation of ``frame_stack`` frames (oldest first),
    each the observation and ``critic_dims`` entries of ground truth the actor skips:
    ``(tokens (M, F p), shared (F g))``, frame-major."""
    per_model, shared = frame_groups(features, n_models, dim_z, critic=False)
    frame = per_model.size + shared.size + critic_dims
    offsets = frame * np.arange(frame_stack)
    tokens = (offsets[:, None, None] + per_model[None]).transpose(1, 0, 2).reshape(n_models, -1)
    return tokens, (offsets[:, None] + shared[None]).ravel()


def check_actor_layers(pi: Sequence[int]) -> None:
    """Refuse an actor of fewer than two layers: ``phi``'s and at least one of ``psi``'s."""
    if len(pi) < 2:
        raise ConfigError(f"net_arch.pi of a PerModelPolicy needs two layers or more, got {pi}")


class PerModelExtractor(nn.Module):
    """SB3's ``MlpExtractor`` contract: the actor's latent is ``(N, M, pi[-1])``, one row per
    model (:math:`h_j` of the module docstring); the critic's an MLP over all the features."""

    def __init__(
        self,
        feature_dim: int,
        tokens: NDArray[np.intp],
        shared: NDArray[np.intp],
        pi: Sequence[int],
        vf: Sequence[int],
        activation_fn: type[nn.Module],
    ) -> None:
        super().__init__()
        check_actor_layers(pi)
        self.register_buffer("tokens", torch.as_tensor(tokens, dtype=torch.long), persistent=False)
        self.register_buffer("shared", torch.as_tensor(shared, dtype=torch.long), persistent=False)
        self.phi = mlp([tokens.shape[1] + shared.size, pi[0]], activation_fn)
        self.psi = mlp([2 * pi[0], *pi[1:]], activation_fn)
        self.value_net = mlp([feature_dim, *vf], activation_fn)
        self.latent_dim_pi = pi[-1]
        self.latent_dim_vf = vf[-1] if vf else feature_dim

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        tokens = features[:, self.tokens]  # (N, M, F p)
        shared = features[:, self.shared].unsqueeze(1).expand(-1, tokens.shape[1], -1)
        e = self.phi(torch.cat([tokens, shared], dim=-1))
        context = e.mean(dim=1, keepdim=True).expand_as(e)
        return self.psi(torch.cat([e, context], dim=-1))

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.value_net(features)


class PerModelHead(nn.Module):
    """The action of every model from its latent row: :math:`a_j = w^\\top h_j + b`."""

    def __init__(self, latent_dim: int) -> None:
        super().__init__()
        self.linear = nn.Linear(latent_dim, 1)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        return self.linear(latent).squeeze(-1)


class PerModelActorCriticPolicy(ActorCriticPolicy):
    """PPO's actor-critic with the actor shared by the models (module docstring); one action
    entry per model (the stay modes), one log standard deviation for all.

    Args:
        obs_features: the environment's ``obs_features`` (the layout of a frame).
        dim_z: the measurement's dimension (the innovation's entries per model).
        frame_stack: frames per observation.
        critic_dims: ground-truth entries at the end of each frame that only the critic reads
            (0 or :func:`~imm_gym.sim.core.critic_state_size` of the bank).
    """

    def __init__(
        self,
        *args: Any,
        obs_features: Sequence[str] = (),
        dim_z: int = 2,
        frame_stack: int = 1,
        critic_dims: int = 0,
        **kwargs: Any,
    ) -> None:
        self.obs_features, self.dim_z = list(obs_features), dim_z
        self.frame_stack, self.critic_dims = frame_stack, critic_dims
        super().__init__(*args, **kwargs)

    @property
    def n_models(self) -> int:
        return int(self.action_space.shape[0])

    def _build_mlp_extractor(self) -> None:
        M = self.n_models
        if self.critic_dims not in (0, critic_state_size(M)):
            raise ConfigError(
                f"critic_dims must be 0 or {critic_state_size(M)} for {M} models, "
                f"got {self.critic_dims}"
            )
        tokens, shared = stacked_index(
            self.obs_features, M, self.dim_z, self.frame_stack, self.critic_dims
        )
        expected = self.frame_stack * (
            (tokens.size + shared.size) // self.frame_stack + self.critic_dims
        )
        if expected != self.features_dim:
            raise ConfigError(
                f"a PerModelPolicy of {M} models reads {expected} entries "
                f"({self.frame_stack} frames of obs_features {self.obs_features}), the "
                f"observation has {self.features_dim}"
            )
        arch = self.net_arch
        pi, vf = (arch["pi"], arch["vf"]) if isinstance(arch, dict) else (arch, arch)
        self.mlp_extractor = PerModelExtractor(
            self.features_dim, tokens, shared, list(pi), list(vf), self.activation_fn
        ).to(self.device)

    def _build(self, lr_schedule: Any) -> None:
        """SB3's networks, then the action head and log standard deviation shared by the models
        in place of the per-entry ones, and the optimizer over them."""
        super()._build(lr_schedule)
        self.action_net = PerModelHead(self.mlp_extractor.latent_dim_pi).to(self.device)
        if self.ortho_init:
            self.action_net.apply(lambda m: self.init_weights(m, gain=0.01))
        self.log_std = nn.Parameter(torch.full((1,), float(self.log_std_init)))
        self.optimizer = self.optimizer_class(
            self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs
        )

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            obs_features=self.obs_features,
            dim_z=self.dim_z,
            frame_stack=self.frame_stack,
            critic_dims=self.critic_dims,
        )
        return data


class TiedRunningMeanStd(RunningMeanStd):
    """A running mean and variance of one observation frame with one statistic per feature entry
    over the models: after each update, the entries of a column of ``per_model`` (the same entry
    of every model) get the statistics of their pooled samples,

    .. math::
        \\bar\\mu = \\tfrac{1}{M}\\textstyle\\sum_j \\mu_j, \\qquad
        \\bar\\sigma^2 = \\tfrac{1}{M}\\textstyle\\sum_j (\\sigma_j^2 + \\mu_j^2) - \\bar\\mu^2

    (every entry has seen as many samples), so that they hold for any number of models."""

    def __init__(self, per_model: NDArray[np.intp], shape: tuple[int, ...]) -> None:
        super().__init__(shape=shape)
        self.per_model = per_model

    def update(self, arr: NDArray[np.float64]) -> None:
        super().update(arr)
        self.mean, self.var = tie(self.mean, self.var, self.per_model)


def tie(
    mean: NDArray[np.float64], var: NDArray[np.float64], per_model: NDArray[np.intp]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``mean``, ``var`` with each column of ``per_model`` given its pooled statistics
    (:class:`TiedRunningMeanStd`)."""
    mean, var = mean.copy(), var.copy()
    m = mean[per_model].mean(axis=0)
    second = (var[per_model] + mean[per_model] ** 2).mean(axis=0)
    mean[per_model] = m
    var[per_model] = np.maximum(second - m**2, 0.0)
    return mean, var


def refit_normalizer(
    mean: NDArray[np.float64],
    var: NDArray[np.float64],
    features: Sequence[str],
    dim_z: int,
    trained_models: int,
    n_models: int,
    critic: bool,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Tied statistics of a frame of ``trained_models`` models carried to a frame of
    ``n_models``: each model of the new frame gets the trained column's statistics, each shared
    entry its own.

    Raises:
        ConfigError: the statistics are not tied over the models (an agent whose normalizer is
            not :class:`TiedRunningMeanStd`'s).
    """
    old_models, old_shared = frame_groups(features, trained_models, dim_z, critic)
    if not (np.allclose(mean[old_models], mean[old_models[:1]])
            and np.allclose(var[old_models], var[old_models[:1]])):
        raise ConfigError("the normalizer's statistics are not shared by the models")
    new_models, new_shared = frame_groups(features, n_models, dim_z, critic)
    size = new_models.size + new_shared.size
    new_mean, new_var = np.zeros(size), np.ones(size)
    new_mean[new_models] = mean[old_models[0]][None, :]
    new_var[new_models] = var[old_models[0]][None, :]
    new_mean[new_shared], new_var[new_shared] = mean[old_shared], var[old_shared]
    return new_mean, new_var


def refit_state(
    state: dict[str, torch.Tensor], target: dict[str, torch.Tensor]
) -> dict[str, torch.Tensor]:
    """``state`` (a trained PerModelPolicy's) for a network of another number of models with
    state ``target``: every tensor whose shape does not depend on the number of models carried
    over (the actor's all), the value side's others kept at ``target``'s, unused: the critic
    never acts. Those read the whole observation: the value network's first layer, or with
    ``net_arch.vf`` empty the value head."""
    out = {}
    for name, tensor in target.items():
        if state[name].shape == tensor.shape:
            out[name] = state[name]
        elif name.startswith(VALUE_SIDE):
            out[name] = tensor
        else:
            raise ConfigError(f"tensor {name!r} depends on the number of models")
    return out
