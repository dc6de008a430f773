"""An ensemble of trained agents as one policy: the mean of their actions.

Agents trained from different seeds of one configuration differ most where the training signal
is weakest (docs/experiments.md, "A baseline that follows the evidence, retraining on another
processor, and an ensemble of the seeds"); acting on the mean of their actions averages those
differences out. An ensemble is a directory holding one data file,
``ensemble.json``::

    {"format": "imm_gym-ensemble", "combine": "mean_action",
     "members": ["../seed_0/agent", "../seed_1/agent", ...]}

Each member is a trained agent's directory (:mod:`agents.policy`), relative to the ensemble's
directory or absolute; loading reads JSON and tensors only, never code. Every member must read
and write the same things — the :data:`~imm_gym.sim.mixture.POLICY_FIELDS` of their
``env.json`` equal (observation features, action mode, detector...) — so one observation serves
them all, and must have been trained on one bank (``env.json``'s ``bank``): the ensemble
records member 0's tracker, which the evaluation names as the one it was trained on and
compares the evaluated bank's models with (with the trackers of a mixture any member was
trained across). They may have been rewarded differently.

Build one with ``python -m agents.ensemble OUT MEMBER [MEMBER ...]`` (``OUT`` not an agent's or a
selector's directory) and evaluate it as any agent (``python -m imm_gym.evaluate --policy OUT``).
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agents.policy import (
    AGENT_FILE,
    ENSEMBLE_FILE,
    LearnedPolicy,
    agent_directory,
    load_agent,
    read_manifest,
    refuse_other_policy,
)
from agents.selector import SELECTOR_FILE, StaySelector, is_selector, load_selector
from imm_gym.sim.config_file import plain
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.mixture import POLICY_FIELDS
from imm_gym.validation import ConfigError

FORMAT = "imm_gym-ensemble"
#: How the members' actions are combined (the only rule so far).
COMBINE = ("mean_action",)
ENSEMBLE_KEYS = ("format", "combine", "members")


class EnsemblePolicy:
    """Several trained agents acting as one: :math:`a = \\frac{1}{K} \\sum_k \\pi_k(o)`, each
    member's action already clipped to ``[-1, 1]`` (so is the mean).

    Args:
        members: the loaded agents (at least one), reading and writing alike.
        source: where the ensemble comes from, for messages.
    """

    name = "ensemble"

    def __init__(self, members: Sequence[LearnedPolicy], source: str = "the ensemble") -> None:
        if not members:
            raise ConfigError(f"{source}: an ensemble needs at least one member")
        first = members[0]
        # compared as the members act: a default spelled out is the default
        acts = [EnvConfig.build(member.env_overrides) for member in members]
        for k, member in enumerate(members[1:], start=1):
            differ = [
                f for f in sorted(POLICY_FIELDS)
                if getattr(acts[k], f) != getattr(acts[0], f)
                and not (f == "detector_weights" and same_detector(acts[k], acts[0]))
            ]
            if differ or member.obs_size != first.obs_size:
                what = ", ".join(differ) if differ else "the observation size"
                raise ConfigError(
                    f"{source}: member {k} ({member.source}) reads or writes other things than "
                    f"member 0 ({first.source}): {what} differ"
                )
            if acts[k].bank != acts[0].bank:
                raise ConfigError(
                    f"{source}: member {k} ({member.source}) was trained on another bank than "
                    f"member 0 ({first.source}), whose tracker the ensemble records: "
                    f"{plain(acts[k].bank)} and {plain(acts[0].bank)}"
                )
        self.members = tuple(members)
        self.source = source
        self.env_overrides = first.env_overrides
        self.obs_size = first.obs_size
        # the trackers any member was trained on (the evaluation names the closest)
        trackers: list[dict[str, Any]] = []
        for member in members:
            for tracker in member.trained_across:
                if tracker not in trackers:
                    trackers.append(tracker)
        self.trained_across = tuple(trackers)

    @property
    def shares_models(self) -> bool:
        """Whether every member's network is shared by the models."""
        return all(member.shares_models for member in self.members)

    def for_models(self, n_models: int) -> EnsemblePolicy:
        """The ensemble of its members for a bank of ``n_models`` models
        (:meth:`LearnedPolicy.for_models`)."""
        members = [member.for_models(n_models) for member in self.members]
        if all(new is old for new, old in zip(members, self.members, strict=True)):
            return self
        return EnsemblePolicy(members, self.source)

    def predict(
        self,
        observation: NDArray[Any],
        state: Any = None,
        episode_start: NDArray[np.bool_] | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray[Any], Any]:
        """The members' mean action; ``state`` is the tuple of the members' states."""
        states = (None,) * len(self.members) if state is None else state
        actions, new_states = [], []
        for member, member_state in zip(self.members, states, strict=True):
            action, member_state = member.predict(
                observation, member_state, episode_start, deterministic
            )
            actions.append(action)
            new_states.append(member_state)
        return np.mean(actions, axis=0), tuple(new_states)


