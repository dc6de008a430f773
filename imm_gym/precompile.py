"""``python -m imm_gym.precompile``: the compiled kernels into numba's cache, in parallel
(:mod:`imm_gym.cli.precompile`)."""

from imm_gym.cli.precompile import main

if __name__ == "__main__":
    raise SystemExit(main())
