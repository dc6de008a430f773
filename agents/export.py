"""Ship a trained agent as the package's ``pretrained`` policy (the acting files only).

    python train.py                                   # trains and evaluates runs/default/seed_0
    python -m agents.export runs/default/seed_0/agent # copies it to agents/pretrained/

Copies ``policy.pt`` (the network without optimizer state), ``env.json``, ``vecnormalize.json``
and ``agent.json``: everything :func:`agents.policy.load_agent` needs to act, well under 1 MB.
``model.zip`` (needed only to resume training) stays in the run directory.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

from agents import PRETRAINED

FILES = ("policy.pt", "env.json", "vecnormalize.json", "agent.json")


def export(source: Path, target: Path = PRETRAINED) -> list[Path]:
    """Copy the acting files of the agent directory ``source`` to ``target``."""
    missing = [name for name in FILES if not (source / name).is_file()]
    if missing:
        raise FileNotFoundError(f"{str(source)!r} is not a trained agent: missing {missing}")
    if json.loads((source / "agent.json").read_text()).get("algo") == "recurrent-ppo":
        raise ValueError("a recurrent agent needs model.zip to act; export a PPO agent")
    target.mkdir(parents=True, exist_ok=True)
    return [Path(shutil.copy2(source / name, target / name)) for name in FILES]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m agents.export", description=__doc__)
    parser.add_argument("source", type=Path, help="a trained agent's directory (OUT/seed_S/agent)")
    parser.add_argument("--to", type=Path, default=PRETRAINED, help="target directory")
    args = parser.parse_args(argv)
    try:
        copied = export(args.source, args.to)
    except (FileNotFoundError, ValueError) as err:
        parser.error(str(err))
    size = sum(p.stat().st_size for p in copied)
    print(f"exported {len(copied)} files ({size / 1024:.0f} KiB) to {args.to}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
