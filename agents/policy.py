"""A trained agent as a policy with the ``predict`` protocol of the evaluation tool.

A trained agent is a directory (a run's ``agent/``, ``best/``, a checkpoint, or the shipped
``pretrained/``) of data files only — loading it never unpickles, so it cannot run code:

* ``agent.json`` — the algorithm, the frame-stack depth, the critic-only entries per frame,
  whether it normalizes its observations (``normalize``) and, under ``"policy"``, the network's
  description (:mod:`agents.schema`: class and activation by name, layer sizes, observation and
  action sizes);
* ``policy.safetensors`` — the network's tensors (policy and value heads; no optimizer state);
* ``env.json`` — the :class:`~imm_gym.EnvConfig` overrides it was trained with (action mode,
  features...);
* ``vecnormalize.json`` — the observation normalizer's running mean/variance, present exactly
  when ``agent.json`` records ``normalize: true`` (an ``agent.json`` written before the field
  that lacks it may go without it: a warning says the agent acts on raw observations).

A checkpoint adds the files that resume training (:mod:`agents.checkpoint`). The pickled files of
earlier versions (``policy.pt``, ``model.zip``) are refused, with the command that converts them
on a machine where they are trusted (``python -m agents.export --from-pickle``).

:class:`LearnedPolicy` applies the normalizer and then the frame stack itself (the order of
SB3's ``VecFrameStack(VecNormalize(env))``), so a model runs through
:func:`imm_gym.evaluation.rollout.rollout` like any baseline.
"""

from __future__ import annotations

import json
import stat
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agents.schema import MAX_INPUT, finite_number
from imm_gym.sim.config_file import TRACKER_FIELDS, tracker_of
from imm_gym.validation import ConfigError, unique_keys

