"""The batched simulation behind every environment front, without Gymnasium: the configuration
(:class:`~imm_gym.sim.env_config.EnvConfig`), the core (:class:`~imm_gym.sim.core.TrackingCore`)
and the compiled step of all its banks (:mod:`imm_gym.sim.kernels`)."""
