"""``python -m imm_gym.track``: any policy on recorded measurements (:mod:`imm_gym.cli.track`;
from Python, :func:`imm_gym.run_policy`)."""

from imm_gym.cli.track import main

if __name__ == "__main__":
    raise SystemExit(main())