ALGOS = ("ppo", "recurrent-ppo")
#: The files of an agent directory (``vecnormalize.json`` only when trained with a normalizer).
AGENT_FILE, ENV_FILE, NORMALIZER_FILE = "agent.json", "env.json", "vecnormalize.json"
#: An ensemble's file (:mod:`agents.ensemble`), named beside the agent's for the writers that
#: must not write a policy into another's directory (:func:`refuse_other_policy`).
ENSEMBLE_FILE = "ensemble.json"
#: The keys of ``agent.json`` (``policy``, ``algo`` and ``frame_stack`` required; ``normalize``
#: written by :func:`agents.training.save_agent` since it is read).
AGENT_KEYS = (
    "algo",
    "frame_stack",
    "critic_dims",
    "normalize",
    "policy",
    "env_id",
    "seed",
    "num_timesteps",
    "swa",
    "trained_across",
)
#: The most frames an agent may stack (its network's input is that many observations) and the
#: most ground-truth entries its critic may read per frame.
MAX_FRAMES, MAX_CRITIC_DIMS = 64, 1024
#: The most models a bank of ``env.json`` may hold: each gives two entries of a frame (its
#: probabilities now and a step before) and no network reads more than
#: :data:`~agents.schema.MAX_INPUT` entries.
MAX_MODELS = MAX_INPUT // 2
#: The keys of ``vecnormalize.json``.
NORMALIZER_KEYS = ("mean", "var", "count", "clip_obs", "epsilon")
#: The largest JSON file of an agent, ensemble, selector or checkpoint read (a checkpoint's
#: ``resume.json`` holds some 10 KiB and 350 bytes a training slot).
MAX_JSON_BYTES = 16 * 2**20


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
        source: where the agent comes from, for the message on an observation of the wrong size.
        trained_across: the trackers (:data:`~imm_gym.sim.config_file.TRACKER_FIELDS`) of the
            further parts of the mixture it was trained on (``env_mixture``), besides the one of
            ``env_overrides``.
        spec: the network's description (:func:`agents.network.policy_spec`), which
            :meth:`for_models` rebuilds a network shared by the models from.
        directory: the agent's directory, if it was loaded from one (messages name its files).
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
        source: str = "the agent",
        trained_across: Sequence[dict[str, Any]] = (),
        spec: dict[str, Any] | None = None,
        directory: Path | None = None,
    ) -> None:
        self.model = model
        self.directory = directory
        self.spec = spec
        self.env_overrides = env_overrides
        self.obs_mean, self.obs_var = obs_mean, obs_var
        self.clip_obs, self.epsilon = clip_obs, epsilon
        self.frame_stack = frame_stack
        self.recurrent = recurrent
        self.critic_dims = critic_dims
        self.source = source
        self.trained_across = tuple(trained_across)
        #: entries of one environment observation, the critic's excluded
        self.obs_size = int(model.observation_space.shape[0]) // frame_stack - critic_dims

    @property
    def shares_models(self) -> bool:
        """Whether its network is shared by the models (reads a bank of any size and order)."""
        return self.spec is not None and self.spec["class"] == "PerModelPolicy"

    def for_models(self, n_models: int) -> LearnedPolicy:
        """This agent for a bank of ``n_models`` models: its network shared by the models
        (``PerModelPolicy``, :mod:`agents.per_model`) rebuilt for that many, with the same actor
        weights and the normalizer's statistics per model carried over; itself when it has that
        many models or its network reads them by position (the evaluation's size check then
        refuses another bank)."""
        from agents.network import build_policy
        from agents.per_model import frame_groups, refit_normalizer, refit_state
        from imm_gym.sim.core import critic_state_size

        trained = int(self.model.action_space.shape[0])
        if self.spec is None or not self.shares_models or n_models == trained:
            return self
        features, dim_z = self.spec["obs_features"], self.spec["dim_z"]
        critic_dims = critic_state_size(n_models) if self.critic_dims else 0
        frame = sum(a.size for a in frame_groups(features, n_models, dim_z, False))
        spec = {
            **self.spec,
            "observation_size": self.frame_stack * (frame + critic_dims),
            "action_size": n_models,
            "critic_dims": critic_dims,
        }
        model = build_policy(spec, self.source)
        model.load_state_dict(refit_state(self.model.state_dict(), model.state_dict()))
        mean, var = self.obs_mean, self.obs_var
        if mean is not None and var is not None:
            try:
                mean, var = refit_normalizer(
                    mean, var, features, dim_z, trained, n_models, bool(self.critic_dims)
                )
            except ConfigError as err:
                where = self.source if self.directory is None else self.directory / NORMALIZER_FILE
                raise ConfigError(
                    f"{where}: {err}, so the agent cannot act on a bank of {n_models} models"
                ) from None
        return LearnedPolicy(
            model,
            self.env_overrides,
            mean,
            var,
            self.clip_obs,
            self.epsilon,
            frame_stack=self.frame_stack,
            critic_dims=critic_dims,
            source=f"{self.source} (for {n_models} models)",
            trained_across=self.trained_across,
            spec=spec,
            directory=self.directory,
        )

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
        """SB3's ``predict`` for ``observation`` ``(N, obs_size)`` (or one ``(obs_size,)``):
        actions in ``[-1, 1]`` and the state to pass next, the frame stack (and the LSTM's
        state). ``episode_start`` ``(N,)`` clears a slot's frames where True; None means no
        episode starts (sb3-contrib's convention), but on a first call (``state`` None)."""
        obs = np.asarray(observation, dtype=np.float64)
        single = obs.ndim == 1
        obs = obs[None] if single else obs
        if obs.ndim != 2 or obs.shape[1] != self.obs_size:
            raise ConfigError(
                f"{self.source} reads observations of {self.obs_size} entries, the environment "
                f"gives {obs.shape[1:]} (other obs_features or another bank than it was trained "
                "with)"
            )
        if self.critic_dims:
            obs = np.concatenate([obs, np.zeros((obs.shape[0], self.critic_dims))], axis=-1)
        N, d = obs.shape
        # episode_start None: no episode starts (sb3-contrib's convention), but on a first call
        start = (
            np.full(N, state is None) if episode_start is None else np.asarray(episode_start, bool)
        )
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


def refuse_other_policy(directory: Path, kind: str, files: tuple[str, ...]) -> None:
    """Refuse writing a ``kind`` (an ensemble, a selector) into ``directory`` where it holds one
    of ``files``, the file of a policy of its own: loading the directory would take one policy
    for the other.

    Raises:
        ConfigError: naming the file found.
    """
    for policy_file in files:
        if (directory / policy_file).exists():
            raise ConfigError(
                f"{directory}: holds {policy_file}, a policy of its own: {kind}'s directory must "
                f"hold neither {' nor '.join(files)} (loading it would take one policy for "
                "another)"
            )


