"""Monte-Carlo evaluation of TPM policies (command line: ``python -m imm_gym.evaluate``).

Every policy — a baseline by name or a saved stable-baselines3 model by path — runs through
:func:`imm_gym.evaluation.rollout.rollout` on the same R runs: same targets, same sensor noise
(common random numbers). The report follows the paper's Table 2 (position ARMSE overall / X / Y,
velocity ARMSE X / Y) and adds NIS/NEES consistency, mode-identification accuracy, the
mode-probability total variation, the peak error and the maneuver response, the clairvoyant
filter (a bound where no policy beats it, else a reference; skipped, with the reason, where it
cannot follow the scenario) and paired differences with 95 % bootstrap confidence intervals
against a reference policy.

Example::

    python -m imm_gym.evaluate --policy fixed --policy tip-imm --policy best-fixed \\
        --scenario paper --runs 100 --seed 0 --json out.json --plots figs/

``--json`` writes ``{"policies": {NAME: {"armse_pos": ..., "armse_pos_x": ..., "armse_pos_y": ...,
"armse_vel_x": ..., "armse_vel_y": ..., ...}}, "clairvoyant": {...}, "paired": {...},
"meta": {...}}``; with ``--runs 1`` the paired differences' confidence bounds ``low`` and
``high`` are null (undefined). ``--json`` and ``--plots`` are checked before anything is evaluated:
an output that cannot be written is a usage error (exit 2).

``--agent-seeds DIR DIR ...`` evaluates the training seeds of one agent, each as a policy, and
adds their interquartile means with stratified bootstrap CIs (:mod:`imm_gym.cli.seeds`; JSON
``"across_seeds"``).

The best fixed TPM is searched on training runs whose seeds (``seed + 1_000_000 + r``) never
overlap the evaluation seeds: ``--runs`` is at most 1 000 000, and ``--seed`` at most
:data:`MAX_SEED` (48 999 900), so that the evaluation and tuning seeds stay below the agents'
validation seeds (50 000 000+) and training slots (100 000 000+); outside, a usage error.

``--ray [ADDR]`` runs the tracking of every roll-out (the best-fixed search's too) in chunks of
runs on a Ray cluster (:mod:`imm_gym.evaluation.distributed`; ``ADDR``: ``auto`` or
``HOST:PORT``, default Ray's: ``RAY_ADDRESS``, a running local cluster, else a new local
instance); every number is the single-process one. Ray is imported only then.

``--env-config FILE`` (YAML or JSON, :mod:`imm_gym.sim.config_file`) sets the EnvConfig of every
policy — baselines, the best-fixed search and trained agents —; ``--scenario``, when given,
replaces the file's scenario and ``--bank`` its bank and filter. A trained agent runs on the
evaluated tracker (sensor, bank, filter) with its own settings (action mode, features...); the
JSON gives its ``trained_on`` and ``evaluated_on`` trackers and ``tracker_differs`` (the fields that
differ, also said under the table), ``models_differ`` where the evaluated bank's models stand for
others than the trained banks' (said too: the agent reads them as its own), and ``meta.env_config``
the file and what it said, ``{"file": PATH, "overrides": {...}}`` (its EnvConfig overrides as
read, before ``--scenario`` and ``--bank``: the record re-runs with ``meta.command`` after the file
is edited; the overrides alone when called from Python; the paper's Table 2 rows are printed only
without one, on the paper scenario with the paper's bank and filter); an agent whose observation or
action size the evaluated configuration does not give is refused before any work.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agents.policy import agent_directory
from baselines import REGISTRY, Baseline, BuildContext
from imm_gym.cli.provenance import record_json, versions
from imm_gym.cli.tables import render_tables
from imm_gym.evaluation.clairvoyant import (
    clairvoyant_filter,
    clairvoyant_role,
    hold_diverged,
    unsupported,
)
from imm_gym.evaluation.distributed import ShardError
from imm_gym.evaluation.metrics import (
    IQM_LEVEL,
    IQM_RESAMPLES,
    IQM_SEED,
    maneuver_response,
    peak_error,
    tracking_errors,
)
from imm_gym.evaluation.rollout import (
    PAIRED_LEVEL,
    PAIRED_RESAMPLES,
    PAIRED_SEED,
    Rollout,
    check_paired,
    evaluation_config,
    paired_bootstrap,
    rollout,
    score,
)
from imm_gym.papers.systems import SYSTEMS
from imm_gym.scenarios.catalog import SCENARIOS, SUITE_CONFIGS, SUITES
from imm_gym.scenarios.segments import Scenario, true_model_index
from imm_gym.seeding import TRAIN_SEED_BASE, TRAIN_SEED_OFFSET, VALIDATION_SEED_BASE
from imm_gym.sim.actions import action_size
from imm_gym.sim.config_file import (
    EVALUATED_FIELDS,
    TRACKER_FIELDS,
    expand_presets,
    plain,
    read_env_config,
    tracker_of,
)
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.sim.features import observation_size
from imm_gym.sim.mixture import AGENT_FIELDS
from imm_gym.sim.model_order import for_bank, model_roles
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.tracking.tpm import stay_tpm
from imm_gym.validation import ConfigError, from_dict, unique_keys

#: ``--bank``: environment overrides of each bank.
BANKS = BANK_PRESETS
TRAIN_RUNS = 100
#: The most runs: the evaluation seeds ``seed .. seed + runs - 1`` stay below the tuners' training
#: seeds ``seed + TRAIN_SEED_OFFSET + r``.
MAX_RUNS = TRAIN_SEED_OFFSET
#: The largest ``--seed``: the tuners' last training seed ``seed + TRAIN_SEED_OFFSET + TRAIN_RUNS
#: - 1`` (and so every evaluation seed) stays below the agents' validation seeds.
MAX_SEED = VALIDATION_SEED_BASE - TRAIN_SEED_OFFSET - TRAIN_RUNS
#: The files a directory suite reads (``--suite DIR``).
CONFIG_SUFFIXES = (".yaml", ".yml", ".json")


class UnreadableTracker(ConfigError):
    """A trained agent's network cannot read or write the evaluated tracker: its observation or
    action is of another size (a bank of another number of models, say), or a feature it reads
    is not given by that tracker. ``reason`` says so in a few words, for a suite's table."""

    def __init__(self, message: str, reason: str) -> None:
        super().__init__(message)
        self.reason = reason


