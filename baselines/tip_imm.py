"""TIP-IMM (seed 000): the temporal-information TPM rule with parallel banks (SPEC §4, §6)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.tip import READINGS, tip_factors
from imm_gym.validation import ConfigError, check_choice, check_range

from .base import Baseline
from .registry import register


@register("tip-imm", help="TIP-IMM, the temporal-information TPM rule of seed 000")
class TIPIMM(Baseline):
    """The TIP-IMM rule as a ``scale`` action: ``a_ij = log(f_ij) / log(max_factor)``.

    ``f`` are the factors of :func:`imm_gym.tracking.tip.tip_factors` on ``mu(t)``, ``mu(t-1)`` (the
    observation's first blocks: with the parallel bank on, the fused probabilities ``U``). The
    environment settings that make this TIP-IMM are part of the policy: bank B with the fixed TPM
    and entropy fusion with feedback (``parallel=True``), the TPM floor ``p_min = 0.05``.

    Args:
        n_models: M.
        alpha, beta: growth and shrink factors (SPEC §6: 1.1, 0.9): ``alpha > 1``,
            ``0 < beta < 1``.
        reading: ``"literal"`` (default) or ``"intent"`` for the ambiguous case.
        floor: the TPM floor (0.05; 0 reproduces the paper's rule as printed, which fails), in
            ``[0, 1/M)``.
        parallel: run the parallel bank with entropy fusion.
        max_factor: the environment's ``scale`` range (> 1, at least ``alpha`` and ``1/beta``).

    Raises:
        ConfigError: a parameter outside its range, named with the range.
    """

    def __init__(
        self,
        n_models: int = 3,
        alpha: float = 1.1,
        beta: float = 0.9,
        reading: str = "literal",
        floor: float = 0.05,
        parallel: bool = True,
        max_factor: float = 2.0,
    ) -> None:
        super().__init__(n_models)
        alpha = check_range("alpha", alpha, 1.0, lo_open=True)
        beta = check_range("beta", beta, 0.0, 1.0, lo_open=True, hi_open=True)
        reading = check_choice("reading", reading, READINGS)
        floor = check_range("floor", floor, 0.0, 1.0 / n_models, hi_open=True)
        max_factor = check_range("max_factor", max_factor, 1.0, lo_open=True)
        if not (alpha <= max_factor and 1.0 / beta <= max_factor):
            raise ConfigError(
                f"max_factor must be at least alpha and 1/beta ({max(alpha, 1.0 / beta)!r}) to "
                f"express them, got {max_factor!r}"
            )
        self.alpha, self.beta, self.reading = alpha, beta, reading
        self.max_factor = max_factor
        self.env_overrides = {
            "action_mode": "scale",
            "max_factor": max_factor,
            "p_min": floor,
            "parallel": parallel,
        }

    def act(
        self, obs: NDArray[np.float64], state: Any, episode_start: NDArray[np.bool_]
    ) -> tuple[NDArray[np.float64], Any]:
        mu_now, mu_prev = self.mode_probs(obs)
        f = tip_factors(mu_now, mu_prev, self.alpha, self.beta, self.reading)
        return (np.log(f) / np.log(self.max_factor)).reshape(obs.shape[0], -1), state
