"""``python -m imm_gym.track``: any policy on recorded measurements (:mod:`imm_gym.cli.track`).
Run it, don't import it: importing ``imm_gym.track`` would shadow the function ``imm_gym.track``."""

from imm_gym.cli.track import main

if __name__ == "__main__":
    raise SystemExit(main())
