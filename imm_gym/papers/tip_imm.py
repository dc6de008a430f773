"""The TIP-IMM paper (source 000): the numbers its Table 2 prints.

The scenario of its Table 1 is :func:`imm_gym.scenarios.segments.paper_scenario`, its rule
:func:`imm_gym.tracking.tip.tip_factors` (the ``tip-imm`` baseline) and its defaults the ``paper``
preset of :class:`imm_gym.sim.env_config.EnvConfig`; ``python -m imm_gym.evaluate --scenario
paper`` prints these rows beside the re-simulation.
"""

#: The paper's Table 2 (ARMSE; m and m/s), printed beside the paper scenario's results.
PAPER_TABLE2 = {
    "paper: classical IMM": {
        "armse_pos": 18.3600,
        "armse_pos_x": 11.4543,
        "armse_pos_y": 14.4556,
        "armse_vel_x": 1.0437,
        "armse_vel_y": 1.6767,
    },
    "paper: TIP-IMM": {
        "armse_pos": 17.0247,
        "armse_pos_x": 10.6614,
        "armse_pos_y": 13.3926,
        "armse_vel_x": 1.0190,
        "armse_vel_y": 1.6014,
    },
}
