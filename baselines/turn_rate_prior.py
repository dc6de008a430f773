"""A fixed switching prior whose jumps lean toward the estimated turn rate (``turn-rate-prior``).

Each row keeps its model with probability ``r = (s - 1/M) / (1 - 1/M)`` and otherwise redraws it
from ``q = (1 - v) / M + v b``, ``b`` the ``turn_rate`` detector's belief (the smoothed heading
rate of the tracker's own estimate interpolated between the models' turn rates,
:mod:`imm_gym.sim.detectors`): ``Pi = r I + (1 - r) 1 q^T``
(:func:`imm_gym.sim.stay_bank.detector_tpm_rows`). With ``q`` uniform (``v = 0``, or a uniform
belief) that is the stay TPM of ``s``, ``s`` on the diagonal; the share ``v`` moves the redraws
toward the belief. A turn slower than the bank's CT models is a blend of CV and the turn of its
sign; a nearly uniform fixed prior mixes them at every step blindly, this one aims the mixing at
the blend. The stay and the
share are searched like ``best-fixed``'s stay, on the training runs.

``learned-prior`` is the same rule led by the ``learned`` detector: a network's belief of the
coming step's turn rate from a window of an unsteered uniform-TPM IMM
(:mod:`imm_gym.sim.learned_detector`; ``EnvConfig.detector_weights``, by default the shipped
network).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.evaluation.rollout import evaluation_config
from imm_gym.sim.env_config import EnvConfig
from imm_gym.tracking.tpm import stay_tpm
from imm_gym.validation import ConfigError, check_range, check_sequence

from .base import Baseline
from .best_fixed import stay_grid
from .registry import BuildContext, register

#: Detector shares ``v`` searched with the stays of :func:`~baselines.best_fixed.stay_grid`.
SHARE_GRID = (0.25, 0.5, 0.75, 1.0)
#: The TPM's floor ``p_min``: below every searched stay TPM's entries (up to 11 models), so the
#: search's roll-outs run at the floor the policy runs at.
P_MIN = 1e-4


class TurnRatePrior(Baseline):
    """The zero ``stay`` action on the tracker's TPM of stay ``stay``, the ``share`` of its
    jumps placed by the ``detector`` (``turn_rate``, or ``learned``: ``learned-prior``;
    ``stay=None``: the configured initial TPM's stays).

    Raises:
        ConfigError: ``stay`` (or one of its entries) is outside ``[1/M, 1]``: the detector's
            rows take stays of at least ``1/M``.
    """

    name = "turn-rate-prior"

    def __init__(
        self,
        n_models: int = 3,
        stay: float | Sequence[float] | None = None,
        share: float = 0.5,
        detector: str = "turn_rate",
    ) -> None:
        super().__init__(n_models)
        if isinstance(stay, (list, tuple, np.ndarray)):
            for i, s in enumerate(check_sequence("stay", stay, n_models)):
                check_range(f"stay[{i}]", s, 1.0 / n_models, 1.0)
        elif stay is not None:
            check_range("stay", stay, 1.0 / n_models, 1.0)
        self.stay = stay
        self.share = share
        if detector == "learned":
            self.name = "learned-prior"
        self.env_overrides = {
            "action_mode": "stay",
            "stay_base": "tracker",
            "detector": detector,
            "detector_share": share,
            "p_min": P_MIN,
        }
        if stay is not None:
            self.env_overrides.update({"initial_stay": stay, "sojourn": None})

    def act(
        self, obs: NDArray[np.float64], state: Any, episode_start: NDArray[np.bool_]
    ) -> tuple[NDArray[np.float64], Any]:
        return np.zeros((obs.shape[0], self.n_models)), state


def admits(base: EnvConfig, detector: str) -> None:
    """Raise :class:`~imm_gym.validation.ConfigError` where ``base`` cannot run the prior led by
    ``detector`` (a linear bank; for the learned one, distinct turn rates and as many models as
    its network reads)."""
    evaluation_config(base, TurnRatePrior(len(base.bank), detector=detector).env_overrides)


@register(
    "turn-rate-prior",
    help="a fixed stay with jumps leaning toward the estimated turn rate; stay and share with "
    "the lowest ARMSE on training runs",
    check=lambda base: admits(base, "turn_rate"),
)
def build_turn_rate_prior(
    context: BuildContext, detector: str = "turn_rate"
) -> tuple[TurnRatePrior, dict[str, Any]]:
    """:class:`TurnRatePrior` with the stay of :func:`~baselines.best_fixed.stay_grid` and
    the share of :data:`SHARE_GRID` scoring best on the training runs: one roll-out of every
    stay per share.

    Notes: the stay and share found, the training ARMSE of every pair (``"stay/share"``), the
    training runs and seeds.
    """
    if context.train_armse_from is None:
        raise ConfigError("a detector prior needs a build context that offers train_armse_from")
    M = context.n_models
    stays = stay_grid(M)
    tpms = np.stack([stay_tpm(M, s) for s in stays])
    search: dict[tuple[float, float], float] = {}
    for share in SHARE_GRID:
        scores = context.train_armse_from(TurnRatePrior(M, share=share, detector=detector), tpms)
        search.update(((s, share), float(v)) for s, v in zip(stays, scores, strict=True))
    stay, share = min(search, key=search.__getitem__)
    notes = {
        "stay": float(stay),
        "share": float(share),
        "search": {f"{s:.4f}/{v:.2f}": score for (s, v), score in search.items()},
        "train_runs": context.train_runs,
        "train_seeds": context.train_seeds(),
    }
    return TurnRatePrior(M, float(stay), float(share), detector), notes


@register(
    "learned-prior",
    help="turn-rate-prior led by the learned detector (a network's belief of the coming turn "
    "rate; EnvConfig.detector_weights); stay and share searched the same way",
    check=lambda base: admits(base, "learned"),
)
def build_learned_prior(context: BuildContext) -> tuple[TurnRatePrior, dict[str, Any]]:
    """:func:`build_turn_rate_prior` with the ``learned`` detector
    (:mod:`imm_gym.sim.learned_detector`)."""
    return build_turn_rate_prior(context, "learned")
