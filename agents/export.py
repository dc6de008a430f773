"""Ship a trained agent, or an ensemble of them, as the package's ``pretrained`` policy (the
acting files only).

    python train.py                                   # trains and evaluates runs/default/seed_0
    python -m agents.export runs/default/seed_0/agent # copies it to agents/pretrained/
    python train.py --seed 0 1 2 3 4 --no-eval --out runs/final
    python -m agents.export runs/final/ensemble       # the five agents as one policy

Checks the policy by loading it, then copies ``policy.safetensors`` (the network without
optimizer state), ``agent.json``, ``env.json`` and ``vecnormalize.json``: data only, everything
the evaluation needs to act, about 340 KiB an agent. An ensemble's members are copied into
``seed_S/`` subdirectories (``member_K/`` when their seeds do not tell them apart) named by a new
``ensemble.json``; a stay selector's ``selector.json``, ``env.json`` and networks are copied as
they are. The network of a ``learned`` detector that ``env.json`` names is copied beside it,
once read as a detector file (``detector_weights`` is refused with any other detector). The
target is replaced as a whole — it must be absent, empty or a policy exported before, holding
nothing an export does not write (a checkpoint's resume files, a user's files are refused) — so
no file of the previous policy stays.

    python -m agents.export --from-pickle OLD_AGENT --to NEW_DIR

converts an agent saved by an earlier version (``policy.pt``, or ``model.zip`` for a recurrent
one: pickles, which run code when loaded) into these files, replacing ``NEW_DIR`` as the export
replaces its target (``--to`` is required here). Run it only on a machine where you trust
``OLD_AGENT``: it is the one place that unpickles, and only when asked to.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from agents import PRETRAINED
from agents.ensemble import (
    ENSEMBLE_FILE,
    is_ensemble,
    load_ensemble,
    member_paths,
    write_ensemble,
)
from agents.policy import (
    AGENT_FILE,
    ENV_FILE,
    NORMALIZER_FILE,
    agent_directory,
    load_agent,
    read_json,
)
from agents.selector import SELECTOR_FILE, is_selector, load_selector
from imm_gym.validation import ConfigError

#: The acting files (``vecnormalize.json`` only if the agent was trained with a normalizer).
FILES = ("policy.safetensors", AGENT_FILE, ENV_FILE, NORMALIZER_FILE)
#: The name of a learned detector's network copied beside a policy that names one.
DETECTOR_FILE = "detector.safetensors"


def export(source: Path, target: Path = PRETRAINED) -> list[Path]:
    """Replace ``target`` by the acting files of ``source`` — an agent directory, an
    ensemble's (:mod:`agents.ensemble`) or a stay selector's (:mod:`agents.selector`), or a file
    in it as their loaders take it (``DIR/agent.json`` is ``DIR``) — after checking that they
    load. Returns the files written.

    Raises:
        FileNotFoundError: ``source`` is neither an agent nor an ensemble directory.
        ConfigError: one of its files is malformed (the message names it), or ``target`` holds
            something other than an exported policy.
    """
    def write(staging: Path) -> None:
        """The acting files of ``source`` into ``staging``, checked by loading them."""
        if is_selector(source):
            directory = source.parent if source.name == SELECTOR_FILE else source
            selector = read_json(directory / SELECTOR_FILE)
            overrides = load_selector(directory).env_overrides
            files = [SELECTOR_FILE, ENV_FILE, *selector["members"]]
            _copy_agent(directory, staging, overrides, files)
            load_selector(staging)
        elif is_ensemble(source):
            ensemble = load_ensemble(source)
            members = member_paths(source)
            names = _member_names(members)
            for member, policy, name in zip(members, ensemble.members, names, strict=True):
                _copy_agent(member, staging / name, policy.env_overrides)
            write_ensemble(staging, [staging / name for name in names])
        else:
            agent = load_agent(source)  # its directory, or a file in it
            _copy_agent(agent_directory(source), staging, agent.env_overrides)

    return _replace(target, write)


def _replace(target: Path, write: Callable[[Path], None]) -> list[Path]:
    """Replace ``target`` by the directory ``write(staging)`` writes, once
    :func:`_check_replaceable` allows it. Returns the files written.

    ``staging`` is in a fresh directory beside the target (no directory of the user's is
    reused), renamed into place once ``write`` returns; nothing is left beside the target, and
    the target is untouched if ``write`` raises.
    """
    _check_replaceable(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".export",
                                    dir=target.parent))
    staging = scratch / target.name
    try:
        write(staging)
        shutil.rmtree(target, ignore_errors=True)
        staging.rename(target)
    finally:  # nothing left beside the target
        shutil.rmtree(scratch, ignore_errors=True)
    return sorted(p for p in target.rglob("*") if p.is_file())


def _copy_agent(
    source: Path, target: Path, overrides: Mapping[str, Any], files: Sequence[str] = FILES
) -> None:
    """Copy the acting files of the policy directory ``source`` into ``target``, ``overrides``
    the environment overrides its loader read (:func:`agents.policy.read_env_file`: a
    ``detector_weights`` made absolute). The network of a ``learned`` detector goes beside them
    as :data:`DETECTOR_FILE`, named relative, once
    :meth:`~imm_gym.sim.learned_detector.DetectorNetwork.load` has accepted it (a regular file
    holding a detector network): no other file is copied.

    Raises:
        ConfigError: ``detector_weights`` is given for another detector than ``learned``, or
            names no detector file; the message names ``env.json``.
    """
    from imm_gym.sim.env_config import EnvConfig
    from imm_gym.sim.learned_detector import DetectorNetwork

    weights = overrides.get("detector_weights")
    if weights is not None:
        if overrides.get("detector") != "learned":
            raise ConfigError(
                f"{source / ENV_FILE}: detector_weights must be null (absent) unless detector is "
                f"'learned', the one that reads it; got {weights!r} with detector "
                f"{overrides.get('detector', EnvConfig.detector)!r}"
            )
        try:
            DetectorNetwork.load(weights)
        except ConfigError as err:
            raise ConfigError(f"{source / ENV_FILE}: {err}") from None
    target.mkdir(parents=True)
    for name in files:
        if (source / name).is_file():
            shutil.copy2(source / name, target / name)
    if weights is not None:
        shutil.copy2(weights, target / DETECTOR_FILE)
        env = read_json(source / ENV_FILE)
        (target / ENV_FILE).write_text(
            json.dumps({**env, "detector_weights": DETECTOR_FILE}, indent=2) + "\n"
        )


def _member_names(members: Sequence[Path]) -> list[str]:
    """``seed_S`` for each member when their ``agent.json`` seeds are distinct, else
    ``member_K``."""
    seeds = [read_json(m / AGENT_FILE).get("seed") for m in members]
    if all(isinstance(s, int) for s in seeds) and len(set(seeds)) == len(seeds):
        return [f"seed_{s}" for s in seeds]
    return [f"member_{k}" for k in range(len(members))]


def _check_replaceable(target: Path) -> None:
    """Refuse to replace a file, or a directory holding anything an export does not write
    (:func:`_exported`): a checkpoint's resume files, an agent's training record or a user's
    files would go with it.

    Raises:
        ConfigError: naming the target and the files an export does not write.
    """
    if target.is_file():
        raise ConfigError(f"{target}: the export replaces its target, which must be absent, "
                          f"empty or a policy exported before, not a file")
    if not target.is_dir():
        return
    unexpected = sorted(str(p.relative_to(target)) for p in target.rglob("*")
                        if p.relative_to(target) not in _exported(target))
    if unexpected:
        more = f" and {len(unexpected) - 5} more" if len(unexpected) > 5 else ""
        raise ConfigError(
            f"{target}: the export replaces its target, which must be absent, empty or a policy "
            f"exported before; it holds {unexpected[:5]}{more}, which an export does not write"
        )


def _exported(target: Path) -> set[Path]:
    """The paths (relative to ``target``) an export writes into ``target`` as the policy it
    holds: an agent's :data:`FILES` and :data:`DETECTOR_FILE`; a selector's
    ``selector.json``, ``env.json``, detector and the members it names; an ensemble's
    ``ensemble.json`` and the member directories it names, each an agent's files."""
    agent = {Path(name) for name in (*FILES, DETECTOR_FILE)}
    for manifest in (SELECTOR_FILE, ENSEMBLE_FILE):
        if (target / manifest).is_file():
            try:
                members = read_json(target / manifest).get("members")
            except ConfigError:  # not a manifest an export writes: its files are not either
                members = None
            names = [m for m in members if isinstance(m, str) and m not in ("", ".", "..")
                     and Path(m).name == m] if isinstance(members, list) else []
            if manifest == SELECTOR_FILE:
                return {Path(SELECTOR_FILE), Path(ENV_FILE), Path(DETECTOR_FILE),
                        *map(Path, names)}
            return {Path(ENSEMBLE_FILE), *map(Path, names),
                    *(Path(name) / file for name in names for file in agent)}
    return agent if (target / AGENT_FILE).is_file() else set()


