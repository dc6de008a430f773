"""The tracker: motion models, sensors, filters, TPM operations, the IMM cycle and its compiled
engine. Depends on nothing else of imm_gym but :mod:`imm_gym.validation`.

==================  ===============================================================
module              what it holds
==================  ===============================================================
``models``          linear motion models (CV, CT, CA) and the paper bank
``conversions``     state spaces of the heterogeneous bank and their conversions
``sensors``         the sonar (range, bearing) and the position(+velocity) sensor
``filters``         UKF (SVD or Cholesky sigma points), EKF and KF: ``predict`` and ``update``
``tpm``             TPM construction, validation, floor and divergence
``tip``             TIP-IMM's TPM rule (the factors of eqs. 13-17)
``fusion``          TIP-IMM's entropy fusion of two probability vectors (eq. 19)
``initiation``      track initiation from the first measurement
``imm``             the IMM cycle: ``mix``, ``update_mode_probs``, ``combine``, ``IMM``
``hetero``          the heterogeneous bank (NCV / CT / CTRA) and ``HeteroIMM``
``kernels.imm``     the compiled engine of ``IMM.step`` (numba)
``linalg``          symmetric eigendecomposition, log-determinants, angle wrapping
==================  ===============================================================
"""