def agent_directory(path: str | Path) -> Path:
    """The agent directory :func:`load_agent` reads for ``path``: ``path`` itself, or the
    directory of the file it names (a ``.json``, ``.safetensors``, ``.pt`` or ``.zip`` name:
    ``agent.json``, ``policy.safetensors``...). Nothing is read."""
    path = Path(path)
    return path.parent if path.suffix in (".zip", ".pt", ".safetensors", ".json") else path


def load_agent(path: str | Path) -> LearnedPolicy:
    """Load a trained agent from its directory (or a file in it), checking every file.

    Raises:
        FileNotFoundError: there is no ``agent.json``.
        ConfigError: a file is unreadable, not a regular file (``agent.json`` a directory or a
            link to ``/dev/zero``), malformed or inconsistent with the others (bad JSON,
            an unknown key, truncated weights, an observation size that the environment of
            ``env.json`` does not give), or the agent is in the pickled format of earlier
            versions; the message names the file.
    """
    from agents.network import build_policy, check_weights_size, load_weights
    from agents.schema import check_spec
    from imm_gym.sim.env_config import EnvConfig

    directory = agent_directory(path)
    agent_file = directory / AGENT_FILE
    if not agent_file.exists():  # one that is not a regular file: read_json says so
        raise FileNotFoundError(f"no trained agent at {str(directory)!r} (agent.json missing)")
    meta = read_json(agent_file)
    if "policy" not in meta and any((directory / f).exists() for f in ("policy.pt", "model.zip")):
        raise ConfigError(pickled_agent_message(directory))
    meta = check_agent_meta(agent_file, meta)
    where = f"{agent_file}: policy"
    spec = check_spec(where, meta["policy"])
    frame_stack, critic_dims = meta["frame_stack"], meta["critic_dims"]
    recurrent = meta["algo"] == "recurrent-ppo"
    if recurrent and critic_dims:
        raise ConfigError(f"{agent_file}: critic_dims {critic_dims} with algo 'recurrent-ppo'")
    expected = (
        ("MlpLstmPolicy",)
        if recurrent
        else ("AsymmetricMlpPolicy", "PerModelPolicy")
        if critic_dims
        else ("MlpPolicy", "PerModelPolicy")
    )
    if spec["class"] not in expected:
        raise ConfigError(
            f"{where}.class is {spec['class']!r}, but algo {meta['algo']!r} with critic_dims "
            f"{critic_dims} needs one of {list(expected)}"
        )
    if spec["class"] in ("AsymmetricMlpPolicy", "PerModelPolicy") and (
        spec["critic_dims"] != critic_dims or spec["frame_stack"] != frame_stack
    ):
        raise ConfigError(f"{where}: critic_dims/frame_stack differ from the agent's")
    env_overrides, frame, actions = read_env_file(directory / ENV_FILE, meta.get("env_id"))
    if spec["class"] == "PerModelPolicy":  # the network's layout of a frame is the env's
        acts = EnvConfig.build(env_overrides)
        for key, value in (("obs_features", list(acts.obs_features)),
                           ("dim_z", acts.sensor.dim_z)):
            if spec[key] != value:
                raise ConfigError(
                    f"{where}.{key} is {spec[key]!r}, but the environment of "
                    f"{directory / ENV_FILE} gives {value!r}"
                )
    frame += critic_dims
    if spec["observation_size"] != frame_stack * frame or spec["action_size"] != actions:
        raise ConfigError(
            f"{where}: the network reads {spec['observation_size']} entries and writes "
            f"{spec['action_size']}, but the environment of {directory / ENV_FILE} gives "
            f"{frame_stack} frames of {frame} entries and takes {actions}"
        )
    check_weights_size(spec, directory)  # before the network is allocated
    norm = _check_normalizer(directory / NORMALIZER_FILE, frame, meta.get("normalize"))
    model = build_policy(spec, where)
    load_weights(model, directory)
    return LearnedPolicy(
        model,
        env_overrides,
        *norm,
        frame_stack=frame_stack,
        recurrent=recurrent,
        critic_dims=critic_dims,
        source=f"agent {str(directory)!r}",
        trained_across=meta.get("trained_across", ()),
        spec=spec,
        directory=directory,
    )


