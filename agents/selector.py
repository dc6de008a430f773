r"""A switching prior chosen by supervision, as a policy the evaluation loads by path.

The stay selector (``examples/stay_selector.py``; docs/experiments.md, "Where in the episode the
agents lose, and a stay chosen by supervision") holds a grid of switching priors, each a stay
``s`` and a detector share ``v`` of the ``learned-prior`` family
(:func:`~imm_gym.sim.stay_bank.detector_tpm_rows`)::

    Pi(s, v) = r I + (1 - r) 1 q^T,   q = (1 - v) / M + v b,   r = (s - 1/M) / (1 - 1/M),

``b`` the learned detector's belief, observed as the last ``M`` entries of the observation. A
network predicts each prior's future squared error (log, relative to the priors' mean) from the
observation, and every step the policy sets the TPM to the prior of the smallest prediction: the
TPM is a switching prior by construction. Several fitted networks act as one on their mean
prediction.

How the prior reaches the tracker depends on the action mode it was fitted in (``env.json``):

* ``stay`` (one share ``v``, the environment's ``detector_share``, ``stay_base: uniform``): each
  row's diagonal ``r + (1 - r) q_i`` in logits from the base's ``q_i``, over ``logit_scale``
  (:func:`stay_action`; the off-diagonal keeps ``q``'s proportions);
* ``set`` (shares per prior): each row's logits ``log Pi_ij`` centred and over ``logit_scale``
  (:func:`set_action`), exact wherever every entry is at least ``p_min``.

A selector with a prior the action cannot set at some belief (its entries beyond ``[-1, 1]``
before the clip) is refused, naming the range of ``logit_scale`` that reaches it
(:func:`check_reach`).

A selector is a directory of data files only — loading never unpickles, so it cannot run code:

* ``selector.json``: ``{"format": "imm_gym-stay-selector", "combine": "mean_prediction",
  "priors": [[s, v], ...], "hidden": H, "members": ["net_0.safetensors", ...]}`` and optionally
  ``"trained_across"`` (the trackers of the further training files) and ``"fit"`` (how it was
  fitted: a record, not read);
* ``env.json``: the :class:`~imm_gym.EnvConfig` overrides it reads and acts in;
* the members: each network's tensors (two tanh layers of ``H``, :func:`network`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from safetensors.torch import save_file

from agents.network import load_tensors
from agents.policy import (
    AGENT_FILE,
    ENSEMBLE_FILE,
    ENV_FILE,
    read_env_file,
    read_manifest,
    read_trackers,
    refuse_other_policy,
    write_env_file,
)
from agents.schema import MAX_WIDTH
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.features import observation_size
from imm_gym.sim.stay_bank import detector_tpm_rows
from imm_gym.tracking.tpm import apply_floor
from imm_gym.validation import ConfigError

Array = NDArray[np.float64]

SELECTOR_FILE = "selector.json"
FORMAT = "imm_gym-stay-selector"
COMBINE = ("mean_prediction",)
SELECTOR_KEYS = ("format", "combine", "priors", "hidden", "members", "trained_across", "fit")
#: The action modes a selector acts in (module docstring).
SELECTOR_MODES = ("stay", "set")
#: The most priors a selector may choose among. Its networks give one prediction per prior, so
#: ``selector.json``'s priors set the size of their last layer, ``hidden`` times as many numbers
#: (16 MiB of float32 at this bound and the widest ``hidden``, :data:`~agents.schema.MAX_WIDTH`;
#: a 16 MiB ``selector.json`` lists some 700 000 priors, 11 GiB). The grids of
#: ``examples/stay_selector.py`` are some tens of priors (the bank's stays at a few shares).
MAX_PRIORS = 1024


def network(inputs: int, outputs: int, hidden: int = 256) -> torch.nn.Sequential:
    """Two tanh layers of ``hidden`` units: observation -> one prediction per prior."""
    return torch.nn.Sequential(
        torch.nn.Linear(inputs, hidden), torch.nn.Tanh(),
        torch.nn.Linear(hidden, hidden), torch.nn.Tanh(),
        torch.nn.Linear(hidden, outputs),
    )


def stay_action(stays: Array, belief: Array, share: float, gain: float) -> Array:
    """``(N, M)`` the ``stay`` action (uniform base, detector share ``share``, ``logit_scale``
    ``gain``) whose rows are ``Pi(s, v)``: each row's diagonal ``r + (1 - r) q_i`` in logits from
    the base's ``q_i`` (the off-diagonal keeps ``q``'s proportions)."""
    M = belief.shape[-1]
    q = (1.0 - share) / M + share * belief
    r = ((stays - 1.0 / M) / (1.0 - 1.0 / M))[:, None]
    target = r + (1.0 - r) * q
    logit = np.log(target) - np.log1p(-target) - (np.log(q) - np.log1p(-q))
    return np.clip(logit / gain, -1.0, 1.0)


def set_action(stays: Array, shares: Array, belief: Array, gain: float, p_min: float) -> Array:
    """``(N, M*M)`` the ``set`` action (``logit_scale`` ``gain``) whose rows are ``Pi(s, v)``
    floored to ``p_min`` as the environment floors them
    (:func:`~imm_gym.tracking.tpm.apply_floor`): each row's logits centred between its largest
    and smallest, over ``gain`` (exact while ``gain >= log(1 / p_min) / 2``)."""
    logits = np.log(apply_floor(detector_tpm_rows(stays, belief, shares), p_min))
    centre = 0.5 * (logits.max(axis=-1, keepdims=True) + logits.min(axis=-1, keepdims=True))
    return np.clip((logits - centre) / gain, -1.0, 1.0).reshape(len(stays), -1)


class StaySelector:
    """The policy (the ``predict`` protocol of the evaluation): the prior of the smallest
    predicted future error, the mean of ``nets``' predictions.

    Args:
        nets: the fitted networks (one output per prior).
        priors: ``(P, 2)`` each prior's stay ``s`` and share ``v``.
        env_overrides: the environment it acts in (action mode, features, ...).
        obs_size: entries of one observation (the networks' input).
        source: where it comes from, for messages.
        trained_across: the trackers of further training files (the evaluation's notes).
    """

    name = "selector"

    def __init__(
        self, nets: Sequence[torch.nn.Module], priors: Any, env_overrides: Mapping[str, Any],
        obs_size: int, source: str = "the selector",
        trained_across: Sequence[Mapping[str, Any]] = (),
    ) -> None:
        self.nets = list(nets)
        self.env_overrides = dict(env_overrides)
        self.obs_size = obs_size
        self.source = source
        self.trained_across = tuple(dict(t) for t in trained_across)
        config = EnvConfig.build({
            key: tuple(value) if key == "obs_features" else value
            for key, value in self.env_overrides.items()
        })
        #: ``(P, 2)`` each prior's stay and share, checked (:func:`check_priors`)
        self.priors = check_priors(source, priors, config)
        #: the bank's models ``M``: the belief is the observation's last ``M`` entries
        self.M = len(config.bank)
        self.mode, self.gain = config.action_mode, config.logit_scale
        self.p_min, self.share = config.p_min, config.detector_share

    def choose(self, obs: NDArray[Any]) -> NDArray[np.int64]:
        """``(N,)`` the index of the chosen prior for each observation ``(N, obs_size)``."""
        x = torch.from_numpy(np.asarray(obs, dtype=np.float32))
        with torch.no_grad():
            predicted = torch.stack([net(x) for net in self.nets]).mean(0)
        return predicted.argmin(1).numpy()

    def predict(
        self, observation: NDArray[Any], state: Any = None,
        episode_start: NDArray[np.bool_] | None = None, deterministic: bool = True,
    ) -> tuple[Array, None]:
        """The action that sets the chosen prior (module docstring); no state."""
        obs = np.asarray(observation)
        single = obs.ndim == 1
        obs = obs[None] if single else obs
        if obs.ndim != 2 or obs.shape[1] != self.obs_size:
            raise ConfigError(f"{self.source} reads observations of {self.obs_size} entries, "
                              f"the environment gives {obs.shape[1:]}")
        belief = np.asarray(obs[:, -self.M:], dtype=np.float64)
        s, v = self.priors[self.choose(obs)].T
        if self.mode == "stay":
            action = stay_action(s, belief, self.share, self.gain)
        else:
            action = set_action(s, v, belief, self.gain, self.p_min)
        return (action[0] if single else action), None


def combine(selectors: Sequence[StaySelector]) -> StaySelector:
    """Several selectors as one, every network of each a member (the mean prediction).

    Raises:
        ConfigError: they choose among other priors or act in another environment.
    """
    first = selectors[0]
    for other in selectors[1:]:
        if not np.array_equal(other.priors, first.priors) or (
            other.env_overrides != first.env_overrides
        ):
            raise ConfigError(f"{other.source} has other priors or another environment than "
                              f"{first.source}: they cannot act as one")
    nets = [net for one in selectors for net in one.nets]
    return StaySelector(nets, first.priors, first.env_overrides, first.obs_size,
                        " + ".join(one.source for one in selectors), first.trained_across)


def check_priors(where: str, priors: Any, config: EnvConfig) -> Array:
    """``priors`` as a ``(P, 2)`` array after checking it against the environment ``config``:
    2 to :data:`MAX_PRIORS` pairs of numbers (a string such as ``"0.6"`` or a boolean is
    refused, not read as one), stays in ``[1/M, 1)``, shares in ``[0, 1]``; in ``stay`` mode at
    ``stay_base: uniform``, every share the environment's ``detector_share``; every prior within
    the action's reach at every belief (:func:`check_reach`)."""
    M = len(config.bank)
    rows = priors.tolist() if isinstance(priors, np.ndarray) else priors
    numbers = isinstance(rows, (list, tuple)) and all(
        isinstance(row, (list, tuple))
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row)
        for row in rows
    )
    try:
        array = np.array(rows, dtype=np.float64) if numbers else np.empty(0)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond floats
        array = np.empty(0)
    if array.ndim != 2 or array.shape[1:] != (2,) or len(array) < 2:
        raise ConfigError(f"{where}: priors must be a list of at least two [stay, share] pairs "
                          f"of numbers, got {priors!r:.200}")
    if len(array) > MAX_PRIORS:
        raise ConfigError(f"{where}: priors must be at most {MAX_PRIORS} [stay, share] pairs, got "
                          f"{len(array)}")
    s, v = array.T
    if not (np.all(s >= 1.0 / M - 1e-12) and np.all(s < 1.0)):
        raise ConfigError(f"{where}: every stay must be in [1/{M}, 1), got {s.tolist()}")
    if not (np.all(v >= 0.0) and np.all(v <= 1.0)):
        raise ConfigError(f"{where}: every share must be in [0, 1], got {v.tolist()}")
    if config.action_mode not in SELECTOR_MODES:
        raise ConfigError(f"{where}: the environment's action_mode must be one of "
                          f"{list(SELECTOR_MODES)}, got {config.action_mode!r}")
    if config.action_mode == "stay" and (
        config.stay_base != "uniform" or not np.all(v == config.detector_share)
    ):
        raise ConfigError(f"{where}: in the stay action mode every share must be the "
                          f"environment's detector_share ({config.detector_share}) at "
                          f"stay_base 'uniform' (got {config.stay_base!r})")
    if "detector_belief" not in config.obs_features or (
        config.obs_features[-1] != "detector_belief"
    ):
        raise ConfigError(f"{where}: the environment's obs_features must end with "
                          f"'detector_belief' (the belief the priors are computed from)")
    check_reach(where, array, config)
    return array


def check_reach(where: str, priors: Array, config: EnvConfig) -> None:
    """Check that the action of ``config``'s mode sets every prior ``(P, 2)`` at every belief,
    its entries within ``[-1, 1]`` before :func:`stay_action` and :func:`set_action` clip them.

    * ``stay``: row ``i``'s entry is ``log(1 + r / ((1 - r) q_i)) / logit_scale``, largest where
      ``q_i`` is least, ``(1 - v) / M`` (a belief of 0 in mode ``i``): in reach while
      ``r <= (exp(logit_scale) - 1) (1 - r) (1 - v) / M``;
    * ``set``: a row's largest entry is half the log-ratio of its largest to its smallest
      probability (floored to ``p_min``) over ``logit_scale``, largest at a belief certain of one
      mode: in reach while that half is at most ``logit_scale`` at each of the ``M`` certain
      beliefs (always so with ``logit_scale >= log(1 / p_min) / 2``).

    Raises:
        ConfigError: a prior out of reach, naming ``env.json``'s ``logit_scale`` (and in the
            ``stay`` mode ``detector_share``) and the range that reaches it.
    """
    M, gain = len(config.bank), config.logit_scale
    s, v = priors.T
    r = (s - 1.0 / M) / (1.0 - 1.0 / M)
    if config.action_mode == "stay":
        out = np.flatnonzero(r > np.expm1(gain) * (1.0 - r) * (1.0 - v) / M)
        if len(out):
            k = out[np.argmax(r[out])]  # the stickiest prior out of reach
            with np.errstate(divide="ignore"):  # a share of 1: no logit_scale reaches it
                need = np.log1p(r[k] / ((1.0 - r[k]) * (1.0 - v[k]) / M))
            share = 1.0 - M * r[k] / ((1.0 - r[k]) * np.expm1(gain))
            ranges = [f"logit_scale >= {need:.6g}"] if np.isfinite(need) else []
            ranges += [f"detector_share in [0, {share:.6g}]"] if share >= 0.0 else []
            needs = " or ".join(ranges) or "a smaller detector_share and a larger logit_scale"
            raise ConfigError(f"{where}: the stay action does not reach the stay {s[k]:.6g} at "
                              f"{ENV_FILE}'s detector_share {v[k]:.6g} and logit_scale "
                              f"{gain:.6g}: it needs {needs}")
        return
    certain = np.eye(M)[:, None]  # (M, 1, M): each certain belief, for every prior
    rows = apply_floor(detector_tpm_rows(s, certain, v), config.p_min)
    with np.errstate(divide="ignore"):  # a zero entry (p_min 0, share 1): out of any reach
        half = 0.5 * (np.log(rows.max(axis=-1)) - np.log(rows.min(axis=-1))).max(axis=(0, 2))
    out = np.flatnonzero(half > gain)
    if len(out):
        k = out[np.argmax(half[out])]
        needs = (f"logit_scale >= {half[k]:.6g}" if np.isfinite(half[k])
                 else "p_min > 0 (a zero entry is out of any logit_scale's reach)")
        raise ConfigError(f"{where}: the set action does not set the prior [{s[k]:.6g}, "
                          f"{v[k]:.6g}] (floored to p_min {config.p_min:.6g}) at {ENV_FILE}'s "
                          f"logit_scale {gain:.6g}: it needs {needs}")


def is_selector(path: str | Path) -> bool:
    """Whether ``path`` is a selector's directory (or its ``selector.json``)."""
    path = Path(path)
    return path.name == SELECTOR_FILE or (path / SELECTOR_FILE).is_file()


def check_member(
    where: str, tensors: Mapping[str, torch.Tensor], obs_size: int, P: int, hidden: int
) -> None:
    """A member's tensors are the :func:`network`'s for an observation of ``obs_size`` entries,
    ``P`` priors and width ``hidden``: the same names and shapes, every one float32.

    Raises:
        ConfigError: a tensor of another dtype, a name missing or extra, or another shape;
            the message begins with ``where``.
    """
    other = sorted(name for name, t in tensors.items() if t.dtype != torch.float32)
    if other:
        raise ConfigError(f"{where}: tensors {other} are not float32")
    with torch.device("meta"):  # the network's names and shapes, nothing allocated
        expected = {name: tuple(t.shape)
                    for name, t in network(obs_size, P, hidden).state_dict().items()}
    shapes = {name: tuple(t.shape) for name, t in tensors.items()}
    wrong = sorted(set(shapes) ^ set(expected)) or sorted(
        name for name in shapes if shapes[name] != expected[name]
    )
    if wrong:
        name = wrong[0]
        raise ConfigError(f"{where} does not fit an observation of {obs_size} entries and {P} "
                          f"priors at width {hidden} (tensor {name!r}: "
                          f"{shapes.get(name, 'absent')} in the file, "
                          f"{expected.get(name, 'absent')} in the network)")


def load_selector(path: str | Path) -> StaySelector:
    """Load a selector from its directory (or its ``selector.json``), every file checked.

    Raises:
        ConfigError: a file is missing or malformed (unknown keys, another format, priors out
            of range, a member that is not there or whose tensors do not fit the observation
            and the priors); the message names the file.
    """
    path = Path(path)
    directory = path.parent if path.name == SELECTOR_FILE else path
    file = directory / SELECTOR_FILE
    data = read_manifest(file, SELECTOR_KEYS, FORMAT, COMBINE)
    hidden = data.get("hidden")
    if not isinstance(hidden, int) or isinstance(hidden, bool) or not 1 <= hidden <= MAX_WIDTH:
        raise ConfigError(
            f"{file}: hidden must be an integer in [1, {MAX_WIDTH}], got {hidden!r}"
        )
    members = data.get("members")
    if (not isinstance(members, list) or not members
            or not all(isinstance(m, str) and m and "/" not in m for m in members)
            or len(set(members)) != len(members)):
        raise ConfigError(f"{file}: members must be a non-empty list of distinct file names "
                          f"in the selector's directory")
    trained_across = read_trackers(file, data.get("trained_across", []))
    env, obs_size, _ = read_env_file(directory / ENV_FILE, None)
    # the priors and the environment checked first, the members' tensors loaded into it
    selector = StaySelector([], data.get("priors"), env, obs_size, f"selector {str(file)!r}",
                            trained_across)
    P = len(selector.priors)
    for member in members:
        if not (directory / member).is_file():
            raise ConfigError(f"{file}: member {member!r} is not a file of the directory")

        def fits(declared: dict[str, torch.Tensor], member: str = member) -> None:
            """The member's declared tensors: the network's names and shapes, float32."""
            check_member(f"{file}: member {member!r}", declared, obs_size, P, hidden)

        # safetensors only, every number finite; names, dtypes and shapes checked from the
        # header before a tensor is read or the network built
        tensors = load_tensors(directory / member, fits)
        net = network(obs_size, P, hidden)
        net.load_state_dict(tensors)
        selector.nets.append(net.eval())
    return selector


def save_selector(
    directory: str | Path, nets: Sequence[torch.nn.Module], priors: Array,
    env_overrides: Mapping[str, Any], trained_across: Sequence[Mapping[str, Any]] = (),
    fit: Mapping[str, Any] | None = None,
) -> StaySelector:
    """Write a selector's directory (module docstring; the width ``hidden`` is the networks'
    first layer's) and load it back, checked.

    Raises:
        ConfigError: the networks are of different widths (``selector.json`` holds one), the
            priors are not ones the environment's action reaches (:func:`check_priors`), or a
            network does not read the environment's observation into one prediction per prior
            (:func:`check_member`) or holds NaN or infinite weights, or ``directory`` holds
            an agent's or an ensemble's file (a policy of its own) — before anything is
            written.
    """
    widths = sorted({net[0].out_features for net in nets})
    if len(widths) > 1:
        raise ConfigError(f"the networks of {directory} have different widths {widths}: a "
                          f"selector's directory holds networks of one width")
    hidden = widths[0]
    directory = Path(directory)
    refuse_other_policy(directory, "a selector", (AGENT_FILE, ENSEMBLE_FILE))
    config = EnvConfig.build(dict(env_overrides))
    check_priors(str(directory / SELECTOR_FILE), priors, config)
    obs_size = observation_size(config.obs_features, len(config.bank), config.sensor.dim_z)
    members = [f"net_{k}.safetensors" for k in range(len(nets))]
    for net, member in zip(nets, members, strict=True):
        where, tensors = f"{directory / member}", net.state_dict()
        check_member(where, tensors, obs_size, len(priors), hidden)
        bad = [name for name, t in tensors.items() if not bool(torch.isfinite(t).all())]
        if bad:
            raise ConfigError(f"{where}: tensors {bad} hold NaN or infinite values")
    directory.mkdir(parents=True, exist_ok=True)
    for net, member in zip(nets, members, strict=True):
        save_file(net.state_dict(), str(directory / member))
    write_env_file(directory, env_overrides)
    data: dict[str, Any] = {
        "format": FORMAT, "combine": COMBINE[0],
        "priors": np.asarray(priors, dtype=np.float64).tolist(), "hidden": hidden,
        "members": members, "trained_across": [dict(t) for t in trained_across],
    }
    if fit is not None:
        data["fit"] = dict(fit)
    (directory / SELECTOR_FILE).write_text(json.dumps(data, indent=2) + "\n")
    return load_selector(directory)
