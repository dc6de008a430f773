"""A comparison on every case of a benchmark suite (``python -m imm_gym.evaluate --suite``).

A named suite (:data:`~imm_gym.scenarios.catalog.SUITES`) reads the configuration files shipped
with the package, a directory the user's own; :func:`evaluate_suite` runs
:func:`~imm_gym.cli.comparison.evaluate` on each case with the same seeds, after checking every
file and every policy against every case, and :func:`suite_tally` sorts the cases by each policy's
paired difference against the reference or the bar: below, level with, above.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from baselines import REGISTRY
from imm_gym.cli.comparison import (
    OPTIONAL_PACKAGES,
    bootstrap_meta,
    config_record,
    evaluate,
    evaluated_config,
    paired_difference,
)
from imm_gym.cli.policies import cannot_run
from imm_gym.cli.provenance import versions
from imm_gym.scenarios.catalog import SUITE_CONFIGS, SUITES
from imm_gym.sim.config_file import bank_name, read_env_config
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.validation import ConfigError

#: The files a directory suite reads (``--suite DIR``).
CONFIG_SUFFIXES = (".yaml", ".yml", ".json")


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
    """:func:`~imm_gym.cli.comparison.evaluate` on every case of ``suite`` with its own
    configuration file (:func:`suite_configs`; baselines, best-fixed search and trained agents on
    it), the same seeds on each. Every file and every trained agent is checked against every
    configuration before any work; an agent whose network cannot read a case's tracker
    (:class:`~imm_gym.cli.policies.UnreadableTracker`: a bank of another size) is not run there,
    and the results say why (:func:`~imm_gym.cli.policies.cannot_run`: a rule whose settings a
    case does not admit is not run there either); a policy that can run on no case, or a
    reference (``fixed`` when among the policies, else the first rule, else the first policy)
    or a policy of ``bar`` that cannot run on one, is refused.

    ``bar``: policies among ``policies`` whose better on each case (the lower position ARMSE on
    its runs) is the bar the others are tallied against there (``("tip-imm", "best-fixed")``:
    the better of the two rules); picking it on the same runs makes the bar, if anything,
    harder to meet.

    Returns:
        ``{"scenarios": {CASE: evaluate's results (``meta.bank``: the bank preset's name, or
        ``env-config`` where the case's file gives a bank of its own, as with ``--env-config``,
        :func:`~imm_gym.sim.config_file.bank_name`; ``meta.env_config``: the file and its
        overrides, :func:`~imm_gym.cli.comparison.config_record`), with "skipped": {POLICY:
        reason}} and, with ``bar``, "bar": {"policy": NAME, "differences": {POLICY: paired
        difference}}},
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
        results["meta"]["bank"] = bank_name(env_config)
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

