"""``python -m imm_gym.evaluate``: the evaluation command line (:mod:`imm_gym.cli.evaluate`)."""

from imm_gym.cli.evaluate import main

if __name__ == "__main__":
    raise SystemExit(main())
