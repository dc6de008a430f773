"""The policies a comparison runs, by name (``--policy`` of ``python -m imm_gym.evaluate`` and
``python -m imm_gym.track``).

A registered rule is built by its registry entry (:mod:`baselines`), a tuned one on training runs
seeded ``seed + TRAIN_SEED_OFFSET + r``, which never meet the evaluation's; ``pretrained``,
``pretrained-per-model`` or a directory is a trained agent (:mod:`agents.ensemble`), loaded for the
evaluated bank. :func:`agent_overrides` fits a trained agent's settings to the tracker it is
evaluated on, or refuses it (:class:`UnreadableTracker`) before any work; :func:`cannot_run` says
in a few words why a policy cannot run on a configuration.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from baselines import REGISTRY, Baseline, BuildContext
from imm_gym.evaluation.metrics import tracking_errors
from imm_gym.evaluation.rollout import evaluation_config, rollout, score
from imm_gym.seeding import TRAIN_SEED_OFFSET
from imm_gym.sim.actions import action_size
from imm_gym.sim.config_file import EVALUATED_FIELDS, TRACKER_FIELDS, plain, tracker_of
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.features import observation_size
from imm_gym.sim.model_order import for_bank, model_roles
from imm_gym.validation import ConfigError

#: The training runs a tuned rule is scored on (seeds ``seed + TRAIN_SEED_OFFSET + r``).
TRAIN_RUNS = 100


class UnreadableTracker(ConfigError):
    """A trained agent's network cannot read or write the evaluated tracker: its observation or
    action is of another size (a bank of another number of models, say), or a feature it reads
    is not given by that tracker. ``reason`` says so in a few words, for a suite's table."""

    def __init__(self, message: str, reason: str) -> None:
        super().__init__(message)
        self.reason = reason


def make_policy(
    name: str,
    base: EnvConfig,
    seed: int,
    train_runs: int = TRAIN_RUNS,
    make_core: Callable[[EnvConfig, int], Any] = TrackingCore,
) -> tuple[Any, dict[str, Any], dict[str, Any]]:
    """``(policy, env_overrides, notes)`` for a policy name or a saved SB3 model path.

    A registered baseline is built by its registry entry; a tuned one sees ``train_runs``
    training runs seeded ``seed + TRAIN_SEED_OFFSET + r``, scored by their position ARMSE
    (roll-outs on the cores ``make_core`` builds, as :func:`~imm_gym.cli.comparison.evaluate`'s).
    """
    if name in REGISTRY:
        train_seed = seed + TRAIN_SEED_OFFSET

        def train_armse(policy: Baseline) -> float:
            cfg = evaluation_config(base, policy.env_overrides)
            run = rollout(policy, cfg, train_runs, train_seed, make_core=make_core)
            return score(run)["armse_pos"]

        def train_armse_from(policy: Baseline, tpms: NDArray[np.float64]) -> NDArray[np.float64]:
            cfg = evaluation_config(base, policy.env_overrides)
            run = rollout(
                policy, cfg, train_runs, train_seed, make_core=make_core, initial_tpms=tpms
            )
            parts = run.groups(len(tpms))
            return np.array([tracking_errors(p.estimate, p.truth)["armse_pos"] for p in parts])

        context = BuildContext(base, train_seed, train_runs, train_armse, train_armse_from)
        policy, notes = REGISTRY[name].build(context)
        return policy, policy.env_overrides, notes
    from agents import SHIPPED

    if name in SHIPPED:
        return load_trained(SHIPPED[name], base)
    path = Path(name)
    if path.suffix == ".zip" or path.is_dir() or path.exists():
        return load_trained(path, base)
    raise ConfigError(
        f"unknown policy {name!r}: use one of {list(REGISTRY)}, {list(SHIPPED)} or a "
        "trained agent's directory"
    )


def load_trained(path: Path, base: EnvConfig) -> tuple[Any, dict[str, Any], dict[str, Any]]:
    """A trained agent (``agents.policy`` directory layout), an ensemble of them
    (``agents.ensemble``) or a stay selector (``agents.selector``) for ``base``'s bank
    (:func:`~imm_gym.sim.model_order.for_bank`) and its environment overrides."""
    from agents.ensemble import load_policy

    try:
        policy = load_policy(path)
    except FileNotFoundError as err:
        raise ConfigError(str(err)) from None
    return for_bank(policy, len(base.bank)), policy.env_overrides, {"path": str(path)}