def convert_pickled(source: Path, target: Path) -> list[Path]:
    """Replace ``target`` by the data-only files of an agent saved in the earlier pickled format.

    Once ``target`` may be replaced as :func:`export` replaces it (absent, empty or a policy
    exported before), unpickles ``source/policy.pt`` (``source/model.zip`` for a recurrent
    agent) with SB3's loaders — code in those files runs — and replaces ``target`` by the
    network's description in ``agent.json`` (``normalize`` whether ``vecnormalize.json`` is
    copied) and its tensors in ``policy.safetensors``, with ``env.json`` and
    ``vecnormalize.json`` copied; the result is checked by loading it. Returns the files
    written.

    Raises:
        ConfigError: ``source`` is not an agent of the earlier pickled format, the result does
            not load, or ``target`` holds something other than an exported policy.
    """
    from agents.asymmetric import AsymmetricActorCriticPolicy
    from agents.network import policy_spec, save_weights
    from agents.policy import read_json

    meta = read_json(source / AGENT_FILE)
    recurrent = meta.get("algo") == "recurrent-ppo"
    file = source / ("model.zip" if recurrent else "policy.pt")
    if not file.is_file():
        raise ConfigError(f"{file}: missing (an agent of the earlier pickled format holds it)")

    def write(staging: Path) -> None:
        """The converted agent's files into ``staging``, checked by loading them."""
        try:
            if recurrent:
                from sb3_contrib import RecurrentPPO

                policy = RecurrentPPO.load(file, device="cpu").policy
            else:
                from stable_baselines3.common.policies import ActorCriticPolicy

                cls = (AsymmetricActorCriticPolicy if meta.get("critic_dims", 0)
                       else ActorCriticPolicy)
                policy = cls.load(str(file), device="cpu")
        except Exception as err:  # whatever the unpickler or SB3 raise on a file of another kind
            raise ConfigError(f"{file}: not an agent of the earlier pickled format "
                              f"({type(err).__name__}: {err})") from None
        staging.mkdir(parents=True)
        save_weights(policy, staging)
        meta["policy"] = policy_spec(policy)
        meta["normalize"] = (source / NORMALIZER_FILE).is_file()
        (staging / AGENT_FILE).write_text(json.dumps(meta, indent=2))
        for name in (ENV_FILE, NORMALIZER_FILE):
            if (source / name).is_file():
                shutil.copy2(source / name, staging / name)
        load_agent(staging)

    return _replace(target, write)  # the target checked before anything is unpickled


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m agents.export",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "source", type=Path,
        help="a trained agent's directory (OUT/seed_S/agent), an ensemble's (OUT/ensemble) or "
        "a stay selector's",
    )
    parser.add_argument(
        "--to", type=Path, default=None,
        help="target directory (default agents/pretrained; required with --from-pickle)",
    )
    parser.add_argument(
        "--from-pickle",
        action="store_true",
        help="SOURCE is an agent of the earlier pickled format: unpickle it (this runs code in "
        "its files: only on a machine where you trust them) and write the data-only files",
    )
    args = parser.parse_args(argv)
    if args.from_pickle and args.to is None:
        parser.error("--from-pickle needs --to NEW_DIR, the converted agent's directory")
    target = PRETRAINED if args.to is None else args.to
    try:
        if args.from_pickle:
            copied = convert_pickled(args.source, target)
        else:
            copied = export(args.source, target)
    except (FileNotFoundError, ConfigError) as err:
        parser.error(str(err))
    size = sum(p.stat().st_size for p in copied)
    print(f"exported {len(copied)} files ({size / 1024:.0f} KiB) to {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
