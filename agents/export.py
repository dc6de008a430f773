"""Ship a trained agent as the package's ``pretrained`` policy (the acting files only).

    python train.py                                   # trains and evaluates runs/default/seed_0
    python -m agents.export runs/default/seed_0/agent # copies it to agents/pretrained/

Checks the agent by loading it (:func:`agents.policy.load_agent`), then copies
``policy.safetensors`` (the network without optimizer state), ``agent.json``, ``env.json`` and
``vecnormalize.json``: data only, everything the evaluation needs to act, well under 1 MB.

    python -m agents.export --from-pickle OLD_AGENT --to NEW_DIR

converts an agent saved by an earlier version (``policy.pt``, or ``model.zip`` for a recurrent
one: pickles, which run code when loaded) into these files. Run it only on a machine where you
trust ``OLD_AGENT``: it is the one place that unpickles, and only when asked to.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

from agents import PRETRAINED
from agents.policy import AGENT_FILE, ENV_FILE, NORMALIZER_FILE, load_agent
from imm_gym.validation import ConfigError

#: The acting files (``vecnormalize.json`` only if the agent was trained with a normalizer).
FILES = ("policy.safetensors", AGENT_FILE, ENV_FILE, NORMALIZER_FILE)


def export(source: Path, target: Path = PRETRAINED) -> list[Path]:
    """Copy the acting files of the agent directory ``source`` to ``target``, after checking
    that they load.

    Raises:
        FileNotFoundError: ``source`` is not an agent directory.
        ConfigError: one of its files is malformed (the message names it).
    """
    load_agent(source)
    target.mkdir(parents=True, exist_ok=True)
    return [
        Path(shutil.copy2(source / name, target / name))
        for name in FILES
        if (source / name).is_file()
    ]


def convert_pickled(source: Path, target: Path) -> list[Path]:
    """Write the data-only files of an agent saved in the earlier pickled format.

    Unpickles ``source/policy.pt`` (``source/model.zip`` for a recurrent agent) with SB3's
    loaders — code in those files runs — then writes the network's description into
    ``agent.json`` and its tensors into ``policy.safetensors``, and copies ``env.json`` and
    ``vecnormalize.json``; the result is checked by loading it.
    """
    from agents.asymmetric import AsymmetricActorCriticPolicy
    from agents.network import policy_spec, save_weights
    from agents.policy import read_json

    meta = read_json(source / AGENT_FILE)
    if meta.get("algo") == "recurrent-ppo":
        from sb3_contrib import RecurrentPPO

        policy = RecurrentPPO.load(source / "model.zip", device="cpu").policy
    else:
        from stable_baselines3.common.policies import ActorCriticPolicy

        cls = AsymmetricActorCriticPolicy if meta.get("critic_dims", 0) else ActorCriticPolicy
        policy = cls.load(str(source / "policy.pt"), device="cpu")
    target.mkdir(parents=True, exist_ok=True)
    save_weights(policy, target)
    meta["policy"] = policy_spec(policy)
    (target / AGENT_FILE).write_text(json.dumps(meta, indent=2))
    for name in (ENV_FILE, NORMALIZER_FILE):
        if (source / name).is_file() and source.resolve() != target.resolve():
            shutil.copy2(source / name, target / name)
    load_agent(target)
    return [target / name for name in FILES if (target / name).is_file()]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m agents.export",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("source", type=Path, help="a trained agent's directory (OUT/seed_S/agent)")
    parser.add_argument("--to", type=Path, default=PRETRAINED, help="target directory")
    parser.add_argument(
        "--from-pickle",
        action="store_true",
        help="SOURCE is an agent of the earlier pickled format: unpickle it (this runs code in "
        "its files: only on a machine where you trust them) and write the data-only files",
    )
    args = parser.parse_args(argv)
    try:
        if args.from_pickle:
            copied = convert_pickled(args.source, args.to)
        else:
            copied = export(args.source, args.to)
    except (FileNotFoundError, ConfigError) as err:
        parser.error(str(err))
    size = sum(p.stat().st_size for p in copied)
    print(f"exported {len(copied)} files ({size / 1024:.0f} KiB) to {args.to}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
