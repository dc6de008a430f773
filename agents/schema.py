"""The vocabulary of the data files that describe training and agents: checked, never evaluated.

The ``policy_kwargs`` of a hyperparameter file (:func:`check_policy_kwargs`) and the network
description in an agent's ``agent.json`` (:func:`check_spec`) use the same allow-list: the policy
class by name (:data:`POLICY_CLASS_NAMES`), the activation by name (:data:`ACTIVATIONS`), layer
sizes as integers, flags as booleans. A name outside it is an error naming the file and the key,
never a lookup in a Python namespace. :mod:`agents.network` turns a checked description into a
network.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from imm_gym.validation import ConfigError, shown

#: Activations by name (the ``torch.nn`` class of each): the only ones a hyperparameter file or
#: an agent may ask for.
ACTIVATIONS = {
    "tanh": "Tanh",
    "relu": "ReLU",
    "elu": "ELU",
    "leaky_relu": "LeakyReLU",
    "silu": "SiLU",
    "gelu": "GELU",
}

#: The policy classes an agent may record (:data:`agents.network.POLICY_CLASSES`).
POLICY_CLASS_NAMES = ("MlpPolicy", "AsymmetricMlpPolicy", "PerModelPolicy", "MlpLstmPolicy")


def check_flag(where: str, value: Any) -> bool:
    """``value`` if it is a boolean (not 0/1, not a string); ``where`` names it."""
    if not isinstance(value, bool):
        raise ConfigError(f"{where} must be true or false, got {shown(value)}")
    return value


def check_size(where: str, value: Any) -> int:
    """``value`` if it is an integer >= 1 (not a float, a boolean or a string)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"{where} must be a positive integer, got {shown(value)}")
    return value


#: The widest layer and the deepest network a description may give. Within them a network can
#: still be gigabytes (eight LSTM layers of 4096 units for the actor and as many for the critic
#: are 2.1 G numbers, 8 GiB): the loader computes the network's size from its description and
#: refuses a weights file too small to hold it before building it
#: (:func:`agents.network.check_weights_size`), so a description read from a file makes it
#: allocate no more than that file holds.
MAX_WIDTH, MAX_LAYERS = 4096, 8
#: The largest input a description may give (frames times entries of a frame).
MAX_INPUT = 16384


def check_width(where: str, value: Any) -> int:
    """``value`` if it is a layer size: an integer in ``[1, MAX_WIDTH]``."""
    return _bounded(where, value, MAX_WIDTH)


def _depth(where: str, value: Any) -> int:
    return _bounded(where, value, MAX_LAYERS)


def _input_size(where: str, value: Any) -> int:
    return _bounded(where, value, MAX_INPUT)


def _bounded(where: str, value: Any, most: int) -> int:
    size = check_size(where, value)
    if size > most:
        raise ConfigError(f"{where} must be at most {most}, got {size}")
    return size


def check_count(where: str, value: Any) -> int:
    """``value`` if it is an integer >= 0 (not a float, a boolean or a string)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ConfigError(f"{where} must be a non-negative integer, got {shown(value)}")
    return value


def finite_number(value: Any) -> float | None:
    """``value`` as a float if it is an int or float (not a boolean or a string) within the
    finite floats (an integer such as ``10**400`` is beyond them), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None


def check_number(where: str, value: Any) -> float:
    """``value`` as a float if it is a finite int or float (not a boolean or a string)."""
    number = finite_number(value)
    if number is None:
        raise ConfigError(f"{where} must be a finite number, got {shown(value)}")
    return number


#: The largest ``|log_std_init|``: a standard deviation of ``e**20`` (or ``e**-20``) is no
#: exploration but overflow, the first update's weights NaN.
MAX_LOG_STD = 20.0


def _log_std(where: str, value: Any) -> float:
    """A finite ``log_std_init`` within ``[-MAX_LOG_STD, MAX_LOG_STD]``."""
    number = check_number(where, value)
    if abs(number) > MAX_LOG_STD:
        raise ConfigError(
            f"{where} must be in [{-MAX_LOG_STD:g}, {MAX_LOG_STD:g}], got {shown(value)}"
        )
    return number


def _activation(where: str, value: Any) -> str:
    if not isinstance(value, str) or value not in ACTIVATIONS:
        raise ConfigError(f"{where} must be one of {list(ACTIVATIONS)}, got {shown(value)}")
    return value


def _layers(where: str, value: Any) -> list[int]:
    if not isinstance(value, list) or len(value) > MAX_LAYERS:
        raise ConfigError(
            f"{where} must be a list of at most {MAX_LAYERS} layer sizes, got {shown(value)}"
        )
    return [check_width(f"{where}[{i}]", n) for i, n in enumerate(value)]


def _names(where: str, value: Any) -> list[str]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{where} must be a list of names, got {shown(value)}")
    return list(value)


def _net_arch(where: str, value: Any) -> list[int] | dict[str, list[int]]:
    """``[64, 64]`` (shared sizes) or ``{pi: [...], vf: [...]}`` (actor and critic)."""
    if isinstance(value, Mapping):
        if set(value) != {"pi", "vf"}:
            raise ConfigError(f"{where} must have the keys pi and vf, got {sorted(value)}")
        return {key: _layers(f"{where}.{key}", value[key]) for key in ("pi", "vf")}
    return _layers(where, value)