def same_detector(a: EnvConfig, b: EnvConfig) -> bool:
    """Whether ``a`` and ``b`` act alike whatever ``detector_weights`` each names: only the
    ``learned`` detector reads it (when either detector is another, it makes no difference;
    ``detector`` itself is compared apart), and two learned detectors act alike when their
    files — the shipped one for None, wherever each is (an export copies a member's detector
    beside it) — load as one network: the same window, weights and biases. Each file is read
    by :meth:`~imm_gym.sim.learned_detector.DetectorNetwork.load`, which checks it, never
    otherwise.

    Raises:
        ConfigError: a file is not a detector network (the message names it).
    """
    from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS, DetectorNetwork

    if a.detector != "learned" or b.detector != "learned":
        return True
    one, other = (DetectorNetwork.load(c.detector_weights or DEFAULT_WEIGHTS) for c in (a, b))
    arrays = (*one.weights, *one.biases), (*other.weights, *other.biases)
    return one.window == other.window and len(arrays[0]) == len(arrays[1]) and all(
        np.array_equal(x, y) for x, y in zip(*arrays, strict=True)
    )


#: The files that make a directory a policy's: an agent's, an ensemble's, a stay selector's.
POLICY_FILES = (AGENT_FILE, ENSEMBLE_FILE, SELECTOR_FILE)


def is_ensemble(path: str | Path) -> bool:
    """Whether ``path`` is an ensemble's directory (or its ``ensemble.json``)."""
    path = Path(path)
    return path.name == ENSEMBLE_FILE or (path / ENSEMBLE_FILE).is_file()


def member_paths(path: str | Path) -> list[Path]:
    """The member directories ``ensemble.json`` (in the directory ``path``, or ``path``
    itself) names, resolved, without loading them: each the directory :func:`load_agent`
    reads (:func:`~agents.policy.agent_directory`: a member named by a file in it, such as
    ``seed_0/agent.json``, is ``seed_0``).

    Raises:
        ConfigError: ``ensemble.json`` is malformed (unknown keys, another format or combine
            rule, no members, a member listed twice, by its directory or a file in it); the
            message names the file.
    """
    path = Path(path)
    directory = path.parent if path.name == ENSEMBLE_FILE else path
    file = directory / ENSEMBLE_FILE
    data = read_manifest(file, ENSEMBLE_KEYS, FORMAT, COMBINE)
    members = data.get("members")
    if (
        not isinstance(members, list)
        or not members
        or not all(isinstance(m, str) and m for m in members)
    ):
        raise ConfigError(f"{file}: members must be a non-empty list of agent directories")
    paths = []
    for m in members:
        try:
            paths.append(agent_directory(directory / m).resolve())
        except (OSError, ValueError, RuntimeError) as err:  # a NUL byte, a loop of symlinks
            raise ConfigError(f"{file}: member {m!r} is not a path ({err})") from None
    if len(set(paths)) != len(paths):
        raise ConfigError(f"{file}: a member is listed twice: {members}")
    return paths


