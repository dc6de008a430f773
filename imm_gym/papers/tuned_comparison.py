"""Classical IMM against its BBSCA- and SCA-tuned versions on the seed-002 and seed-003 systems
(seed 003's method, :mod:`imm_gym.papers.tuning`): ``python -m imm_gym.evaluate --scenario
seed002|seed003``."""

from __future__ import annotations

import numpy as np

from imm_gym.papers.systems import (
    HETERO_EKF_PAPER,
    draw,
    run_bank,
    score_run,
    system_setup,
)
from imm_gym.papers.tuning import TunedBank, TunerConfig, bank_objective, tune
from imm_gym.seeding import TRAIN_SEED_OFFSET
from imm_gym.validation import ConfigError

#: The policies that load a tuned bank from a file (``tuned``, ``--tuned POLICY=FILE``).
TUNED_POLICIES = ("bbsca", "sca")
SYSTEM_POLICIES = ("fixed", *TUNED_POLICIES)


def evaluate_system(
    name: str,
    policies: list[str],
    runs: int,
    seed: int,
    tuned: dict[str, str] | None = None,
    train_runs: int = 10,
    generations: int = 30,
) -> dict[str, object]:
    """Classical IMM (``fixed``) and its BBSCA- / SCA-tuned versions on a seed scenario.

    A tuned policy loads its :class:`~imm_gym.papers.tuning.TunedBank` from ``tuned[policy]`` if
    given (its ``bank`` must be ``name``: a file tuned for another system is refused), else tunes
    on ``train_runs`` training runs (seeds ``seed + TRAIN_SEED_OFFSET + r``) with 10 particles
    and ``generations`` generations. All policies are scored on the same runs (seeds
    ``seed .. seed + runs - 1``), with the held-out innovation objective ``J`` beside seed 002's
    metrics.

    Raises:
        ConfigError: before any run, a policy not of :data:`SYSTEM_POLICIES` or given twice, or
            a key of ``tuned`` that is not a tuned policy (:data:`TUNED_POLICIES`) among
            ``policies`` (its file would go unused); a tuned file that cannot be read or is for
            another system.
    """
    imm, family, sensor, tpm = system_setup(name)
    for p in policies:
        if p not in SYSTEM_POLICIES:
            raise ConfigError(
                f"on scenario {name!r} the policies are {list(SYSTEM_POLICIES)} (classical IMM and "
                f"its tuned versions), got {p!r}"
            )
    if len(set(policies)) != len(policies):
        raise ConfigError(f"--policy given twice: {policies}")
    asked = [p for p in policies if p in TUNED_POLICIES]
    for key in tuned or {}:
        if key not in asked:
            raise ConfigError(
                f"--tuned {key}=FILE: {key!r} is not a tuned policy evaluated here; the keys "
                f"allowed are those of {list(TUNED_POLICIES)} given as --policy "
                f"({list(policies)}): {asked or 'none'}"
            )
    batch = draw(family, sensor, runs, seed)
    held_out = bank_objective(imm, batch, tpm, sensor.sigma)
    results: dict[str, object] = {}
    for p in policies:
        notes: dict[str, object] = {}
        if p == "fixed":
            bank = TunedBank(name, (1.0,) * imm.n_models, 1.0, method="none")
        elif tuned and p in tuned:
            bank = TunedBank.load(tuned[p], method=p)
            if bank.bank != name:
                raise ConfigError(
                    f"tuned bank {tuned[p]}: its field bank is {bank.bank!r}, the factors of "
                    f"another system; scenario {name!r} needs a bank tuned for {name!r}"
                )
            notes["tuned_file"] = tuned[p]
        else:
            train = draw(family, sensor, train_runs, seed + TRAIN_SEED_OFFSET)
            cfg = TunerConfig(method=p, generations=generations, seed=seed)
            bank, _ = tune(imm, train, tpm, sensor.sigma, cfg, bank=name)
            notes["train_seeds"] = (
                f"{seed + TRAIN_SEED_OFFSET}..{seed + TRAIN_SEED_OFFSET + train_runs - 1}"
            )
        if len(bank.q_scale) != imm.n_models:
            raise ConfigError(
                f"tuned bank has {len(bank.q_scale)} Q scales for {imm.n_models} models"
            )
        q = np.tile(bank.q_scale, (runs, 1))
        r = np.full(runs, bank.r_scale)
        run = run_bank(imm, batch, tpm, q_scale=q, r_scale=r)
        metrics = score_run(run, batch, sensor.dim_z)
        metrics["innovation_mse"] = float(held_out(bank.theta[None])[0])
        results[p] = {
            **metrics,
            "q_scale": list(bank.q_scale),
            "r_scale": bank.r_scale,
            "train_objective": bank.objective,
            **notes,
        }
    return {
        "policies": results,
        "paper": HETERO_EKF_PAPER if name == "seed002" else {},
        "meta": {
            "scenario": name,
            "runs": runs,
            "seed": seed,
            "seeds": f"{seed}..{seed + runs - 1}",
            "steps": batch.measurements.z.shape[1] - 1,
            "filter": "ekf",
        },
    }
