"""Monte-Carlo comparison of TPM policies on common random numbers (:func:`evaluate`, the engine
of ``python -m imm_gym.evaluate``: :mod:`imm_gym.cli.evaluate`).

Every policy (:mod:`imm_gym.cli.policies`) runs through :func:`imm_gym.evaluation.rollout.rollout`
on the same R runs — same targets, same sensor noise — on one configuration
(:func:`evaluated_config`) and is scored by the same code
(:func:`~imm_gym.evaluation.rollout.score`); the paired differences of the position ARMSE against a
reference carry 95 % bootstrap confidence intervals (:func:`paired_difference`), the clairvoyant
filter runs on the same draws (:func:`clairvoyant_bound`), and the results' ``meta`` records what
was run: seeds, steps, configuration, versions, the divergence rule and the bootstrap's settings.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from baselines import REGISTRY
from imm_gym.cli.policies import agent_overrides, make_policy
from imm_gym.cli.provenance import versions
from imm_gym.evaluation.clairvoyant import (
    clairvoyant_filter,
    clairvoyant_role,
    hold_diverged,
    unsupported,
)
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
from imm_gym.scenarios.catalog import SCENARIOS
from imm_gym.scenarios.segments import Scenario, true_model_index
from imm_gym.sim.config_file import plain
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.sim.mixture import AGENT_FIELDS
from imm_gym.sim.model_order import for_bank
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.validation import ConfigError, from_dict, unique_keys

#: ``--bank``: environment overrides of each bank.
BANKS = BANK_PRESETS


#: Packages whose versions the results record where they are installed, beside the core's.
OPTIONAL_PACKAGES = ("torch", "stable-baselines3", "sb3-contrib", "numba")


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
    """Score ``policies`` on R common-random-number runs (the results: :mod:`imm_gym.cli.evaluate`).

    ``extra`` adds policy objects by name: ``{name: (policy, env_overrides)}`` (a freshly trained
    agent, say); they are evaluated first. ``bank``: a preset of
    :data:`~imm_gym.sim.presets.BANK_PRESETS` applied over ``env_config`` (``paper``, the
    default, changes nothing: EnvConfig's bank or the file's); ``hetero`` has no clairvoyant
    filter, said in the results. ``env_config``: EnvConfig overrides (a configuration file's,
    :func:`~imm_gym.sim.config_file.read_env_config`) every policy runs on, ``scenario``
    replacing theirs; what an agent is trained as (:data:`~imm_gym.sim.mixture.AGENT_FIELDS`:
    action mode, features, reward) is each policy's own and is dropped from it, a detector
    network it names kept (the rules' learned detector). Trained agents (``extra`` and paths)
    are checked against it before any work (:func:`~imm_gym.cli.policies.agent_overrides`).
    The clairvoyant row is labelled a bound or a reference, or skipped with the reason
    (:func:`clairvoyant_bound`).
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

