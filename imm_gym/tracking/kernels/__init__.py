"""Compiled engines (numba) of the trackers in :mod:`imm_gym.tracking`, each beside the numpy
reference it must equal: :mod:`imm_gym.tracking.kernels.imm` runs
:meth:`imm_gym.tracking.imm.IMM.step`."""