def agent_overrides(
    policy: Any, overrides: Mapping[str, Any], base: EnvConfig
) -> tuple[dict[str, Any], dict[str, Any]]:
    """A trained agent's overrides for the evaluated configuration ``base`` and its notes.

    The agent keeps its own settings (action mode, features, ...) and runs on ``base``'s tracker
    and targets, scored as every other policy: its recorded
    :data:`~imm_gym.sim.config_file.TRACKER_FIELDS`,
    :data:`~imm_gym.sim.config_file.TARGET_FIELDS` and
    :data:`~imm_gym.sim.config_file.EVALUATION_FIELDS` (the divergence cap) are dropped. The
    notes give ``trained_on`` (the recorded tracker), ``evaluated_on`` (``base``'s) and
    ``tracker_differs`` (the fields that differ), and ``models_differ`` where the evaluated
    bank's models stand for others than every trained bank's, position by position
    (:func:`~imm_gym.sim.model_order.model_roles`: the policy reads them as the ones it was
    trained on; not for a network shared by the models, ``policy.shares_models``, which reads
    each model's role); for an agent trained across trackers (``policy.trained_across``),
    ``trained_on`` is the trained tracker with the fewest fields differing and
    ``trained_across`` lists them all.

    Raises:
        UnreadableTracker: the agent's settings do not fit ``base``'s tracker (features it
            cannot give: a linear bank's on a heterogeneous one), or the observation (one frame,
            ``policy.obs_size``) or the action (M² entries, M in the stay modes) that ``base``
            gives is not the size the agent's network reads or writes.
    """
    kept = {k: v for k, v in overrides.items() if k not in EVALUATED_FIELDS}
    source = getattr(policy, "source", "the agent")
    try:
        cfg = evaluation_config(base, kept)
    except ConfigError as err:  # base is valid: the agent's settings do not fit its tracker
        raise UnreadableTracker(
            f"{source} cannot be evaluated on this configuration: {err}", str(err)
        ) from None
    M = len(cfg.bank)
    obs_size = observation_size(cfg.obs_features, M, cfg.sensor.dim_z)
    if hasattr(policy, "obs_size") and obs_size != policy.obs_size:
        raise UnreadableTracker(
            f"{source} reads observations of {policy.obs_size} entries, but the evaluated "
            f"configuration gives {obs_size} (a bank of {M} models, features "
            f"{list(cfg.obs_features)}): it cannot be evaluated on this configuration (the shipped "
            "'pretrained-per-model', or an agent trained with agents/hyperparams/per_model.yml, "
            "reads a bank of any size)",
            f"reads {policy.obs_size} observation entries, the tracker gives {obs_size} "
            f"({M} models)",
        )
    space = getattr(getattr(policy, "model", None), "action_space", None)
    size = action_size(cfg.action_mode, M)
    if space is not None and int(np.prod(space.shape)) != size:
        raise UnreadableTracker(
            f"{source} writes actions of {int(np.prod(space.shape))} entries, but a bank of {M} "
            f"models takes {size} in {cfg.action_mode!r} mode: it cannot be evaluated on this "
            "configuration",
            f"writes {int(np.prod(space.shape))} action entries, the tracker takes {size} "
            f"({M} models)",
        )
    evaluated_on = {name: plain(getattr(base, name)) for name in TRACKER_FIELDS}
    trackers = [tracker_of(overrides), *getattr(policy, "trained_across", ())]
    differs = [[f for f in TRACKER_FIELDS if t[f] != evaluated_on[f]] for t in trackers]
    closest = min(range(len(trackers)), key=lambda i: len(differs[i]))
    notes = {
        "trained_on": trackers[closest],
        "evaluated_on": evaluated_on,
        "tracker_differs": differs[closest],
    }
    roles = model_roles(cfg.bank, cfg.model_order)
    trained = [
        model_roles(EnvConfig.build({"bank": t["bank"], "filter": t["filter"]}).bank,
                    cfg.model_order)
        for t in trackers
    ]
    if roles not in trained and not getattr(policy, "shares_models", False):
        notes["models_differ"] = {"trained": list(trained[closest]), "evaluated": list(roles)}
    if len(trackers) > 1:
        notes["trained_across"] = trackers
    return kept, notes


def cannot_run(name: str, base: EnvConfig, seed: int) -> str | None:
    """Why the policy ``name`` cannot run on ``base``, in a few words, or None: a rule whose
    settings the configuration does not admit (its registry entry's ``check``: a detector rule
    on a bank its detector cannot read), an agent whose network cannot read the tracker
    (:class:`UnreadableTracker`). Checked before any tuning or roll-out."""
    if name in REGISTRY:
        try:
            REGISTRY[name].check(base)
        except ConfigError as err:
            return str(err)
        return None
    policy, recorded, _ = make_policy(name, base, seed)
    try:
        agent_overrides(policy, recorded, base)
    except UnreadableTracker as err:
        return err.reason
    return None

