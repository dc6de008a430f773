"""The main job: train a PPO agent to adapt the IMM's TPM, then evaluate it against the baselines.

Not implemented yet: training lands with the PPO issue. Until then this script says so and exits
with status 2, so nobody mistakes it for a finished run. The tracking core and its evaluation are
ready: ``python -m imm_gym.evaluate --policy fixed --scenario paper --runs 100 --seed 0``.
"""

import sys

if __name__ == "__main__":
    print(
        "train.py: training is not implemented yet (see the PPO issue).\n"
        "Meanwhile: python -m imm_gym.evaluate --policy fixed --scenario paper --runs 100 --seed 0",
        file=sys.stderr,
    )
    raise SystemExit(2)