def pickled_agent_message(directory: Path) -> str:
    """Why an agent of the earlier pickled format is refused, and how to convert it."""
    return (
        f"{directory}: an agent in the pickled format of earlier versions (policy.pt, "
        "model.zip), which can run code when loaded, so it is not loaded; on a machine where you "
        f"trust these files convert it with: python -m agents.export --from-pickle {directory} "
        "--to NEW_DIR"
    )


def read_json(file: Path) -> dict[str, Any]:
    """A JSON object from ``file``.

    Raises:
        ConfigError: the file is missing, unreadable, not a regular file (a directory, a
            device such as ``/dev/zero``, a FIFO: read without end or waiting for a writer),
            larger than :data:`MAX_JSON_BYTES`, not valid JSON (a key given twice included, or
            nested too deeply to parse) or not an object.
    """
    try:
        info = file.stat()  # before opening it: opening a FIFO waits for a writer
        if not stat.S_ISREG(info.st_mode):
            raise ConfigError(f"{file}: not a regular file")
        if info.st_size > MAX_JSON_BYTES:
            raise ConfigError(f"{file}: {info.st_size} bytes, more than the {MAX_JSON_BYTES} a "
                              "data file of an agent may hold")
        with file.open("rb") as stream:
            raw = stream.read(MAX_JSON_BYTES + 1)  # whatever it grew to since
        if len(raw) > MAX_JSON_BYTES:
            raise ConfigError(f"{file}: more than the {MAX_JSON_BYTES} bytes a data file of an "
                              "agent may hold")
        data = json.loads(raw.decode("utf-8"), object_pairs_hook=unique_keys)
    except FileNotFoundError:
        raise ConfigError(f"{file}: missing") from None
    except OSError as err:  # a loop of symlinks, a file it may not read...
        raise ConfigError(f"{file}: cannot be read ({err.strerror or err})") from None
    except ConfigError:
        raise
    except ValueError as err:  # not UTF-8, not JSON, or a key given twice
        raise ConfigError(f"{file}: not valid JSON ({err})") from None
    except RecursionError:
        raise ConfigError(f"{file}: not valid JSON (nested too deeply)") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{file}: must hold a JSON object, got {type(data).__name__}")
    return data


def read_manifest(
    file: Path, keys: Sequence[str], fmt: str, combine: Sequence[str]
) -> dict[str, Any]:
    """The JSON object of a directory of several networks acting as one (``ensemble.json``,
    ``selector.json``), checked: only ``keys``, the format ``fmt``, a ``combine`` rule among
    ``combine`` (the first when absent).

    Raises:
        ConfigError: the file is unreadable or breaks one of those; the message names it.
    """
    data = read_json(file)
    unknown = sorted(set(data) - set(keys))
    if unknown:
        raise ConfigError(f"{file}: unknown keys {unknown}; allowed: {list(keys)}")
    if data.get("format") != fmt:
        raise ConfigError(f"{file}: format must be {fmt!r}, got {data.get('format')!r}")
    if data.get("combine", combine[0]) not in combine:
        raise ConfigError(f"{file}: combine must be one of {list(combine)}, got "
                          f"{data.get('combine')!r}")
    return data


def check_agent_meta(file: Path, meta: dict[str, Any]) -> dict[str, Any]:
    """``agent.json`` checked: known keys; ``algo``, ``frame_stack``, ``critic_dims``,
    ``normalize`` (a boolean), ``env_id``, ``seed``, ``num_timesteps`` and ``swa`` valid, each
    tracker of ``trained_across`` a valid one (the ``policy`` entry is checked by
    :func:`agents.schema.check_spec`)."""
    unknown = sorted(set(meta) - set(AGENT_KEYS))
    if unknown:
        raise ConfigError(f"{file}: unknown keys {unknown}; allowed: {list(AGENT_KEYS)}")
    if "policy" not in meta:
        raise ConfigError(f"{file}: no 'policy' entry (the network's description)")
    if meta.get("algo") not in ALGOS:
        raise ConfigError(f"{file}: algo must be one of {list(ALGOS)}, got {meta.get('algo')!r}")
    out = dict(meta)
    for key, low, high, default in (("frame_stack", 1, MAX_FRAMES, None),
                                    ("critic_dims", 0, MAX_CRITIC_DIMS, 0)):
        value = meta.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ConfigError(
                f"{file}: {key} must be an integer in [{low}, {high}], got {value!r}"
            )
        out[key] = value
    if "normalize" in meta and not isinstance(meta["normalize"], bool):
        raise ConfigError(f"{file}: normalize must be true or false, got {meta['normalize']!r}")
    if "env_id" in meta and not isinstance(meta["env_id"], str):
        raise ConfigError(f"{file}: env_id must be a string, got {meta['env_id']!r}")
    for key in ("seed", "num_timesteps"):
        value = meta.get(key, 0)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ConfigError(f"{file}: {key} must be an integer >= 0, got {value!r}")
    swa = meta.get("swa", {})
    if not isinstance(swa, dict) or not all(
        key in ("swa_start", "snapshots") and isinstance(v, int) and not isinstance(v, bool)
        and v >= 0
        for key, v in swa.items()
    ):
        raise ConfigError(
            f"{file}: swa must map swa_start and snapshots to integers >= 0, got {swa!r}"
        )
    out["trained_across"] = read_trackers(file, meta.get("trained_across", []))
    return out