def load_source(name: str) -> str | Scenario:
    """``random``, a named scenario (:data:`imm_gym.scenarios.catalog.SCENARIOS`) or a JSON file
    holding a :class:`Scenario` (``segments`` list...)."""
    if name == "random" or name in SCENARIOS:
        return name
    path = Path(name)
    if not path.is_file():
        names = ", ".join(repr(n) for n in ("random", *SCENARIOS))
        raise ConfigError(f"--scenario must be {names} or a JSON file; {name!r} is neither")
    try:
        data = json.loads(path.read_text(), object_pairs_hook=unique_keys)
    except OSError as err:
        raise ConfigError(f"scenario file {name}: cannot read ({err})") from None
    except ValueError as err:  # not UTF-8, not JSON, or a key given twice
        raise ConfigError(f"scenario file {name}: not valid JSON ({err})") from None
    except RecursionError:
        raise ConfigError(f"scenario file {name}: not valid JSON (nested too deeply)") from None
    try:
        return from_dict(Scenario, data, "scenario")
    except ConfigError as err:
        raise ConfigError(f"scenario file {name}: {err}") from None


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
    (roll-outs on the cores ``make_core`` builds, as :func:`evaluate`'s).
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


def evaluate(
    policies: Sequence[str],
    scenario: str | Scenario | Mapping[str, Any],
    runs: int,
    seed: int,
    reference: str | None = None,
    clairvoyant: bool = True,
    progress: bool = False,
    extra: dict[str, tuple[Any, dict[str, Any]]] | None = None,
    bank: str = "paper",
    env_config: Mapping[str, Any] | None = None,
    make_core: Callable[[EnvConfig, int], Any] = TrackingCore,
) -> tuple[dict[str, Any], dict[str, Rollout]]:
    """Score ``policies`` on R common-random-number runs; see the module docstring.

    ``extra`` adds policy objects by name: ``{name: (policy, env_overrides)}`` (a freshly trained
    agent, say); they are evaluated first. ``bank``: a preset of
    :data:`~imm_gym.sim.presets.BANK_PRESETS` applied over ``env_config`` (``paper``, the
    default, changes nothing: EnvConfig's bank or the file's); ``hetero`` has no clairvoyant
    filter, said in the results. ``env_config``: EnvConfig overrides (a configuration file's,
    :func:`~imm_gym.sim.config_file.read_env_config`) every policy runs on, ``scenario``
    replacing theirs; what an agent is trained as (:data:`~imm_gym.sim.mixture.AGENT_FIELDS`:
    action mode, features, reward) is each policy's own and is dropped from it, a detector
    network it names kept (the rules' learned detector). Trained agents (``extra`` and paths)
    are checked against it before any work (:func:`agent_overrides`). The clairvoyant row is
    labelled a bound or a reference, or skipped with the reason (:func:`clairvoyant_bound`).
    ``make_core``: builds the core of each roll-out
    (:func:`~imm_gym.evaluation.rollout.rollout`; ``--ray``: a
    :class:`~imm_gym.evaluation.distributed.ShardPool`'s, the same numbers). ``meta.versions``
    (:func:`~imm_gym.cli.provenance.versions`) is read once, as the evaluation starts: the code
    it ran, not a commit made while it runs.
    """
    started = versions(*OPTIONAL_PACKAGES)
    if bank not in BANKS:
        raise ConfigError(f"--bank must be one of {list(BANKS)}, got {bank!r}")
    base = evaluated_config(scenario, env_config, bank)
    if len(set(policies)) != len(policies):
        raise ConfigError(f"--policy given twice: {list(policies)}")
    if reference is not None and reference not in [*(extra or {}), *policies]:
        raise ConfigError(f"--reference {reference!r} is not among the evaluated policies")
    agents = {
        name: (for_bank(p, len(base.bank)), o, {}) for name, (p, o) in (extra or {}).items()
    }
    for name in (name for name in policies if name in REGISTRY):
        try:
            REGISTRY[name].check(base)
        except ConfigError as err:
            raise ConfigError(f"{name} cannot run on this configuration: {err}") from None
    loaded = (name for name in policies if name not in REGISTRY)
    agents.update({name: make_policy(name, base, seed, make_core=make_core) for name in loaded})
    for name, (policy, overrides, notes) in agents.items():
        kept, tracker = agent_overrides(policy, overrides, base)
        agents[name] = (policy, kept, {**notes, **tracker})
    made = {name: agents[name] for name in extra or {}}
    for name in policies:
        if name not in agents:
            agents[name] = make_policy(name, base, seed, make_core=make_core)
        made[name] = agents[name]
    rollouts: dict[str, Rollout] = {}
    results: dict[str, Any] = {"policies": {}}
    bar = _progress_bar(len(made) * base.source.horizon, progress)
    for name, (policy, overrides, notes) in made.items():
        cfg = evaluation_config(base, overrides)
        done = [0]

        def tick(k: int, done: list[int] = done) -> None:
            bar.update(k - done[0])
            done[0] = k

        rollouts[name] = rollout(policy, cfg, runs, seed, progress=tick, make_core=make_core)
        results["policies"][name] = {**score(rollouts[name]), **notes}
    bar.close()
    check_paired(rollouts)  # the differences below, and a suite's against its bar, are paired
    ref = reference or ("fixed" if "fixed" in rollouts else next(iter(rollouts)))
    results["paired"] = {
        "reference": ref,
        "differences": {
            name: paired_difference(r.squared_position_error, rollouts[ref].squared_position_error)
            for name, r in rollouts.items()
            if name != ref
        },
    }
    if clairvoyant:
        results["clairvoyant"] = clairvoyant_bound(base, runs, seed, results["policies"])
    results["meta"] = {
        "scenario": scenario if isinstance(scenario, str) else "file",
        "runs": runs,
        "seed": seed,
        "seeds": f"{seed}..{seed + runs - 1}",
        "steps": base.source.horizon,
        "filter": base.filter,
        "bank": bank,
        "env_config": plain(dict(env_config)) if env_config else None,
        "versions": started,
        "divergence": divergence_meta(base),
        "bootstrap": bootstrap_meta(),
    }
    return results, rollouts


def bootstrap_meta() -> dict[str, dict[str, Any]]:
    """The settings of the confidence intervals, for the JSON's ``meta``: the paired bootstrap
    of the differences (:func:`~imm_gym.evaluation.rollout.paired_bootstrap`) and the
    stratified bootstrap of the training seeds' IQM
    (:func:`~imm_gym.evaluation.metrics.stratified_bootstrap_iqm`, ``--agent-seeds``)."""
    return {
        "paired": {
            "resamples": PAIRED_RESAMPLES,
            "seed": PAIRED_SEED,
            "level": PAIRED_LEVEL,
            "interval": "percentile",
            "resampled": "runs, the same for both policies (paired)",
        },
        "seeds_iqm": {
            "resamples": IQM_RESAMPLES,
            "seed": IQM_SEED,
            "level": IQM_LEVEL,
            "interval": "percentile",
            "resampled": "training seeds, within each scenario (stratified)",
        },
    }


def divergence_meta(base: EnvConfig) -> dict[str, Any]:
    """How a diverged run is scored (:func:`~imm_gym.evaluation.rollout.score`), for the JSON's
    ``meta`` and the note under the table: ``error_m`` the cap and ``scored`` in words."""
    return {
        "error_m": base.divergence_error,
        "scored": "a diverged run's position error is held at error_m, and its velocity error at "
        "the one it diverged with, from the step it diverges at; NIS and NEES are over the steps "
        "before it (the runs are counted in 'diverged')",
    }


def evaluated_config(
    scenario: Any, env_config: Mapping[str, Any] | None = None, bank: str = "paper"
) -> EnvConfig:
    """The configuration every policy of :func:`evaluate` runs on: ``env_config`` without what an
    agent is trained as (:data:`~imm_gym.sim.mixture.AGENT_FIELDS`; a detector network it names
    kept), ``bank``'s preset over it, at ``scenario``."""
    dropped = set(AGENT_FIELDS) - {"detector_weights"}
    shared = {k: v for k, v in (env_config or {}).items() if k not in dropped}
    return EnvConfig.build({**shared, **BANKS[bank], "scenario": scenario})


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


def config_record(
    path: Path | None, overrides: Mapping[str, Any] | None
) -> dict[str, Any] | None:
    """``meta.env_config`` of a configuration file: ``{"file": path, "overrides": what it said}``
    (the EnvConfig overrides read from it, :func:`~imm_gym.sim.config_file.read_env_config`, as
    plain data; a suite's case with the scenario it runs where the file gives none), so that the
    record re-runs after the file is edited; None without a file."""
    if path is None:
        return None
    return {"file": str(path), "overrides": plain(overrides)}


def suite_files(suite: str) -> dict[str, Path]:
    """Each case of ``suite`` and its configuration file: a named suite's
    (:data:`~imm_gym.scenarios.catalog.SUITES`) ``SUITE_CONFIGS/NAME.yaml`` per scenario,
    shipped in the package; or, for a directory, every ``.yaml``, ``.yml`` and ``.json`` file in
    it, named by its stem, in name order (your own suite: ``examples/probes/``).

    Raises:
        ConfigError: neither a suite's name nor a directory, a directory without configuration
            files, or two files of one stem.
    """
    if suite in SUITES:
        return {name: SUITE_CONFIGS / f"{name}.yaml" for name in SUITES[suite]}
    folder = Path(suite)
    if not folder.is_dir():
        raise ConfigError(
            f"--suite must be one of {list(SUITES)} or a directory of configuration files, "
            f"got {suite!r}"
        )
    files: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if path.suffix not in CONFIG_SUFFIXES or not path.is_file():
            continue
        if path.stem in files:
            raise ConfigError(
                f"--suite {suite}: {files[path.stem].name} and {path.name} name one case, "
                f"{path.stem!r}; keep one"
            )
        files[path.stem] = path
    if not files:
        raise ConfigError(
            f"--suite {suite}: the directory holds no configuration file "
            f"({', '.join(CONFIG_SUFFIXES)})"
        )
    return files


def suite_configs(suite: str) -> dict[str, dict[str, Any]]:
    """The EnvConfig overrides of every case of ``suite`` (:func:`suite_files`), each with its
    ``scenario``: a named suite's file must give its own name (or none, the randomized family
    then), a directory's file its scenario (``paper`` when it gives none, as ``--env-config``).

    Raises:
        ConfigError: an unknown suite, or a configuration file missing or invalid.
    """
    return _read_suite(suite, suite_files(suite))


def _read_suite(suite: str, files: Mapping[str, Path]) -> dict[str, dict[str, Any]]:
    """:func:`suite_configs` of the files :func:`suite_files` listed."""
    configs = {}
    for name, path in files.items():
        overrides = read_env_config(path)
        if suite in SUITES and overrides.get("scenario", "random") != name:
            raise ConfigError(f"{path}: scenario must be {name!r}")
        configs[name] = {"scenario": "random" if suite in SUITES else "paper", **overrides}
    return configs


def evaluate_suite(
    policies: Sequence[str],
    suite: str,
    runs: int,
    seed: int,
    reference: str | None = None,
    clairvoyant: bool = True,
    progress: bool = False,
    make_core: Callable[[EnvConfig, int], Any] = TrackingCore,
    bar: Sequence[str] = (),
) -> dict[str, Any]:
    """:func:`evaluate` on every case of ``suite`` with its own configuration file
    (:func:`suite_configs`; baselines, best-fixed search and trained agents on it), the same
    seeds on each. Every file and every trained agent is checked against every configuration
    before any work; an agent whose network cannot read a case's tracker
    (:class:`UnreadableTracker`: a bank of another size) is not run there, and the results say
    why (:func:`cannot_run`: a rule whose settings a case does not admit is not run there
    either); a policy that can run on no case, or a reference (``fixed`` when among the
    policies, else the first rule, else the first policy) or a policy of ``bar`` that cannot
    run on one, is refused.

    ``bar``: policies among ``policies`` whose better on each case (the lower position ARMSE on
    its runs) is the bar the others are tallied against there (``("tip-imm", "best-fixed")``:
    the better of the two rules); picking it on the same runs makes the bar, if anything,
    harder to meet.

    Returns:
        ``{"scenarios": {CASE: evaluate's results (``meta.bank``: ``env-config`` where the case's
        file gives a bank, as with ``--env-config``; ``meta.env_config``: the file and its
        overrides, :func:`config_record`), with "skipped": {POLICY: reason}} and, with
        ``bar``, "bar": {"policy": NAME, "differences": {POLICY: paired difference}}},
        "tally": {POLICY: {"below", "level", "above", "skipped": [CASE, ...]}}, "meta": {...}}``;
        the tally sorts the cases by the paired difference against the bar, else the reference
        (its 95 % CI below zero, including it, above it). ``meta.versions``, the suite's and
        every case's, is read once, as the suite starts: the code it ran, not a commit made
        while it runs.
    """
    started = versions(*OPTIONAL_PACKAGES)
    files = suite_files(suite)
    configs = _read_suite(suite, files)
    rules = [name for name in policies if name in REGISTRY]
    ref = reference or ("fixed" if "fixed" in policies else (rules or policies)[0])
    for name, flag in ((ref, "--reference"), *((b, "--bar") for b in bar)):
        if name not in policies:
            raise ConfigError(f"{flag} {name!r} is not among the evaluated policies")
    skipped: dict[str, dict[str, str]] = {case: {} for case in configs}
    for case, overrides in configs.items():
        base = evaluated_config(overrides["scenario"], overrides)
        for name in policies:
            reason = cannot_run(name, base, seed)
            if reason is None:
                continue
            if name == ref or name in bar:
                role = "the reference" if name == ref else "a policy of --bar"
                raise ConfigError(
                    f"{case}: {role}, {name}, cannot run there ({reason}); the reference and "
                    "the bar run on every case"
                )
            skipped[case][name] = reason
    for name in policies:
        if all(name in skipped[case] for case in configs):
            raise ConfigError(
                f"{name} cannot run on any case of the suite "
                f"({next(iter(skipped.values()))[name]})"
            )
    out: dict[str, Any] = {"scenarios": {}}
    for case, overrides in configs.items():
        env_config = {k: v for k, v in overrides.items() if k != "scenario"}
        results, rollouts = evaluate(
            [name for name in policies if name not in skipped[case]],
            overrides["scenario"],
            runs,
            seed,
            reference=ref,
            clairvoyant=clairvoyant,
            progress=progress,
            env_config=env_config,
            make_core=make_core,
        )
        results["meta"]["env_config"] = config_record(files[case], overrides)
        results["meta"]["bank"] = "env-config" if "bank" in env_config else "paper"
        results["meta"]["versions"] = started
        results["skipped"] = skipped[case]
        if bar:
            best = min(bar, key=lambda name: results["policies"][name]["armse_pos"])
            err2 = rollouts[best].squared_position_error
            results["bar"] = {
                "policy": best,
                "differences": {
                    name: paired_difference(r.squared_position_error, err2)
                    for name, r in rollouts.items()
                    if name not in bar
                },
            }
        out["scenarios"][case] = results
    tallied = [name for name in policies if name not in (bar or (ref,))]
    out["tally"] = suite_tally(out["scenarios"], tallied, "bar" if bar else "paired")
    out["meta"] = {
        "suite": suite,
        "reference": ref,
        "bar": list(bar),
        "runs": runs,
        "seed": seed,
        "seeds": f"{seed}..{seed + runs - 1}",
        "versions": started,
        "bootstrap": bootstrap_meta(),
    }
    return out


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


def suite_tally(
    scenarios: Mapping[str, Mapping[str, Any]], policies: Sequence[str], against: str = "paired"
) -> dict[str, dict[str, list[str]]]:
    """For each of ``policies``, the cases where its paired difference of the position ARMSE
    against the reference (``against="paired"``) or the bar (``"bar"``) is below zero (the 95 %
    CI's upper bound below zero), level (the CI includes zero, or undefined with one run) or
    above (its lower bound above zero), and those it was not run on."""
    tally: dict[str, dict[str, list[str]]] = {}
    for name in policies:
        sorted_cases: dict[str, list[str]] = {"below": [], "level": [], "above": [], "skipped": []}
        for case, r in scenarios.items():
            d = r[against]["differences"].get(name)
            if d is None:
                sorted_cases["skipped"].append(case)
            elif d["high"] is not None and d["high"] < 0:
                sorted_cases["below"].append(case)
            elif d["low"] is not None and d["low"] > 0:
                sorted_cases["above"].append(case)
            else:
                sorted_cases["level"].append(case)
        tally[name] = sorted_cases
    return tally


def paired_difference(
    err2: NDArray[np.float64], err2_ref: NDArray[np.float64]
) -> dict[str, float | None]:
    """:func:`~imm_gym.evaluation.rollout.paired_bootstrap` of ``(R, K)`` squared errors against
    the reference's; with one run (R = 1) every resample is that run, so the confidence interval
    is undefined: ``low`` and ``high`` are None (JSON null)."""
    d: dict[str, float | None] = {**paired_bootstrap(err2, err2_ref)}
    if err2.shape[0] < 2:
        d["low"] = d["high"] = None
    return d


def clairvoyant_bound(
    base: EnvConfig, runs: int, seed: int, policies: dict[str, dict[str, Any]]
) -> dict[str, Any]:
    """The clairvoyant filter's errors on the same runs (same seeds, same draws) and its role.

    Returns:
        Its :func:`~imm_gym.evaluation.metrics.tracking_errors` under the policies' divergence
        rule (:func:`~imm_gym.evaluation.clairvoyant.hold_diverged`), ``diverged`` (the runs it
        lost), ``peak_error`` and ``maneuver_response``, with ``role`` ``"bound"`` or
        ``"reference"``, ``note`` and ``beaten_by``
        (:func:`~imm_gym.evaluation.clairvoyant.clairvoyant_role` against ``policies``'
        scores); where the filter cannot follow the scenario or the bank
        (:func:`~imm_gym.evaluation.clairvoyant.unsupported`) only ``role`` ``"skipped"`` and
        the ``note`` saying why.
    """
    if base.vary.active:
        varied = ", ".join(base.vary.varied)
        return {
            "role": "skipped",
            "note": f"skipped: conditions vary per run ({varied}); the filter runs one sensor "
            "and sampling period",
        }
    batch = draw_batch(
        base.source, base.sensor, runs, seed, base.velocity_std, bank=base.linear_bank
    )
    reason = unsupported(batch.truth, base.bank)
    if reason is not None:
        return {"role": "skipped", "note": f"skipped: {reason}"}
    xs, Ps = clairvoyant_filter(
        batch.truth,
        batch.measurements.z[:, 1:],
        base.sensor,
        base.bank,
        batch.x0,
        batch.P0,
        base.filter,
        batch.measurements.detected[:, 1:],
    )
    truth = batch.truth.states[:, 1:]
    xs, diverged = hold_diverged(xs, Ps, truth, base.divergence_error, base.divergence_cov)
    errors = tracking_errors(xs, truth)
    true_model = true_model_index(batch.truth, base.bank)
    return {
        **errors,
        "diverged": int(diverged.sum()),
        "peak_error": peak_error(xs, truth),
        "maneuver_response": maneuver_response(xs, truth, true_model),
        **clairvoyant_role(errors, policies),
    }


class _NoBar:
    def update(self, n: int) -> None:
        """No progress display."""

    def close(self) -> None:
        """No progress display."""


def _progress_bar(total: int, enabled: bool) -> Any:
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc="evaluating", unit="step", leave=False)


