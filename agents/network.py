"""The policy network as data: described in JSON, its tensors in safetensors, nothing unpickled.

A network is rebuilt (:func:`build_policy`) from a description checked by
:func:`agents.schema.check_spec` — the policy class by name from :data:`POLICY_CLASSES`, the
activation by name, sizes as integers, flags as booleans — and its weights are read with
``safetensors`` (a header of names, dtypes and shapes, then raw numbers: reading it cannot run
code), the header compared with the described network's tensors before the network is built
(:func:`check_weights_size`, :func:`expected_tensors`) and with the built network before any
number is read (:func:`load_tensors`). :func:`policy_spec` writes the description of a live
policy.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor
from torch import nn

from agents.asymmetric import AsymmetricActorCriticPolicy
from agents.per_model import PerModelActorCriticPolicy, check_actor_layers, stacked_index
from agents.schema import ACTIVATIONS, SDE_KEYS
from imm_gym.validation import ConfigError

#: The ``nn.Module`` class of each activation name of :data:`agents.schema.ACTIVATIONS`.
ACTIVATION_CLASSES: dict[str, type[nn.Module]] = {
    name: getattr(nn, cls) for name, cls in ACTIVATIONS.items()
}


def _recurrent_policy() -> type[ActorCriticPolicy]:
    from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy

    return RecurrentActorCriticPolicy


#: Policy classes by the name an agent records (sb3-contrib imported only for a recurrent one).
POLICY_CLASSES: dict[str, Callable[[], type[ActorCriticPolicy]]] = {
    "MlpPolicy": lambda: ActorCriticPolicy,
    "AsymmetricMlpPolicy": lambda: AsymmetricActorCriticPolicy,
    "PerModelPolicy": lambda: PerModelActorCriticPolicy,
    "MlpLstmPolicy": _recurrent_policy,
}

#: File of an agent's network weights.
WEIGHTS = "policy.safetensors"


def sb3_policy_kwargs(kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """Checked ``policy_kwargs`` as SB3 takes them: ``activation_fn`` the ``nn.Module`` class."""
    out = dict(kwargs)
    if "activation_fn" in out:
        out["activation_fn"] = ACTIVATION_CLASSES[out["activation_fn"]]
    return out


def policy_spec(policy: ActorCriticPolicy) -> dict[str, Any]:
    """The JSON description of a live SB3 policy from which :func:`build_policy` rebuilds it.

    Raises:
        ValueError: the policy is not one of :data:`POLICY_CLASSES` with a flat Box observation,
            a Box(-1, 1) action, the flatten feature extractor and an activation of
            :data:`ACTIVATION_CLASSES` — it could not be described as data.
    """
    names = {factory(): name for name, factory in POLICY_CLASSES.items()}
    name = names.get(type(policy))
    activation = {cls: key for key, cls in ACTIVATION_CLASSES.items()}.get(policy.activation_fn)
    obs_space, act_space = policy.observation_space, policy.action_space
    describable = (
        name is not None
        and activation is not None
        and isinstance(obs_space, spaces.Box)
        and len(obs_space.shape) == 1
        and isinstance(act_space, spaces.Box)
        and len(act_space.shape) == 1
        and np.all(act_space.low == -1.0)
        and np.all(act_space.high == 1.0)
        and policy.features_extractor_class is FlattenExtractor
        and not policy.features_extractor_kwargs
        and not getattr(policy, "lstm_kwargs", None)
    )
    if not describable:
        raise ValueError(f"a {type(policy).__name__} of this configuration cannot be saved as data")
    net_arch = policy.net_arch
    spec: dict[str, Any] = {
        "class": name,
        "observation_size": int(obs_space.shape[0]),
        "action_size": int(act_space.shape[0]),
        "net_arch": dict(net_arch) if isinstance(net_arch, dict) else list(net_arch),
        "activation_fn": activation,
        "log_std_init": float(policy.log_std_init),
        "ortho_init": bool(policy.ortho_init),
        "share_features_extractor": bool(policy.share_features_extractor),
        "use_sde": bool(policy.use_sde),
    }
    if policy.use_sde:
        spec.update({k: bool(policy.dist_kwargs[k]) for k in SDE_KEYS})
    if name == "AsymmetricMlpPolicy":
        spec.update(critic_dims=policy.critic_dims, frame_stack=policy.frame_stack)
    if name == "PerModelPolicy":
        spec.update(
            critic_dims=policy.critic_dims,
            frame_stack=policy.frame_stack,
            obs_features=list(policy.obs_features),
            dim_z=policy.dim_z,
        )
    if name == "MlpLstmPolicy":
        spec.update(
            lstm_hidden_size=policy.lstm_actor.hidden_size,
            n_lstm_layers=policy.lstm_actor.num_layers,
            shared_lstm=bool(policy.shared_lstm),
            enable_critic_lstm=bool(policy.enable_critic_lstm),
        )
    return spec


def build_policy(spec: dict[str, Any], where: str) -> ActorCriticPolicy:
    """A freshly initialized policy network from a description checked by :func:`check_spec`.

    Raises:
        ConfigError: SB3 refuses the combination of settings (the message names ``where``).
    """
    kwargs = {
        k: v for k, v in spec.items() if k not in ("class", "observation_size", "action_size")
    }
    obs = spaces.Box(-np.inf, np.inf, (spec["observation_size"],), np.float32)
    act = spaces.Box(-1.0, 1.0, (spec["action_size"],), np.float32)
    try:
        return POLICY_CLASSES[spec["class"]]()(obs, act, _no_schedule, **sb3_policy_kwargs(kwargs))
    except (AssertionError, TypeError, ValueError, RuntimeError) as err:
        raise ConfigError(f"{where}: SB3 cannot build this network ({err})") from None


def parameter_count(spec: dict[str, Any]) -> int:
    """The numbers (float32 parameters) of the network :func:`build_policy` builds from the
    checked description ``spec``, computed without building it (its weights file holds at
    least four bytes each).

    Linear layers ``n_in -> n_out`` hold ``(n_in + 1) n_out``; an LSTM layer of ``H`` units
    over ``n_in`` inputs ``4 H (n_in + H) + 8 H``; SB3's heads an action layer, a value layer
    and the log standard deviations (``latent x actions`` with gSDE's ``full_std``).
    """
    obs, actions = spec["observation_size"], spec["action_size"]
    arch = spec.get("net_arch", {"pi": [64, 64], "vf": [64, 64]})
    pi, vf = (arch["pi"], arch["vf"]) if isinstance(arch, dict) else (arch, arch)
    name = spec["class"]

    def mlp(sizes: list[int]) -> int:
        return sum((n_in + 1) * n_out for n_in, n_out in pairwise(sizes))

    def lstm(n_in: int, hidden: int, layers: int) -> int:
        return sum(4 * hidden * (n + hidden) + 8 * hidden for n in [n_in, *[hidden] * (layers - 1)])

    features = obs
    count = 0
    if name == "MlpLstmPolicy":
        hidden, layers = spec.get("lstm_hidden_size", 256), spec.get("n_lstm_layers", 1)
        count += lstm(obs, hidden, layers)
        if spec.get("enable_critic_lstm", True):
            count += lstm(obs, hidden, layers)
        elif not spec.get("shared_lstm", False):
            count += mlp([obs, hidden])
        features = hidden
    actor_in = features
    if name == "AsymmetricMlpPolicy":
        actor_in = obs - spec["frame_stack"] * spec["critic_dims"]
    latent_pi = pi[-1] if pi else actor_in
    latent_vf = vf[-1] if vf else features
    count += mlp([features, *vf]) + mlp([latent_vf, 1])
    if name == "PerModelPolicy":
        check_actor_layers(pi)
        # phi reads a model's entries with the shared ones, psi each model's embedding with
        # their mean; one action layer and one log std for every model
        try:
            tokens, shared = stacked_index(
                spec["obs_features"], actions, spec["dim_z"], spec["frame_stack"],
                spec["critic_dims"],
            )
            token = tokens.shape[1] + shared.size
        except (KeyError, ValueError):  # a layout build_policy refuses
            token = 1
        return count + mlp([token, pi[0]]) + mlp([2 * pi[0], *pi[1:]]) + mlp([latent_pi, 1]) + 1
    count += mlp([actor_in, *pi]) + mlp([latent_pi, actions])
    if spec.get("use_sde", False):
        return count + latent_pi * (actions if spec.get("full_std", True) else 1)
    return count + actions


def expected_tensors(spec: dict[str, Any]) -> dict[str, torch.Tensor]:
    """The state dict of the network :func:`build_policy` builds from the checked description
    ``spec`` as meta tensors (names, dtypes and shapes; no numbers), computed without building
    it: SB3's ``mlp_extractor.policy_net``/``value_net`` (``Linear`` layers at even indices,
    activations between), ``action_net``, ``value_net`` and ``log_std`` (``latent x actions``,
    or ``latent x 1`` without ``full_std``, with gSDE); the asymmetric actor's input index
    (:mod:`agents.asymmetric`); the per-model ``phi``, ``psi`` and shared action layer
    (:mod:`agents.per_model`); sb3-contrib's ``lstm_actor`` and ``lstm_critic`` (or the
    ``critic`` layer of a critic without LSTM that does not share the actor's). The same layout
    :func:`parameter_count` counts.
    """
    obs, actions = spec["observation_size"], spec["action_size"]
    arch = spec.get("net_arch", {"pi": [64, 64], "vf": [64, 64]})
    pi, vf = (arch["pi"], arch["vf"]) if isinstance(arch, dict) else (arch, arch)
    name = spec["class"]
    shapes: dict[str, tuple[torch.dtype, tuple[int, ...]]] = {}

    def linear(prefix: str, n_in: int, n_out: int) -> None:
        shapes[f"{prefix}.weight"] = (torch.float32, (n_out, n_in))
        shapes[f"{prefix}.bias"] = (torch.float32, (n_out,))

    def mlp(prefix: str, sizes: list[int]) -> None:
        for i, (n_in, n_out) in enumerate(pairwise(sizes)):
            linear(f"{prefix}.{2 * i}", n_in, n_out)

    def lstm(prefix: str, n_in: int, hidden: int, layers: int) -> None:
        for k, n in enumerate([n_in, *[hidden] * (layers - 1)]):
            for kind, width in (("ih", n), ("hh", hidden)):
                shapes[f"{prefix}.weight_{kind}_l{k}"] = (torch.float32, (4 * hidden, width))
                shapes[f"{prefix}.bias_{kind}_l{k}"] = (torch.float32, (4 * hidden,))

    features = obs
    if name == "MlpLstmPolicy":
        hidden, layers = spec.get("lstm_hidden_size", 256), spec.get("n_lstm_layers", 1)
        lstm("lstm_actor", obs, hidden, layers)
        if spec.get("enable_critic_lstm", True):
            lstm("lstm_critic", obs, hidden, layers)
        elif not spec.get("shared_lstm", False):
            linear("critic", obs, hidden)
        features = hidden
    actor_in = features
    if name == "AsymmetricMlpPolicy":
        actor_in = obs - spec["frame_stack"] * spec["critic_dims"]
        shapes["mlp_extractor.index"] = (torch.int64, (actor_in,))
    latent_pi = pi[-1] if pi else actor_in
    latent_vf = vf[-1] if vf else features
    mlp("mlp_extractor.value_net", [features, *vf])
    linear("value_net", latent_vf, 1)
    if name == "PerModelPolicy":
        check_actor_layers(pi)
        try:  # as parameter_count: a layout build_policy refuses reads one entry
            tokens, shared = stacked_index(
                spec["obs_features"], actions, spec["dim_z"], spec["frame_stack"],
                spec["critic_dims"],
            )
            token = tokens.shape[1] + shared.size
        except (KeyError, ValueError):
            token = 1
        mlp("mlp_extractor.phi", [token, pi[0]])
        mlp("mlp_extractor.psi", [2 * pi[0], *pi[1:]])
        linear("action_net.linear", latent_pi, 1)
        shapes["log_std"] = (torch.float32, (1,))
    else:
        mlp("mlp_extractor.policy_net", [actor_in, *pi])
        linear("action_net", latent_pi, actions)
        sde = spec.get("use_sde", False)
        std = actions if spec.get("full_std", True) else 1
        shapes["log_std"] = (torch.float32, (latent_pi, std) if sde else (actions,))
    return {
        key: torch.empty(shape, dtype=dtype, device="meta")
        for key, (dtype, shape) in shapes.items()
    }


def check_weights_size(spec: dict[str, Any], directory: Path) -> None:
    """Refuse, before the network is built, a ``directory/policy.safetensors`` that is not a
    safetensors file, holds fewer bytes than the :func:`parameter_count` float32 numbers of the
    described network, or whose header declares other tensors than the network's
    (:func:`expected_tensors`: a name missing or unexpected, another dtype or shape), the
    header read, not its tensors: building a network the file does not hold would allocate what
    no file asked for (a description within the bounds of :mod:`agents.schema` may describe
    gigabytes, and a sparse file may pad its few real tensors with a gigabyte-tensor hole).

    Raises:
        ConfigError: the file is missing, not a regular file, not safetensors, too small, or
            declares tensors that do not fit; the message names it.
    """
    file = directory / WEIGHTS
    check_regular_file(file)
    try:
        with safe_open(str(file), framework="pt") as f:
            declared = _declared_tensors(file, f)
    except ConfigError:
        raise
    except (SafetensorError, OSError, ValueError, RuntimeError) as err:
        raise ConfigError(f"{file}: not a readable safetensors file ({err})") from None
    count = parameter_count(spec)
    size = file.stat().st_size
    if size < 4 * count:
        raise ConfigError(
            f"{file}: {size} bytes, fewer than the {4 * count} of the {count} float32 "
            "parameters of the network agent.json describes"
        )
    check_declared(file, declared, expected_tensors(spec), "the network of agent.json")


def check_regular_file(file: Path) -> None:
    """Refuse a ``file`` that is missing or not a regular file (a directory, a device such as
    ``/dev/zero``, a FIFO), a link to one included.

    Raises:
        ConfigError: naming the file and which of the two it is.
    """
    if not file.is_file():
        raise ConfigError(f"{file}: {'not a regular file' if file.exists() else 'missing'}")


def _no_schedule(progress_remaining: float) -> float:
    """The learning rate of a policy that only acts: never used."""
    del progress_remaining
    return 0.0


def save_tensors(file: Path, tensors: Mapping[str, torch.Tensor], **metadata: str) -> None:
    """Write named tensors (copied: safetensors refuses shared storage) to ``file``."""
    save_file(
        {k: v.detach().clone().contiguous() for k, v in tensors.items()},
        str(file),
        metadata=metadata or None,
    )


#: The dtypes a tensor file may hold (each reader then asks for its own): the usual floats and
#: integers, not the float8 or complex ones, whose numbers cannot be checked.
TENSOR_DTYPES = (
    torch.float16,
    torch.bfloat16,
    torch.float32,
    torch.float64,
    torch.uint8,
    torch.int8,
    torch.int16,
    torch.int32,
    torch.int64,
    torch.bool,
)
#: safetensors' names of the dtypes of :data:`TENSOR_DTYPES` and of the float8 ones (which a
#: message names as torch does); a name outside them is refused as it is spelt.
SAFETENSORS_DTYPES = {
    "F16": torch.float16,
    "BF16": torch.bfloat16,
    "F32": torch.float32,
    "F64": torch.float64,
    "U8": torch.uint8,
    "I8": torch.int8,
    "I16": torch.int16,
    "I32": torch.int32,
    "I64": torch.int64,
    "BOOL": torch.bool,
    "F8_E4M3": torch.float8_e4m3fn,
    "F8_E5M2": torch.float8_e5m2,
}


def load_tensors(
    file: Path, check: Callable[[dict[str, torch.Tensor]], None]
) -> dict[str, torch.Tensor]:
    """Named tensors from a safetensors ``file``, each of :data:`TENSOR_DTYPES`, every floating
    one finite, read only after ``check`` has accepted what the file's header declares.

    ``check`` is given the declared tensors as meta tensors (name, dtype and shape; torch's
    ``meta`` device holds no numbers) and raises on any the caller does not expect, so a file
    that declares other tensors (an extra one of gigabytes, say, in a sparse file) is refused
    before any of its tensors is read or allocated.

    Raises:
        ConfigError: the file is missing, not a regular file, truncated or not safetensors,
            declares a tensor of another dtype, holds NaN/inf, or ``check`` refuses it.
    """
    check_regular_file(file)
    try:
        with safe_open(str(file), framework="pt") as f:
            declared = _declared_tensors(file, f)
            check(declared)
            tensors = {name: f.get_tensor(name) for name in declared}
    except ConfigError:
        raise
    except (SafetensorError, OSError, ValueError, RuntimeError) as err:
        raise ConfigError(f"{file}: not a readable safetensors file ({err})") from None
    for name, tensor in tensors.items():
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise ConfigError(f"{file}: tensor {name!r} holds NaN or infinite values")
    return tensors


def _declared_tensors(file: Path, f: Any) -> dict[str, torch.Tensor]:
    """The tensors the header of ``file`` (open as ``f`` by ``safe_open``) declares, as meta
    tensors, each of :data:`TENSOR_DTYPES` (a ConfigError naming ``file`` otherwise)."""
    declared = {}
    for name in f.keys():
        view = f.get_slice(name)
        dtype = SAFETENSORS_DTYPES.get(view.get_dtype())
        if dtype not in TENSOR_DTYPES:
            raise ConfigError(
                f"{file}: tensor {name!r} is {dtype or view.get_dtype()}, not one of "
                f"{[str(dtype) for dtype in TENSOR_DTYPES]}"
            )
        declared[name] = torch.empty(view.get_shape(), dtype=dtype, device="meta")
    return declared


def check_declared(
    file: Path, declared: Mapping[str, torch.Tensor], expected: Mapping[str, torch.Tensor],
    what: str,
) -> None:
    """Refuse tensors ``declared`` (meta tensors of :func:`load_tensors`, or read ones) whose
    names are not those of ``expected`` or one of which has another dtype or shape; ``what``
    names what they should fit in the message.

    Raises:
        ConfigError: naming ``file``, the missing and unexpected names, or the tensor of
            another dtype or shape and the one ``what`` needs.
    """
    missing = sorted(set(expected) - set(declared))
    unexpected = sorted(set(declared) - set(expected))
    if missing or unexpected:
        raise ConfigError(
            f"{file}: the tensors do not fit {what} (missing {missing}, unexpected {unexpected})"
        )
    for name, tensor in declared.items():
        if tensor.shape != expected[name].shape or tensor.dtype != expected[name].dtype:
            raise ConfigError(
                f"{file}: tensor {name!r} is {tensor.dtype} {tuple(tensor.shape)}, {what} "
                f"needs {expected[name].dtype} {tuple(expected[name].shape)}"
            )


def save_weights(policy: nn.Module, directory: Path) -> None:
    """``directory/policy.safetensors``: the policy's state dict."""
    save_tensors(directory / WEIGHTS, policy.state_dict())


def load_weights(policy: nn.Module, directory: Path) -> None:
    """Load ``directory/policy.safetensors`` into ``policy`` (every tensor, exact shapes; an
    integer buffer must equal the network's own), its names, dtypes and shapes compared with
    the network's from the file's header before any tensor is read (:func:`load_tensors`).

    Raises:
        ConfigError: the file is unreadable, or its tensors do not fit the network.
    """
    file = directory / WEIGHTS
    expected = policy.state_dict()
    what = "the network of agent.json"
    state = load_tensors(file, lambda declared: check_declared(file, declared, expected, what))
    for name, tensor in state.items():
        # an integer buffer (the actor's input index) is not learned: agent.json fixes it
        if not tensor.is_floating_point() and not torch.equal(tensor, expected[name]):
            raise ConfigError(
                f"{file}: tensor {name!r} is not the one the network of agent.json defines "
                "(it is set by the network's description, not learned)"
            )
    policy.load_state_dict(state)