def read_trackers(file: Path, across: Any) -> list[dict[str, Any]]:
    """``trained_across`` of ``file``: a list of trackers, each a mapping of
    :data:`~imm_gym.sim.config_file.TRACKER_FIELDS` (another key, a misspelt ``filtr`` say, is
    refused: the tracker's default would be recorded in its place), read whole."""
    if not isinstance(across, list) or not all(isinstance(t, dict) for t in across):
        raise ConfigError(f"{file}: trained_across must be a list of trackers, got {across!r}")
    for i, tracker in enumerate(across):
        unknown = sorted(set(tracker) - set(TRACKER_FIELDS))
        if unknown:
            raise ConfigError(f"{file}: trained_across[{i}]: unknown keys {unknown}; a tracker "
                              f"has {list(TRACKER_FIELDS)}")
    try:
        return [tracker_of(t) for t in across]
    except ConfigError as err:
        raise ConfigError(f"{file}: trained_across: {err}") from None


def read_env_file(file: Path, env_id: Any) -> tuple[dict[str, Any], int, int]:
    """The agent's overrides — ``env_id``'s preset with ``env.json``'s fields over it, validated
    — and the size of one observation and of an action in that environment. A relative
    ``detector_weights`` is taken from the directory of ``env.json``, as a configuration file's
    is from its own (:func:`write_env_file`), and made absolute (``..`` and links resolved); it
    is refused unless the detector is ``learned``, the one that reads it (and checks it: a
    detector file, :class:`~imm_gym.sim.learned_detector.DetectorNetwork`), so that no other
    file is named by a policy (:mod:`agents.export` copies the detector beside it).

    The observation's size is summed from the features' declared sizes, no array built: a
    bank of :data:`MAX_MODELS` models observing its ``M x M`` TPM gives 268 M entries, which the
    caller compares with what the network reads.

    Raises:
        ConfigError: ``env.json`` is unreadable or malformed, its bank holds more than
            :data:`MAX_MODELS` models (refused before the configuration is built), its fields
            do not make an :class:`~imm_gym.EnvConfig`, or it names ``detector_weights`` for
            another detector than ``learned``; the message names the file.
    """
    from imm_gym.envs import PRESETS
    from imm_gym.sim.actions import action_size
    from imm_gym.sim.env_config import EnvConfig
    from imm_gym.sim.features import observation_size

    recorded = read_json(file)
    weights = recorded.get("detector_weights")
    if isinstance(weights, str):  # a relative one from beside env.json, "..", links resolved
        try:
            recorded["detector_weights"] = str((file.parent / weights).resolve())
        except (OSError, ValueError, RuntimeError) as err:  # a NUL byte, a loop of links
            raise ConfigError(
                f"{file}: detector_weights {weights!r} is not a path ({err})"
            ) from None
    if env_id is not None and (not isinstance(env_id, str) or env_id not in PRESETS):
        raise ConfigError(
            f"{file.parent / AGENT_FILE}: env_id must be one of {list(PRESETS)}, got {env_id!r}"
        )
    # the agent acted in the preset of its env id with env.json's fields over it (as train.py
    # builds its environment): those are its overrides
    overrides = {**PRESETS.get(env_id, {}), **recorded}
    if "obs_features" in overrides and isinstance(overrides["obs_features"], list):
        overrides["obs_features"] = tuple(overrides["obs_features"])
    bank = overrides.get("bank")
    models = bank.get("models") if isinstance(bank, Mapping) else bank  # linear or hetero
    if isinstance(models, (list, tuple)) and len(models) > MAX_MODELS:
        raise ConfigError(
            f"{file}: bank holds {len(models)} models, more than the {MAX_MODELS} an agent's "
            f"network can read (two entries each, at most {MAX_INPUT} entries)"
        )
    try:
        config = EnvConfig.build(overrides)
    except ConfigError as err:
        raise ConfigError(f"{file}: {err}") from None
    if config.detector != "learned" and weights is not None:
        raise ConfigError(
            f"{file}: detector_weights must be null (absent) unless detector is 'learned', the "
            f"one that reads it; got {weights!r} with detector {config.detector!r}"
        )
    M = len(config.bank)
    obs_size = observation_size(config.obs_features, M, config.sensor.dim_z)
    return overrides, obs_size, action_size(config.action_mode, M)