#: Packages whose versions the results record where they are installed, beside the core's.
OPTIONAL_PACKAGES = ("torch", "stable-baselines3", "sb3-contrib", "numba")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m imm_gym.evaluate",
        description="Monte-Carlo evaluation of TPM policies with common random numbers.",
    )
    parser.add_argument(
        "--policy",
        action="append",
        default=[],
        help="policy to evaluate (repeatable; at least one, or --agent-seeds): "
        + "; ".join(f"{name}: {entry.help}" for name, entry in REGISTRY.items()).replace("%", "%%")
        + "; pretrained: the shipped PPO policy (five seeds' mean action, banks of three models); "
        "pretrained-per-model: the shipped policy shared by the models (banks of any size); or a "
        "trained agent's or an ensemble's directory",
    )
    parser.add_argument(
        "--scenario",
        help=" | ".join((*SCENARIOS, "random"))
        + " | a scenario JSON file | seed002 | seed003 (the NCV/CT/CTRA IMM-EKF "
        "of seed 002, the CV/CA/CT bank of seed 003; policies fixed, bbsca, sca); default: "
        "the --env-config file's scenario, else paper",
    )
    parser.add_argument(
        "--suite",
        metavar="NAME|DIR",
        help="evaluate on every scenario of the suite ("
        + "; ".join(f"{k}: {', '.join(v)}" for k, v in SUITES.items())
        + "), each with its configuration file (imm_gym/scenarios/suite/NAME.yaml), or on every "
        "configuration file (.yaml, .yml, .json) of the directory DIR (e.g. examples/probes), "
        "and print one table with, per policy, the cases below, level with and above the "
        "reference; a policy that cannot run on a case (an agent that cannot read its tracker, "
        "a rule whose settings it does not admit) is not run there, and the table says so",
    )
    parser.add_argument(
        "--env-config",
        type=Path,
        metavar="FILE",
        help="YAML or JSON file of EnvConfig fields (scenario, family, sensor, bank, filter, "
        "...) every policy runs on; --scenario replaces its scenario, --bank its bank and filter",
    )
    parser.add_argument("--runs", type=int, default=100, help="Monte-Carlo runs (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="run r uses seed + r (default 0)")
    parser.add_argument("--reference", help="policy the paired differences are taken against")
    parser.add_argument(
        "--agent-seeds",
        nargs="+",
        default=[],
        metavar="DIR",
        help="training seeds of one agent (two or more directories): each is evaluated as a "
        "policy, and their interquartile means with stratified bootstrap CIs are added (position "
        "ARMSE, mode accuracy, relative difference against --reference; with --suite also over "
        "all scenarios; JSON: \"across_seeds\")",
    )
    parser.add_argument(
        "--bar",
        nargs="+",
        default=[],
        metavar="POLICY",
        help="with --suite: on each case the better of these policies (the lower position ARMSE "
        "on its runs; added to --policy if absent) is the bar every other policy is tallied "
        "against, with paired 95%% CIs (JSON: \"bar\" per case, \"tally\"); e.g. --bar "
        "tip-imm best-fixed (--agent-seeds' relative differences stay against --reference)",
    )
    parser.add_argument("--json", type=Path, help="write the results to this JSON file")
    parser.add_argument("--plots", type=Path, help="write PNG figures to this directory")
    parser.add_argument(
        "--tradeoff",
        type=Path,
        metavar="FILE",
        help="write a PNG of position ARMSE against mode accuracy: every policy beside the "
        "classical IMM at each stay of the best-fixed grid (1/3 ... 0.999), on the same runs "
        "(their scores also go to the JSON, under \"tradeoff\")",
    )
    parser.add_argument("--no-clairvoyant", action="store_true", help="skip the clairvoyant bound")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument(
        "--bank",
        help=" | ".join(BANK_PRESETS)
        + " (default: the --env-config file's bank, else paper; paper: CV, CT(±4°/s), "
        "SVD-UKF; hetero: the NCV/CT/CTRA IMM-EKF of seed 002; "
        "cv-ct-continuous: the paper's models with white-noise-acceleration intensities)",
    )
    parser.add_argument(
        "--tuned",
        action="append",
        default=[],
        metavar="POLICY=FILE",
        help="seed scenarios: load the tuned bank of bbsca/sca from FILE instead of tuning",
    )
    parser.add_argument(
        "--animate",
        type=Path,
        metavar="FILE",
        help="write an animation of run 0 (seed --seed), every policy side by side on the same "
        "target and noise: FILE.gif (Pillow) or FILE.mp4 (needs ffmpeg)",
    )
    parser.add_argument(
        "--ray",
        nargs="?",
        const="",
        metavar="ADDR",
        help="run the tracking in chunks of runs on a Ray cluster (pip install -e '.[ray]'): "
        "ADDR auto or HOST:PORT, default Ray's (RAY_ADDRESS, a running local cluster, else a "
        "new local instance); the same numbers as without",
    )
    return parser


def output_problem(path: Path, kind: str) -> str | None:
    """Why ``path`` cannot receive the output ``kind`` (``"file"`` or ``"directory"``), or None.

    Checked before any evaluation runs, so an unwritable output costs nothing: ``path`` must not
    be an existing entry of the other kind, and a file must be created (a temporary one, removed
    at once) in it (a directory), next to it (a file) or in the nearest existing ancestor (where
    the missing directories will go).
    """
    if path.exists():
        if kind == "file" and path.is_dir():
            return "is a directory; give a file name"
        if kind == "directory" and not path.is_dir():
            return "exists and is not a directory"
    target = path if path.is_dir() else path.absolute().parent
    while not target.exists():
        target = target.parent
    if not target.is_dir():
        return f"{target} is not a directory"
    try:
        with tempfile.TemporaryFile(dir=target):
            pass
    except OSError as err:
        return f"cannot write in {target} ({err.strerror or err})"
    if path.is_file() and not os.access(path, os.W_OK):
        return "is not writable"
    return None


def seed_problem(seed: int, runs: int) -> str | None:
    """Why ``--seed seed --runs runs`` cannot be evaluated, or None: the runs' seeds
    ``seed .. seed + runs - 1`` and the tuners' training seeds ``seed + TRAIN_SEED_OFFSET + r``
    must not meet each other nor reach the agents' validation seeds or training slots."""
    if runs < 1:
        return f"--runs must be >= 1, got {runs}"
    if seed < 0:
        return f"--seed must be >= 0, got {seed}"
    if runs > MAX_RUNS:
        return (
            f"--runs must be in [1, {MAX_RUNS}], got {runs}: the run seeds --seed .. --seed + "
            f"--runs - 1 stay below the tuners' training seeds --seed + {TRAIN_SEED_OFFSET}+"
        )
    if seed > MAX_SEED:
        return (
            f"--seed must be in [0, {MAX_SEED}], got {seed}: the run seeds and the tuners' "
            f"training seeds (--seed + {TRAIN_SEED_OFFSET} + r, r < {TRAIN_RUNS}) stay below the "
            f"agents' validation seeds ({VALIDATION_SEED_BASE}+) and training slots "
            f"({TRAIN_SEED_BASE}+)"
        )
    return None


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    args.argv = argv
    problem = seed_problem(args.seed, args.runs)
    if problem:
        parser.error(problem)
    outputs = (("--json", args.json, "file"), ("--plots", args.plots, "directory"),
               ("--tradeoff", args.tradeoff, "file"))
    for flag, path, kind in outputs:
        problem = None if path is None else output_problem(path, kind)
        if problem:
            parser.error(f"{flag} {str(path)!r}: {problem}")
    if args.tradeoff is not None and args.tradeoff.suffix.lower() != ".png":
        # matplotlib takes the format from the suffix: '.txt' failed after the evaluation
        parser.error(f"--tradeoff {str(args.tradeoff)!r}: the figure is a PNG, end it in .png")
    _check_animate(parser, args)
    if len(args.agent_seeds) == 1:
        parser.error("--agent-seeds needs two or more directories (one is a --policy)")
    # the directory the loader reads, resolved: 'dir', 'dir/', './dir' and 'dir/agent.json' are
    # one seed, whose IQM would have zero-width CIs
    seed_dirs = [agent_directory(d).resolve() for d in args.agent_seeds]
    if len(set(seed_dirs)) != len(seed_dirs):
        parser.error(f"--agent-seeds given a directory twice: {args.agent_seeds}")
    # a --policy or --reference naming a seed's directory otherwise spelled is that seed
    spelling = dict(zip(seed_dirs, args.agent_seeds, strict=True))
    args.policy = [spelling.get(agent_directory(p).resolve(), p) for p in args.policy]
    if args.reference is not None:
        args.reference = spelling.get(agent_directory(args.reference).resolve(), args.reference)
    if args.bar and args.suite is None:
        parser.error("--bar applies to --suite")
    if args.tuned and args.scenario not in SYSTEMS:
        parser.error(f"--tuned applies to --scenario {'|'.join(SYSTEMS)}")
    if args.reference is not None and args.reference in args.agent_seeds:
        parser.error(
            f"--reference {args.reference} is one of --agent-seeds: the seeds are compared with a "
            "policy outside them"
        )
    args.policy += [d for d in args.bar if d not in args.policy]
    args.policy += [d for d in args.agent_seeds if d not in args.policy]
    if not args.policy:
        parser.error("give at least one --policy (or --agent-seeds)")
    seeds_only = args.agent_seeds and args.policy[0] in args.agent_seeds
    if seeds_only and args.reference is None and args.scenario not in SYSTEMS:
        parser.error(
            "--agent-seeds needs a reference outside the seeds: give --reference NAME (a "
            "--policy of its own)"
        )
    if args.ray is not None and args.scenario in SYSTEMS:
        parser.error(f"--ray does not apply to --scenario {args.scenario}")
    make_core = _cores(parser, args.ray)
    try:
        return _run(parser, args, make_core)
    except ShardError as err:
        # a shard that died mid-run (its process or node ended): one line, not Ray's traceback
        parser.exit(1, f"{parser.prog}: error: {err}\n")


def _run(
    parser: argparse.ArgumentParser,
    args: argparse.Namespace,
    make_core: Callable[[EnvConfig, int], Any],
) -> int:
    """The checked command line's evaluation: a suite, a seed system, or one scenario's."""
    if args.suite is not None:
        return _main_suite(parser, args, make_core)
    if args.scenario in SYSTEMS:
        return _main_system(parser, args)
    try:
        file_config = None if args.env_config is None else read_env_config(args.env_config)
        overrides = _run_config(args, file_config)
        scenario = overrides.pop("scenario")
        results, rollouts = evaluate(
            args.policy,
            scenario,
            args.runs,
            args.seed,
            reference=args.reference,
            clairvoyant=not args.no_clairvoyant,
            progress=not args.quiet and sys.stderr.isatty(),
            env_config=overrides,
            make_core=make_core,
        )
    except ConfigError as err:
        parser.error(str(err))
    results["meta"]["bank"] = args.bank or ("env-config" if "bank" in overrides else "paper")
    results["meta"]["env_config"] = config_record(args.env_config, file_config)
    if args.scenario is not None:
        results["meta"]["scenario"] = args.scenario
    elif results["meta"]["scenario"] == "file":
        results["meta"]["scenario"] = str(args.env_config)
    if args.agent_seeds:
        from imm_gym.cli.seeds import across_seeds, render_seeds

        results["across_seeds"] = across_seeds(results, args.agent_seeds)
    if args.tradeoff:
        results["tradeoff"] = _tradeoff(args, scenario, overrides, results, make_core)
    # the JSON before the tables: a table that cannot be printed loses no result
    _record(results, args)
    render_tables(results)
    if args.agent_seeds:
        render_seeds(results["across_seeds"], results["meta"]["scenario"])
    if args.plots:
        from imm_gym.evaluation.plots import write_figures

        base = evaluated_config(scenario, overrides)
        for path in write_figures(rollouts, args.plots, results["meta"], base):
            print(f"wrote {path}")
    if args.animate:
        _write_animation(args, rollouts, file_config)
    return 0


def _tradeoff(
    args: argparse.Namespace,
    scenario: Any,
    overrides: Mapping[str, Any],
    results: dict[str, Any],
    make_core: Callable[[EnvConfig, int], Any],
) -> dict[str, Any]:
    """``--tradeoff FILE``: the classical IMM at every stay of
    :func:`baselines.best_fixed.stay_grid` on the evaluation's runs and configuration, the
    figure of ARMSE against mode accuracy (:func:`~imm_gym.evaluation.plots.tradeoff_figure`)
    and the points."""
    from baselines.best_fixed import stay_grid
    from baselines.fixed import FixedTPM
    from imm_gym.evaluation.plots import tradeoff_figure

    base = evaluated_config(scenario, overrides)
    keys = ("armse_pos", "mode_accuracy", "mode_prob_tv")
    M = len(base.bank)
    fixed = FixedTPM(M)
    stays = stay_grid(M)
    tpms = np.stack([stay_tpm(M, stay) for stay in stays])
    cfg = evaluation_config(base, fixed.env_overrides)
    run = rollout(fixed, cfg, args.runs, args.seed, make_core=make_core, initial_tpms=tpms)
    fixed_points = {}
    for stay, part in zip(stays, run.groups(len(stays)), strict=True):
        row = score(part)
        fixed_points[stay] = {k: row[k] for k in keys}
    points = {name: {k: row[k] for k in keys} for name, row in results["policies"].items()}
    path = tradeoff_figure(points, fixed_points, args.tradeoff, results["meta"])
    print(f"wrote {path}")
    return {"policies": points, "fixed": {f"{s:.6g}": v for s, v in fixed_points.items()}}


def _cores(parser: argparse.ArgumentParser, address: str | None) -> Callable[[EnvConfig, int], Any]:
    """The roll-outs' core: in this process, or with ``--ray`` a pool of shards on the cluster
    at ``address`` ("" for Ray's default) (:mod:`imm_gym.evaluation.distributed`), joined and
    started when the first roll-out builds its core: after every check of the arguments, the
    configuration and the policies. Ray not installed is a usage error here; a cluster that
    cannot be joined, or whose shards do not start, a ConfigError naming ``--ray`` then; a shard
    that dies later a :class:`~imm_gym.evaluation.distributed.ShardError`, which :func:`main`
    reports in one line (exit status 1)."""
    if address is None:
        return TrackingCore
    try:
        from ray import init  # noqa: F401  (installed; importing it starts nothing)
    except ImportError:
        parser.error("--ray needs Ray: pip install -e '.[ray]' (make install-ray)")
    from imm_gym.evaluation.distributed import ShardPool, connect

    pools: list[ShardPool] = []

    def make_core(config: EnvConfig, n_envs: int) -> Any:
        if not pools:
            try:
                connect(address or None)
                pools.append(ShardPool())
            except (ConnectionError, TimeoutError, RuntimeError, ValueError) as err:
                reason = (str(err).strip().splitlines() or [type(err).__name__])[0]
                raise ConfigError(f"--ray {address or '(Ray default)'}: {reason}") from None
        return pools[0].core(config, n_envs)

    return make_core


def _run_config(
    args: argparse.Namespace, file_config: Mapping[str, Any] | None
) -> dict[str, Any]:
    """The EnvConfig overrides of the command line: ``file_config`` (the ``--env-config``
    file's, read once by the caller), its scenario replaced by ``--scenario`` (``paper`` when
    neither gives one) and its bank and filter by ``--bank``'s preset."""
    overrides = dict(file_config or {})
    if args.scenario is not None:
        overrides["scenario"] = load_source(args.scenario)
    overrides.setdefault("scenario", "paper")
    if args.bank is not None:
        if args.bank not in BANKS:
            raise ConfigError(f"--bank must be one of {list(BANKS)}, got {args.bank!r}")
        overrides.pop("filter", None)
        overrides = {**overrides, **expand_presets({"bank": args.bank}, "--bank")}
    EnvConfig.build(overrides)
    return overrides


def _check_animate(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--animate FILE``, before any evaluation: an episode scenario, a ``.gif`` (or a ``.mp4``
    with ffmpeg installed) that can be written."""
    from imm_gym.evaluation.animation import check_animation_path

    if args.animate is None:
        return
    if args.scenario in SYSTEMS:
        parser.error(f"--animate does not apply to --scenario {args.scenario}")
    try:
        check_animation_path(args.animate)
    except ConfigError as err:
        parser.error(f"--animate: {err}")
    problem = output_problem(args.animate, "file")
    if problem:
        parser.error(f"--animate {str(args.animate)!r}: {problem}")


def _write_animation(
    args: argparse.Namespace, rollouts: dict[str, Rollout], file_config: Mapping[str, Any] | None
) -> None:
    """Run 0 of every policy's roll-out side by side (:mod:`imm_gym.evaluation.animation`) on
    the command line's configuration (``file_config``: the ``--env-config`` file's overrides)."""
    from imm_gym.evaluation.animation import write_animation

    base = EnvConfig.build(_run_config(args, file_config))
    frames = write_animation(rollouts, base, args.seed, args.animate)
    print(f"wrote {args.animate} ({frames} frames of seed {args.seed}: {', '.join(rollouts)})")


def _main_suite(
    parser: argparse.ArgumentParser,
    args: argparse.Namespace,
    make_core: Callable[[EnvConfig, int], Any],
) -> int:
    """``--suite NAME|DIR``: every case of the suite with its configuration file, one table."""
    from imm_gym.cli.tables import render_suite_table

    unused = {
        "--scenario": args.scenario,
        "--env-config": args.env_config,
        "--bank": args.bank,
        "--plots": args.plots,
        "--tradeoff": args.tradeoff,
        "--animate": args.animate,
        "--tuned": args.tuned,
    }
    for flag in (f for f, given in unused.items() if given):
        parser.error(f"{flag} does not apply to --suite (each scenario has its configuration)")
    try:
        results = evaluate_suite(
            args.policy,
            args.suite,
            args.runs,
            args.seed,
            reference=args.reference,
            clairvoyant=not args.no_clairvoyant,
            progress=not args.quiet and sys.stderr.isatty(),
            make_core=make_core,
            bar=args.bar,
        )
    except ConfigError as err:
        parser.error(str(err))
    if args.agent_seeds:
        from imm_gym.cli.seeds import render_seeds, suite_across_seeds

        results["across_seeds"] = suite_across_seeds(results, args.agent_seeds)
    _record(results, args)
    render_suite_table(results)
    if args.agent_seeds:
        render_seeds(results["across_seeds"])
    return 0


def _main_system(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """``--scenario seed002|seed003``: classical IMM-EKF and its BBSCA / SCA-tuned versions."""
    from imm_gym.cli.tables import render_system_tables
    from imm_gym.papers.tuned_comparison import evaluate_system

    unused = {
        "--bank": args.bank is not None,
        "--env-config": args.env_config,
        "--reference": args.reference,
        "--plots": args.plots,
        "--tradeoff": args.tradeoff,
        "--agent-seeds": args.agent_seeds,
    }
    for flag in (f for f, given in unused.items() if given):
        parser.error(f"{flag} does not apply to --scenario {args.scenario}")
    tuned: dict[str, str] = {}
    for item in args.tuned:
        policy, sep, path = item.partition("=")
        if not sep or not policy or not path:
            parser.error(f"--tuned must be POLICY=FILE (e.g. bbsca=tuned.json), got {item!r}")
        if policy in tuned:
            parser.error(f"--tuned {policy} given twice: {tuned[policy]!r} and {path!r}")
        tuned[policy] = path
    started = versions(*OPTIONAL_PACKAGES)  # the code that runs, as evaluate's meta.versions
    try:
        results = evaluate_system(args.scenario, args.policy, args.runs, args.seed, tuned)
    except ValueError as err:
        parser.error(str(err))
    results["meta"]["versions"] = started
    _record(results, args)
    render_system_tables(results)
    return 0


def _record(results: dict[str, Any], args: argparse.Namespace) -> None:
    """The command line :func:`main` parsed (``args.argv``, quoted for a shell) in the results'
    ``meta`` and, with ``--json``, the results written."""
    results["meta"]["command"] = f"python -m imm_gym.evaluate {shlex.join(args.argv)}"
    path = args.json
    if path:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(record_json(results))
