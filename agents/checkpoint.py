"""Training checkpoints as data: everything ``train.py --resume`` needs, nothing pickled.

A checkpoint directory is an agent directory (the acting files of :mod:`agents.policy`:
``agent.json``, ``policy.safetensors``, ``env.json``, ``vecnormalize.json`` with the observation
normalizer's statistics) plus

* ``resume.json`` — the run: algorithm, environment id, seed and hyperparameters, and the
  configuration its final evaluation runs on (the first ``--env-config`` file's); the algorithm's
  counters (steps, updates, episodes); each training slot's two random streams (the numpy
  bit-generator states of its scenario and noise generators), so that a resumed run draws the
  episodes that come next instead of replaying the first ones; the global numpy generator
  (minibatch order); the reward normalizer's running mean, variance and count; the weight
  average's counters and the step it began at;
* ``resume.safetensors`` — the optimizer's state (Adam's step counts and moments per
  parameter), torch's generator state (action sampling) and the weight average's tensors.

A resumed run rebuilds the model from the recorded hyperparameters and loads these; the episodes
in progress at the checkpoint and the partial rollout are not kept (each slot starts its next
episode from its continued streams). Checkpoints are written to a sibling directory and then
renamed into place, so an existing checkpoint is never left half-written. SB3's ``model.zip``
(pickled objects) is neither written nor read.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from agents.policy import ALGOS, load_agent, read_json
from agents.schema import finite_number
from agents.training import (
    MAX_SEED,
    WeightAverage,
    check_hyperparams,
    find_normalizer,
    save_agent,
)
from imm_gym.validation import ConfigError, unique_keys

RESUME_FILE = "resume.json"
TENSORS_FILE = "resume.safetensors"
#: The version of the layout above, recorded in ``resume.json``.
FORMAT = 1
#: The keys of ``resume.json``.
RESUME_KEYS = (
    "format",
    "algo",
    "env_id",
    "seed",
    "hyperparams",
    "num_timesteps",
    "n_updates",
    "episode_num",
    "streams",
    "numpy_rng",
    "reward_normalizer",
    "swa",
)
#: Keys a checkpoint of this format may lack (written since): ``evaluation_config``, the first
#: ``--env-config`` file's fields the run's final evaluation runs on (null: the default
#: tracker); ``swa.start``, the step the weight average began at.
OPTIONAL_KEYS = ("evaluation_config",)
SWA_KEYS = ["last_update", "snapshots"]


def save_checkpoint(
    directory: Path,
    model: Any,
    env: Any,
    run: dict[str, Any],
    agent_meta: dict[str, Any],
    swa: WeightAverage | None,
) -> None:
    """Write the checkpoint ``directory`` (replacing it once complete).

    Args:
        directory: the checkpoint directory.
        model: the SB3 algorithm (PPO or RecurrentPPO) being trained.
        env: its VecEnv stack (:func:`agents.training.make_training_env`).
        run: ``algo``, ``env_id``, ``seed`` and the checked ``hyperparams`` (plain data).
        agent_meta: the extra entries of ``agent.json`` (critic_dims, steps...).
        swa: the weight average, if the run keeps one.
    """
    import torch

    from agents.network import save_tensors

    partial = directory.with_name(f".{directory.name}.partial")
    if partial.exists():
        shutil.rmtree(partial)
    hyperparams = run["hyperparams"]
    frame_stack = int(hyperparams.get("frame_stack", 1))
    env_kwargs = hyperparams.get("env_kwargs", {})
    save_agent(partial, model, env, env_kwargs, run["algo"], frame_stack, agent_meta)
    tensors = _optimizer_tensors(model.policy.optimizer)
    tensors["rng/torch"] = torch.get_rng_state()
    averaging = swa is not None and swa.snapshots > 0
    if averaging:
        tensors.update({f"swa/{name}": value for name, value in swa.average.items()})
    save_tensors(partial / TENSORS_FILE, tensors)
    norm = find_normalizer(env)
    numpy_state = np.random.get_state(legacy=False)  # noqa: NPY002 (SB3 shuffles with it)
    numpy_state["state"]["key"] = numpy_state["state"]["key"].tolist()
    state = {
        "format": FORMAT,
        **{key: run[key] for key in ("algo", "env_id", "seed", "hyperparams")},
        "num_timesteps": int(model.num_timesteps),
        "n_updates": int(model._n_updates),
        "episode_num": int(model._episode_num),
        "streams": stream_states(env.unwrapped.core),
        "numpy_rng": numpy_state,
        "reward_normalizer": None
        if norm is None
        else {
            "mean": float(norm.ret_rms.mean),
            "var": float(norm.ret_rms.var),
            "count": float(norm.ret_rms.count),
        },
        "swa": {"snapshots": swa.snapshots, "last_update": swa.last_update, "start": swa.start}
        if averaging
        else None,
        "evaluation_config": run.get("evaluation_config"),
    }
    (partial / RESUME_FILE).write_text(json.dumps(state))
    old = directory.with_name(f".{directory.name}.old")
    if directory.exists():
        if old.exists():
            shutil.rmtree(old)
        directory.rename(old)
    partial.rename(directory)
    if old.exists():
        shutil.rmtree(old)


def read_checkpoint(directory: Path) -> dict[str, Any]:
    """The checked ``resume.json`` of a checkpoint whose acting files and tensors load.

    Raises:
        ConfigError: ``directory`` is not a checkpoint of this version (a ``model.zip`` of an
            earlier version is refused: it is a pickle), or one of its files is malformed; the
            message names the file.
    """
    from agents.network import load_tensors
    from imm_gym.envs import PRESETS
    from imm_gym.sim.env_config import EnvConfig

    file = directory / RESUME_FILE
    if not file.exists():  # one that is not a regular file: read_json says so
        if (directory / "model.zip").exists():
            raise ConfigError(
                f"{directory} is a checkpoint of an earlier version (SB3's model.zip: pickled "
                "objects, which can run code when loaded), so it is not loaded; this version "
                f"resumes only from its own data-only checkpoints ({RESUME_FILE} + "
                f"{TENSORS_FILE}). The run cannot be continued; its policy can be converted "
                f"on a machine where you trust the files: python -m agents.export --from-pickle "
                f"{directory} --to NEW_DIR"
            )
        raise ConfigError(f"{directory} is not a checkpoint ({RESUME_FILE} missing)")
    state = read_json(file)
    if not set(RESUME_KEYS) <= set(state) <= {*RESUME_KEYS, *OPTIONAL_KEYS}:
        raise ConfigError(
            f"{file}: keys must be {list(RESUME_KEYS)} and optionally {list(OPTIONAL_KEYS)}, got "
            f"{sorted(state)}"
        )
    if state["format"] != FORMAT:
        raise ConfigError(f"{file}: format {state['format']!r} is not {FORMAT}")
    if state["algo"] not in ALGOS:
        raise ConfigError(f"{file}: algo must be one of {list(ALGOS)}, got {state['algo']!r}")
    if not isinstance(state["env_id"], str) or state["env_id"] not in PRESETS:
        raise ConfigError(
            f"{file}: env_id must be one of {sorted(PRESETS)}, got {state['env_id']!r}"
        )
    for key in ("seed", "num_timesteps", "n_updates", "episode_num"):
        if not _is_count(state[key]):
            raise ConfigError(f"{file}: {key} must be a non-negative integer, got {state[key]!r}")
    if state["seed"] > MAX_SEED:
        raise ConfigError(f"{file}: seed must be at most {MAX_SEED}, got {state['seed']}")
    state["hyperparams"] = check_hyperparams(
        f"{file}: hyperparams", state["hyperparams"], state["algo"]
    )
    _generators(file, state["streams"])
    _numpy_state(file, state["numpy_rng"])
    state["reward_normalizer"] = _reward_normalizer(file, state["reward_normalizer"])
    swa = state["swa"]
    counts = isinstance(swa, dict) and sorted(swa) in (SWA_KEYS, sorted([*SWA_KEYS, "start"]))
    if swa is not None and not (counts and all(_is_count(v) for v in swa.values())):
        raise ConfigError(
            f"{file}: swa must be null or {{snapshots, last_update[, start]}}, got {swa!r}"
        )
    if swa is not None and state["hyperparams"].get("swa_start") is None:
        raise ConfigError(f"{file}: swa records a weight average, the hyperparameters keep none "
                          "(no swa_start)")
    evaluation = state.setdefault("evaluation_config", None)
    if evaluation is not None and not isinstance(evaluation, dict):
        raise ConfigError(f"{file}: evaluation_config must be null or an object of EnvConfig "
                          f"fields, got {evaluation!r}")
    if evaluation is not None:  # the final evaluation's: checked before the budget is trained
        try:
            EnvConfig.build(evaluation)
        except ConfigError as err:
            raise ConfigError(f"{file}: evaluation_config: {err}") from None
    network = load_agent(directory).model
    tensors_file = directory / TENSORS_FILE
    # names, dtypes and shapes from the header before a tensor is read, then the numbers
    tensors = load_tensors(
        tensors_file,
        lambda declared: check_tensors(tensors_file, declared, network, swa, state["n_updates"]),
    )
    check_tensors(tensors_file, tensors, network, swa, state["n_updates"])
    return state


def restore(
    directory: Path, state: dict[str, Any], model: Any, env: Any, swa: WeightAverage | None
) -> None:
    """Load a checkpoint into a model freshly built from its hyperparameters and seed.

    Sets the policy's weights, the optimizer's state, the step/update/episode counters, the
    normalizer's statistics, each training slot's streams (the next reset continues them), the
    weight average, and torch's and numpy's global generators.

    Raises:
        ConfigError: a file does not fit the model (the message names it).
    """
    import torch

    from agents.network import load_tensors, load_weights

    file = directory / RESUME_FILE
    load_weights(model.policy, directory)
    tensors_file = directory / TENSORS_FILE
    swa_state, n_updates = state["swa"], state["n_updates"]
    tensors = load_tensors(
        tensors_file,
        lambda declared: check_tensors(tensors_file, declared, model.policy, swa_state, n_updates),
    )
    check_tensors(tensors_file, tensors, model.policy, swa_state, n_updates)
    _load_optimizer(model.policy, tensors, directory / TENSORS_FILE, n_updates)
    model.num_timesteps = state["num_timesteps"]
    model._n_updates = state["n_updates"]
    model._episode_num = state["episode_num"]
    norm = find_normalizer(env)
    reward = state["reward_normalizer"]
    if (norm is None) != (reward is None):
        raise ConfigError(f"{file}: the reward normalizer does not match the hyperparameters")
    if norm is not None:
        stats = read_json(directory / "vecnormalize.json")
        norm.obs_rms.mean = np.array(stats["mean"])
        norm.obs_rms.var = np.array(stats["var"])
        norm.obs_rms.count = stats["count"]
        norm.ret_rms.mean = np.array(reward["mean"])
        norm.ret_rms.var = np.array(reward["var"])
        norm.ret_rms.count = reward["count"]
    restore_streams(env.unwrapped, state["streams"], file)
    if swa is not None and state["swa"] is not None:
        swa.average = {k[4:]: v for k, v in tensors.items() if k.startswith("swa/")}
        swa.snapshots = state["swa"]["snapshots"]
        swa.last_update = state["swa"]["last_update"]
        # the mean continues from where it began, whatever budget the resumed run is given (a
        # checkpoint without it began at its own budget's fraction)
        recorded = state["hyperparams"]
        began = int(float(recorded.get("swa_start", 0.0)) * recorded["n_timesteps"])
        swa.start = state["swa"].get("start", began)
    np.random.set_state(_numpy_state(file, state["numpy_rng"]))  # noqa: NPY002
    try:
        torch.set_rng_state(tensors["rng/torch"])
    except (KeyError, TypeError, RuntimeError) as err:
        raise ConfigError(
            f"{directory / TENSORS_FILE}: no torch generator state ({err!r})"
        ) from None


def check_tensors(
    file: Path, tensors: dict[str, Any], policy: Any, swa: Any, n_updates: int
) -> None:
    """The tensors of ``resume.safetensors`` checked against the network ``policy`` (the one of
    ``agent.json``, or the model's being resumed): only ``optimizer/...``, ``rng/torch`` and
    ``swa/...`` names; ``rng/torch`` of the dtype and shape of torch's generator state; the
    optimizer's state fitting the policy's parameters, every parameter's once ``n_updates`` (the
    run's gradient steps, ``resume.json``'s) is above 0 (:func:`_optimizer_state`); the weight
    average (present exactly when ``resume.json``'s ``swa`` records one) the network's state
    dict, name for name, each tensor of its shape and dtype, an integer buffer equal to the
    network's. Meta tensors (the file's header, :func:`agents.network.load_tensors`) have
    their names, dtypes and shapes checked, not their numbers.

    Raises:
        ConfigError: a tensor does not fit; the message names ``file``.
    """
    import torch

    unknown = sorted(
        name for name in tensors
        if name != "rng/torch" and name.split("/")[0] not in ("optimizer", "swa")
    )
    if unknown:
        raise ConfigError(f"{file}: {unknown[0]!r} is no tensor of a checkpoint (optimizer/..., "
                          "rng/torch, swa/...)")
    rng, own_rng = tensors.get("rng/torch"), torch.get_rng_state()
    if rng is not None and (rng.dtype != own_rng.dtype or rng.shape != own_rng.shape):
        raise ConfigError(f"{file}: 'rng/torch' is {rng.dtype} {tuple(rng.shape)}, torch's "
                          f"generator state is {own_rng.dtype} {tuple(own_rng.shape)}")
    _optimizer_state(policy.optimizer, tensors, file, n_updates)
    average = {name[4:]: value for name, value in tensors.items() if name.startswith("swa/")}
    if swa is None:
        if average:
            raise ConfigError(f"{file}: holds a weight average (swa/...), but {RESUME_FILE}'s "
                              "swa is null")
        return
    expected = policy.state_dict()
    missing = sorted(f"swa/{name}" for name in set(expected) - set(average))
    unexpected = sorted(f"swa/{name}" for name in set(average) - set(expected))
    if missing or unexpected:
        raise ConfigError(
            f"{file}: the weight average (swa/...) of {swa['snapshots']} snapshots is not the "
            f"network's of agent.json: missing {missing}, unexpected {unexpected}"
        )
    for name in sorted(average):
        value, own = average[name], expected[name]
        if value.shape != own.shape or value.dtype != own.dtype:
            raise ConfigError(
                f"{file}: tensor 'swa/{name}' is {value.dtype} {tuple(value.shape)}, the network "
                f"of agent.json needs {own.dtype} {tuple(own.shape)}"
            )
        if not value.is_meta and not value.is_floating_point() and not torch.equal(value, own):
            raise ConfigError(f"{file}: tensor 'swa/{name}' is not the network's (an integer "
                              "buffer its description sets, not averaged)")


def _is_count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _reward_normalizer(file: Path, value: Any) -> dict[str, float] | None:
    """``reward_normalizer``: null, or the return's running ``mean``, ``var`` (>= 0) and
    ``count`` (> 0, as ``vecnormalize.json``'s: the running mean divides by it) as finite
    numbers."""
    if value is None:
        return None
    keys = ("mean", "var", "count")
    numbers = isinstance(value, dict) and sorted(value) == sorted(keys)
    numbers = numbers and all(finite_number(v) is not None for v in value.values())
    if not numbers or value["var"] < 0 or value["count"] <= 0:
        raise ConfigError(f"{file}: reward_normalizer must be null or finite {list(keys)} "
                          f"(var >= 0, count > 0), got {value!r}")
    return {k: float(value[k]) for k in keys}


def _numpy_state(file: Path, value: Any) -> dict[str, Any]:
    """``numpy_rng`` (``np.random.get_state(legacy=False)`` with the key as a list) as
    ``np.random.set_state`` takes it, checked on a scratch generator."""
    try:
        state = {**value, "state": {**value["state"]}}
        state["state"]["key"] = np.array(state["state"]["key"], dtype=np.uint32)
        np.random.RandomState().set_state(state)
    except (KeyError, TypeError, ValueError, OverflowError) as err:
        raise ConfigError(f"{file}: numpy_rng is not an MT19937 state ({err!r})") from None
    return state


def _generators(file: Path, states: Any) -> list[tuple[np.random.Generator, np.random.Generator]]:
    """``streams``: for each slot, its scenario and noise generators from their PCG64 states."""
    if not isinstance(states, list):
        raise ConfigError(f"{file}: streams must be a list")
    out = []
    for i, pair in enumerate(states):
        try:
            generators = [np.random.Generator(np.random.PCG64()) for _ in range(2)]
            for generator, recorded in zip(generators, pair, strict=True):
                generator.bit_generator.state = recorded
        except (KeyError, TypeError, ValueError, OverflowError) as err:
            raise ConfigError(f"{file}: streams[{i}] is not two PCG64 states ({err!r})") from None
        out.append((generators[0], generators[1]))
    return out


def stream_states(core: Any) -> list[list[dict[str, Any]]]:
    """Each slot's ``[scenario, noise]`` bit-generator states (JSON-able: PCG64 holds ints).

    Reads :meth:`~imm_gym.sim.core.TrackingCore.streams`, the per-slot generators it keeps
    across episodes (a slot reset without a seed continues them).
    """
    return [[rng.bit_generator.state for rng in pair] for pair in core.streams()]


def restore_streams(venv: Any, states: list[Any], file: Path) -> None:
    """Give each slot of the SB3 adapter ``venv`` the generators of ``states`` and drop the
    seeds pending for its next reset, so that the reset continues the recorded streams."""
    core = venv.core
    if len(states) != core.n_envs:
        raise ConfigError(f"{file}: {len(states)} streams for {core.n_envs} training slots")
    core.set_streams(_generators(file, states))
    venv._reset_seeds()


#: The per-parameter state of Adam (PPO's optimizer) that a checkpoint holds.
ADAM_STATE = ("step", "exp_avg", "exp_avg_sq")


def _optimizer_tensors(optimizer: Any) -> dict[str, Any]:
    """``optimizer/<parameter index>/<name>`` for each tensor of the optimizer's state."""
    return {
        f"optimizer/{index}/{name}": value
        for index, entries in optimizer.state_dict()["state"].items()
        for name, value in entries.items()
    }


def _load_optimizer(policy: Any, tensors: dict[str, Any], file: Path, n_updates: int) -> None:
    """Load the ``optimizer/...`` tensors into ``policy.optimizer`` (its hyperparameters are the
    recorded ones, rebuilt; only the per-parameter state is loaded), checked
    (:func:`_optimizer_state`)."""
    optimizer = policy.optimizer
    state = _optimizer_state(optimizer, tensors, file, n_updates)
    optimizer.load_state_dict(
        {"state": state, "param_groups": optimizer.state_dict()["param_groups"]}
    )


def _optimizer_state(
    optimizer: Any, tensors: dict[str, Any], file: Path, n_updates: int
) -> dict[int, Any]:
    """The per-parameter state of the ``optimizer/...`` tensors, every name and shape checked
    against ``optimizer``'s parameters: each parameter's :data:`ADAM_STATE` (or none before the
    first update, ``n_updates`` 0: a run that has updated its weights has Adam's moments for
    every parameter, without which a resumed run would restart them silently) in float32,
    ``step`` a scalar count >= 0, ``exp_avg_sq`` >= 0 (Adam divides by ``1 - beta ** step``
    and takes the square root of the second moment: a negative step or moment is NaN or a
    division by zero in the first update). The numbers of meta tensors are not checked
    (:func:`check_tensors`)."""
    import torch

    params = [p for group in optimizer.param_groups for p in group["params"]]
    # each parameter's index as str() writes it: int() also reads "01" or "١" (an Arabic-Indic
    # one) as 1, a second tensor that would silently replace optimizer/1's
    indices = {str(i): i for i in range(len(params))}
    state: dict[int, dict[str, Any]] = {}
    for key, value in sorted(tensors.items()):
        parts = key.split("/")
        if parts[0] != "optimizer":
            continue
        if len(parts) != 3 or parts[1] not in indices:
            raise ConfigError(f"{file}: {key!r} names no parameter of the optimizer (indices 0 "
                              f"to {len(params) - 1} in decimal digits, no leading zero)")
        index = indices[parts[1]]
        if parts[2] not in ADAM_STATE:
            raise ConfigError(
                f"{file}: {key!r} is no entry of Adam's state (one of {list(ADAM_STATE)})"
            )
        if parts[2] == "step" and value.dim():
            raise ConfigError(f"{file}: {key!r} must be a scalar, got {tuple(value.shape)}")
        if value.dim() and value.shape != params[index].shape:
            raise ConfigError(
                f"{file}: {key!r} is {tuple(value.shape)}, its parameter "
                f"{tuple(params[index].shape)}"
            )
        if value.dtype != torch.float32:
            raise ConfigError(f"{file}: {key!r} is {value.dtype}, not torch.float32")
        numbers = not value.is_meta
        if numbers and parts[2] == "step" and not 0.0 <= float(value) < np.inf:
            raise ConfigError(
                f"{file}: {key!r} must be a finite count >= 0, got {float(value)!r}"
            )
        if numbers and parts[2] == "exp_avg_sq" and bool((value < 0).any()):
            raise ConfigError(
                f"{file}: {key!r} holds negative values (Adam's second moments are >= 0)"
            )
        state.setdefault(index, {})[parts[2]] = value
    if (state or n_updates > 0) and sorted(state) != list(range(len(params))):
        raise ConfigError(
            f"{file}: optimizer state for {len(state)} of {len(params)} parameters (n_updates "
            f"{n_updates}: Adam's state of every parameter needed to resume)"
        )
    for index, entries in state.items():
        if sorted(entries) != sorted(ADAM_STATE):
            raise ConfigError(
                f"{file}: optimizer/{index} holds {sorted(entries)}, Adam's state is "
                f"{sorted(ADAM_STATE)}"
            )
    return state


def read_validation(file: Path) -> dict[str, Any]:
    """A run's ``best/validation.json``, which a resumed run continues: ``armse_pos`` (the best
    validation ARMSE, or null before any), the ``timesteps`` it was reached at and the
    ``history`` of ``{"timesteps", "armse_pos"}`` validations.

    Raises:
        ConfigError: the file is not such a record (naming it and what is wrong).
    """
    def refuse(problem: str) -> NoReturn:
        raise ConfigError(f"{file}: {problem}")

    def count(value: Any) -> bool:
        return type(value) is int and value >= 0

    def score(value: Any) -> bool:
        return type(value) in (int, float) and math.isfinite(value) and value >= 0

    try:
        data = json.loads(file.read_bytes().decode("utf-8"), object_pairs_hook=unique_keys)
    except (OSError, ValueError, RecursionError) as err:
        refuse(f"not valid JSON ({' '.join(str(err).split()) or type(err).__name__})")
    if not isinstance(data, dict):
        refuse(f"must hold an object, got {type(data).__name__}")
    unknown = sorted(set(data) - {"armse_pos", "timesteps", "history"})
    if unknown:
        refuse(f"unknown keys {unknown}")
    if "armse_pos" not in data or not (data["armse_pos"] is None or score(data["armse_pos"])):
        refuse(f"armse_pos must be null or a finite number >= 0, got {data.get('armse_pos')!r}")
    if "timesteps" in data and not count(data["timesteps"]):
        refuse(f"timesteps must be an integer >= 0, got {data['timesteps']!r}")
    history = data.get("history", [])
    if not isinstance(history, list):
        refuse(f"history must be a list, got {type(history).__name__}")
    for i, entry in enumerate(history):
        if not (
            isinstance(entry, dict)
            and set(entry) == {"timesteps", "armse_pos"}
            and count(entry["timesteps"])
            and score(entry["armse_pos"])
        ):
            refuse(
                f"history[{i}] must be {{\"timesteps\": an integer >= 0, \"armse_pos\": a finite "
                f"number >= 0}}, got {entry!r}"
            )
    return data