def write_env_file(directory: Path, overrides: Mapping[str, Any]) -> None:
    """``directory/env.json``: the overrides an agent acts with, tuples as lists, a
    ``detector_weights`` path made absolute, so that it reads the same from any working
    directory (:mod:`agents.export` copies that file beside the policy and names it relative);
    ``detector_weights`` only with the ``learned`` detector, the one that reads it
    (:func:`read_env_file` refuses it with another: a configuration file may give it to every
    part of a run, whatever its detector)."""
    from imm_gym.sim.env_config import EnvConfig

    data = dict(overrides)  # JSON writes tuples as lists
    if data.get("detector", EnvConfig.detector) != "learned":
        data.pop("detector_weights", None)
    if isinstance(data.get("detector_weights"), str):
        data["detector_weights"] = str(Path(data["detector_weights"]).resolve())
    (directory / ENV_FILE).write_text(json.dumps(data, indent=2) + "\n")


def _check_normalizer(
    file: Path, size: int, recorded: bool | None = None
) -> tuple[NDArray[np.float64] | None, NDArray[np.float64] | None, float, float]:
    """``vecnormalize.json``'s mean, variance (``size`` entries each), clip and epsilon (its
    ``count`` checked, a positive number); no normalizer (None, None, 10, 1e-8) when
    ``agent.json`` records ``normalize`` (``recorded``) false. An ``agent.json`` that does not
    record it (written before the field) has the normalizer the file gives: none, with a
    warning, when the file does not exist.

    Raises:
        ConfigError: the file is missing while ``agent.json`` records ``normalize: true``
            (the agent would act on raw observations), present while it records false, or
            malformed.
    """
    present = file.exists() or file.is_symlink()  # a broken link: read_json says missing
    if recorded is not None and present != recorded:
        raise ConfigError(
            f"{file}: missing, but {file.parent / AGENT_FILE} records normalize: true (the agent "
            "acts on observations normalized by its statistics)"
            if recorded
            else f"{file}: present, but {file.parent / AGENT_FILE} records normalize: false"
        )
    if not present:
        if recorded is None:
            warnings.warn(
                f"{file.parent / AGENT_FILE} does not record whether the agent normalizes its "
                f"observations (normalize, written since) and {file.name} is absent: the agent "
                "acts on raw observations, wrongly if its normalizer's file was lost",
                stacklevel=3,
            )
        return None, None, 10.0, 1e-8
    stats = read_json(file)
    if set(stats) != set(NORMALIZER_KEYS):
        raise ConfigError(f"{file}: keys must be {list(NORMALIZER_KEYS)}, got {sorted(stats)}")
    arrays = []
    for key in ("mean", "var"):
        value = stats[key]
        ok = isinstance(value, list) and all(finite_number(v) is not None for v in value)
        array = np.array([finite_number(v) for v in value], dtype=np.float64) if ok else np.empty(0)
        if not ok or array.shape != (size,):
            raise ConfigError(f"{file}: {key} must be {size} finite numbers")
        arrays.append(array)
    if np.any(arrays[1] < 0):
        raise ConfigError(f"{file}: var must be >= 0")
    scalars = []
    for key in ("count", "clip_obs", "epsilon"):
        number = finite_number(stats[key])
        if number is None or number <= 0:
            raise ConfigError(f"{file}: {key} must be a positive number, got {stats[key]!r}")
        scalars.append(number)
    return arrays[0], arrays[1], scalars[1], scalars[2]