def load_ensemble(path: str | Path) -> EnsemblePolicy:
    """Load an ensemble from its directory (or its ``ensemble.json``), every member checked.

    Raises:
        ConfigError: ``ensemble.json`` is malformed (:func:`member_paths`) or a member does not
            load or reads and writes other things than the first; the message names the file
            or the member.
    """
    path = Path(path)
    directory = path.parent if path.name == ENSEMBLE_FILE else path
    file = directory / ENSEMBLE_FILE
    loaded = []
    for member in member_paths(directory):
        name = os.path.relpath(member, directory.resolve())
        try:
            loaded.append(load_agent(member))
        except FileNotFoundError:
            raise ConfigError(f"{file}: member {name!r}: no trained agent there "
                              f"({AGENT_FILE} missing)") from None
        except ConfigError as err:
            raise ConfigError(f"{file}: member {name!r}: {err}") from None
    return EnsemblePolicy(loaded, source=f"ensemble {str(directory)!r}")


def load_policy(path: str | Path) -> LearnedPolicy | EnsemblePolicy | StaySelector:
    """A trained agent, an ensemble of them or a stay selector (:mod:`agents.selector`),
    whichever ``path`` holds: a directory, or its policy file (``agent.json``,
    ``ensemble.json``, ``selector.json``).

    Raises:
        ConfigError: ``path`` is a directory holding two or more policy files (put there by
            hand: :func:`write_ensemble` and :func:`~agents.selector.save_selector` refuse to
            write into another policy's directory), which would load one of its policies for
            another; name the file to load.
    """
    held = [f for f in POLICY_FILES if (Path(path) / f).is_file()]
    if len(held) > 1:
        raise ConfigError(
            f"{path}: holds {' and '.join(held)}, a policy each: name the one to load "
            f"({Path(path) / held[0]}, ...)"
        )
    if is_selector(path):
        return load_selector(path)
    return load_ensemble(path) if is_ensemble(path) else load_agent(path)


def write_ensemble(directory: str | Path, members: Sequence[str | Path]) -> Path:
    """Write ``directory/ensemble.json`` naming ``members`` (their directories, relative to
    ``directory``), after checking that they load as one ensemble. Returns the file.

    Raises:
        ConfigError: ``directory`` holds ``agent.json`` or ``selector.json`` (a policy of its
            own, which the ensemble would shadow or be shadowed by when the directory is
            loaded), a member is given twice (by its directory or a file in it, as
            :func:`member_paths` reads them), or the members do not load as one ensemble; all
            checked before ``directory`` is created.
        FileNotFoundError: a member is not a trained agent's directory.
    """
    directory = Path(directory)
    refuse_other_policy(directory, "an ensemble", (AGENT_FILE, SELECTOR_FILE))
    resolved = [agent_directory(m).resolve() for m in members]
    if len(set(resolved)) != len(resolved):
        raise ConfigError(f"a member is given twice: {[str(m) for m in members]}")
    EnsemblePolicy([load_agent(m) for m in members], source=str(directory))
    directory.mkdir(parents=True, exist_ok=True)
    relative = [os.path.relpath(m, directory.resolve()) for m in resolved]
    file = directory / ENSEMBLE_FILE
    data = {"format": FORMAT, "combine": COMBINE[0], "members": relative}
    file.write_text(json.dumps(data, indent=2) + "\n")
    return file


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m agents.ensemble",
        description="Write an ensemble of trained agents (the mean of their actions) to OUT.",
    )
    parser.add_argument("out", type=Path, help="the ensemble's directory")
    parser.add_argument("members", nargs="+", type=Path, help="trained agents' directories")
    args = parser.parse_args(argv)
    try:
        file = write_ensemble(args.out, args.members)
    except (ConfigError, FileNotFoundError) as err:
        parser.exit(2, f"error: {err}\n")
    print(f"wrote {file} ({len(args.members)} members)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