#: ``policy_kwargs`` a hyperparameter file may set, with their checks.
POLICY_KWARGS: dict[str, Callable[[str, Any], Any]] = {
    "net_arch": _net_arch,
    "activation_fn": _activation,
    "log_std_init": _log_std,
    "ortho_init": check_flag,
    "full_std": check_flag,
    "use_expln": check_flag,
    "squash_output": check_flag,
    "share_features_extractor": check_flag,
    "lstm_hidden_size": check_width,
    "n_lstm_layers": _depth,
    "shared_lstm": check_flag,
    "enable_critic_lstm": check_flag,
}

#: the recurrent policy's own keys, and those of the gSDE distribution
LSTM_KEYS = ("lstm_hidden_size", "n_lstm_layers", "shared_lstm", "enable_critic_lstm")
SDE_KEYS = ("full_std", "use_expln", "squash_output")

#: Entries of an agent's network description beyond :data:`POLICY_KWARGS`.
SPEC_FIELDS: dict[str, Callable[[str, Any], Any]] = {
    "observation_size": _input_size,
    "action_size": check_size,
    "use_sde": check_flag,
    "critic_dims": check_count,
    "frame_stack": check_size,
    "obs_features": _names,
    "dim_z": check_size,
}

#: description keys of every policy class, and those of one class only
_COMMON_KEYS = (
    *(k for k in POLICY_KWARGS if k not in LSTM_KEYS),
    "observation_size",
    "action_size",
    "use_sde",
)
_CLASS_KEYS = {
    "MlpPolicy": (),
    "AsymmetricMlpPolicy": ("critic_dims", "frame_stack"),
    "PerModelPolicy": ("critic_dims", "frame_stack", "obs_features", "dim_z"),
    "MlpLstmPolicy": LSTM_KEYS,
}


def check_policy_kwargs(where: str, value: Any, recurrent: bool) -> dict[str, Any]:
    """The ``policy_kwargs`` of a hyperparameter entry, checked; still data (activation by name).

    Args:
        where: the file and entry, for the messages.
        value: a mapping of :data:`POLICY_KWARGS` keys, e.g. ``{net_arch: {pi: [128, 128],
            vf: [128, 128]}, activation_fn: tanh, log_std_init: -1.0}``.
        recurrent: whether the policy is RecurrentPPO's (the LSTM keys are its only).

    Raises:
        ConfigError: ``value`` is not a mapping (a Python expression such as
            ``"dict(net_arch=[64])"`` is refused, never evaluated), has an unknown key or a value
            of the wrong kind.
    """
    if not isinstance(value, Mapping):
        raise ConfigError(
            f"{where}: policy_kwargs must be a mapping in YAML (e.g. net_arch: {{pi: [64], "
            f"vf: [64]}}, activation_fn: tanh), not {shown(value)}; Python expressions are not "
            "evaluated"
        )
    allowed = [k for k in POLICY_KWARGS if recurrent or k not in LSTM_KEYS]
    unknown = sorted(set(value) - set(allowed))
    if unknown:
        raise ConfigError(f"{where}: unknown policy_kwargs {unknown}; allowed: {sorted(allowed)}")
    return {k: POLICY_KWARGS[k](f"{where}: policy_kwargs.{k}", v) for k, v in value.items()}


def check_spec(where: str, spec: Any) -> dict[str, Any]:
    """An agent's network description (``agent.json``'s ``"policy"``), checked.

    Raises:
        ConfigError: not a mapping, an unknown class or key, a missing size or activation, a
            wrong kind, or ``use_sde`` for a ``PerModelPolicy`` (:data:`NO_SDE`).
    """
    if not isinstance(spec, Mapping):
        raise ConfigError(f"{where} must be a mapping, got {shown(spec)}")
    name = spec.get("class")
    if name not in POLICY_CLASS_NAMES:
        raise ConfigError(
            f"{where}.class must be one of {list(POLICY_CLASS_NAMES)}, got {shown(name)}"
        )
    unknown = sorted(set(spec) - {"class", *_COMMON_KEYS, *_CLASS_KEYS[name]})
    if unknown:
        raise ConfigError(f"{where}: unknown keys {unknown} for a {name}")
    # the activation too: SB3's default (tanh) is not necessarily the one it was trained with
    required = ("observation_size", "action_size", "activation_fn", *_CLASS_KEYS[name])
    missing = [k for k in required if k not in spec]
    if missing:
        raise ConfigError(f"{where}: missing {missing}")
    checks = {**POLICY_KWARGS, **SPEC_FIELDS}
    out = {"class": name} | {
        k: checks[k](f"{where}.{k}", v) for k, v in spec.items() if k != "class"
    }
    check_sde(f"{where}.use_sde", name, out.get("use_sde", False))
    return out


#: The policy classes that cannot explore with gSDE (``use_sde``): the per-model policy's log
#: standard deviation is one number shared by the models, of shape ``(1,)``, where gSDE needs a
#: matrix of the latent's size by the actions' (its first action fails on it).
NO_SDE = ("PerModelPolicy",)


def check_sde(where: str, policy: Any, use_sde: Any) -> None:
    """Refuse ``use_sde: true`` (``where`` names it) for a policy class of :data:`NO_SDE`."""
    if use_sde is True and policy in NO_SDE:
        raise ConfigError(
            f"{where} must be false for a {policy} (its one log standard deviation shared by "
            "the models is no matrix gSDE can use), got true"
        )
