"""How far a per-episode choice of the fixed TPM gets against the best fixed TPM of a scenario.

The benchmark suite's bar for a TPM policy (issue "A learned TPM policy people can trust",
must-show 1) is the better of TIP-IMM and the *best fixed TPM*, whose stay is chosen per
scenario on its own training runs: an oracle over the scenario. This runs the classical IMM at
every stay of the best-fixed search grid on the same runs (one core, common random numbers) and
scores two estimators that choose the stay per episode from the measurements alone, by each
IMM's measurement evidence :math:`\\log p(z_t \\mid Z^{t-1}) = \\log \\sum_j \\bar c_j \\Lambda_j`
summed over the episode so far (discounted by ``lam``):

* ``select``: the estimate of the IMM with the largest evidence at each step;
* ``average``: the evidence-weighted average of the IMMs' position estimates (Bayesian model
  averaging over the stays).

Neither is a TPM policy (they run one IMM per stay); they show what knowing the right stay per
episode is worth, and so how much a policy must gain inside an episode to beat the oracle::

    python examples/stay_selection.py --runs 100 --seed 0
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

import numpy as np

from baselines.best_fixed import stay_grid
from imm_gym import EnvConfig, TrackingCore, stay_tpm
from imm_gym.cli.suite import suite_configs
from imm_gym.evaluation.rollout import armse_from_squared
from imm_gym.tracking.imm import measurement_loglik
from imm_gym.validation import ConfigError

#: Per-step evidence below the best IMM's is floored here (nats): one outlier moves it at most
#: this much.
STEP_FLOOR = -10.0


def stay_runs(
    overrides: dict[str, Any], runs: int, seed: int
) -> tuple[tuple[float, ...], np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(grid, err2, pos, truth, evidence)``: the stays of the best-fixed search for the bank
    (:func:`~baselines.best_fixed.stay_grid`) and the classical IMM at each of them on
    runs ``seed .. seed + runs - 1``: squared position errors ``(S, R, K)``, position estimates
    ``(S, R, K, 2)``, true positions ``(R, K, 2)``, per-step measurement log-likelihoods
    ``(S, R, K)`` (0 on a missed detection)."""
    config = EnvConfig.build(overrides).replace(
        shadow="none", reward="error", action_mode="scale", sojourn=None, p_min=1e-4
    )
    M = len(config.bank)
    grid = stay_grid(M)
    S = len(grid)
    core = TrackingCore(config, S * runs)
    tpms = np.stack([stay_tpm(M, s) for s in grid])
    core.reset(np.arange(S * runs), [seed + r for _ in range(S) for r in range(runs)],
               np.repeat(tpms, runs, axis=0))
    K = core.horizon
    truth = core.truth[:runs, 1 : K + 1, :2].copy()
    pos = np.empty((S, runs, K, 2))
    evidence = np.empty((S, runs, K))
    for k in range(K):
        result = core.step(np.zeros((S * runs, core.action_dim)))
        pos[:, :, k] = result.info["estimate"][:, :2].reshape(S, runs, 2)
        loglik = measurement_loglik(core.loglik, core.cbar)
        evidence[:, :, k] = np.where(result.info["detected"], loglik, 0.0).reshape(S, runs)
    err2 = np.sum((pos - truth) ** 2, axis=-1)
    return grid, err2, pos, truth, evidence


def choose(
    pos: np.ndarray, truth: np.ndarray, evidence: np.ndarray, lam: float
) -> tuple[np.ndarray, np.ndarray]:
    """Squared position errors ``(R, K)`` of ``select`` and ``average`` (module docstring)."""
    S, R, K = evidence.shape
    total = np.zeros((S, R))
    select, average = np.empty((R, K)), np.empty((R, K))
    for k in range(K):
        step = evidence[:, :, k]
        total = lam * total + np.maximum(step - step.max(axis=0), STEP_FLOOR)
        best = total.argmax(axis=0)
        select[:, k] = np.sum((pos[best, np.arange(R), k] - truth[:, k]) ** 2, axis=-1)
        w = np.exp(total - total.max(axis=0))
        w /= w.sum(axis=0)
        mean = np.einsum("sr,srd->rd", w, pos[:, :, k])
        average[:, k] = np.sum((mean - truth[:, k]) ** 2, axis=-1)
    return select, average


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--suite", default="benchmark")
    args = p.parse_args(argv)
    if args.runs < 1:
        p.error(f"--runs must be >= 1, got {args.runs}")
    if args.seed < 0:
        p.error(f"--seed must be >= 0, got {args.seed}")
    try:
        suite = suite_configs(args.suite)
    except ConfigError as err:
        p.error(str(err))
    print(f"runs {args.seed}..{args.seed + args.runs - 1}; position ARMSE (m)")
    print("| scenario | best fixed (stay) | select, λ = 1 | average, λ = 1 | select, λ = 0.99 "
          "| average, λ = 0.99 |")
    print("|---|---|---|---|---|---|")
    for name, overrides in suite.items():
        grid, err2, pos, truth, evidence = stay_runs(overrides, args.runs, args.seed)
        fixed = [armse_from_squared(e) for e in err2]
        best = int(np.argmin(fixed))
        cells = [f"{fixed[best]:.2f} ({grid[best]:.3g})"]
        for lam in (1.0, 0.99):
            cells += [f"{armse_from_squared(e):.2f}" for e in choose(pos, truth, evidence, lam)]
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
