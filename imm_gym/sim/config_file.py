"""Configuration files: one YAML or JSON mapping of :class:`~imm_gym.sim.env_config.EnvConfig`
fields, read by ``python -m imm_gym.evaluate --env-config FILE`` and ``python train.py
--env-config FILE``.

The keys are EnvConfig's field names (``scenario``, ``family``, ``sensor``, ``bank``, ``filter``,
...), nested mappings are the fields of the nested dataclasses, and a key not given keeps
EnvConfig's default. ``bank`` is either a list of :class:`~imm_gym.tracking.models.MotionModel`
mappings (``{kind: ct, turn_rate_deg: 3, noise: continuous, intensity: 1.0}``) or the name of a
preset of :data:`imm_gym.sim.presets.BANK_PRESETS` (``bank: cv-ct-continuous``), which stands
for the preset's overrides (its bank, and ``filter`` where the preset sets one; a ``filter``
given in the file wins). Files are read with :func:`imm_gym.validation.load_yaml` (YAML 1.2
floats) or :func:`json.loads`; a wrong key, a wrong type or a quoted number is a
:class:`~imm_gym.validation.ConfigError` naming the key and the file.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.validation import ConfigError, load_yaml, shown, unique_keys

#: The fields that make the tracker (what a trained agent records as ``trained_on`` and the
#: evaluation reports as ``evaluated_on``): the sensor, the bank, the filter and its TPM prior.
TRACKER_FIELDS = ("sensor", "bank", "filter", "initial_stay", "sojourn")
#: The fields that say where the targets and their conditions come from, and how each track
#: starts (``velocity_std``: the prior standard deviation of the first velocity estimate, which
#: is the true velocity, SPEC §6): every policy evaluated on a configuration meets the same.
TARGET_FIELDS = ("scenario", "family", "vary", "velocity_std")
#: The fields of how an evaluation is run: when a track counts as diverged (and is capped) and
#: which engine computes it. Every policy of an evaluation runs with the same.
EVALUATION_FIELDS = ("divergence_error", "divergence_cov", "engine")
#: What the evaluated configuration gives every policy — its tracker, its targets, how it is
#: run: a trained agent records the ones it was trained with, and does not carry them over.
EVALUATED_FIELDS = (*TRACKER_FIELDS, *TARGET_FIELDS, *EVALUATION_FIELDS)


def plain(value: Any) -> Any:
    """``value`` as plain data (dicts, lists, numbers, strings, None): dataclasses become the
    mappings of their fields, tuples become lists, recursively."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


def expand_presets(data: Mapping[str, Any], where: str) -> dict[str, Any]:
    """``data`` with a bank preset name replaced by the preset's overrides (as plain data);
    keys given in ``data`` besides ``bank`` win over the preset's."""
    out = dict(data)
    bank = out.get("bank")
    if isinstance(bank, str):
        if bank not in BANK_PRESETS:
            raise ConfigError(
                f"{where}: bank must be a list of models or one of {list(BANK_PRESETS)}, "
                f"got {shown(bank)}"
            )
        preset = plain(BANK_PRESETS[bank])
        del out["bank"]
        out = {**preset, **out}
        if "bank" not in out:  # the paper preset: EnvConfig's default bank
            out["bank"] = plain(EnvConfig().bank)
    return out


def bank_name(overrides: Mapping[str, Any]) -> str:
    """The name a run's bank is recorded by (``meta.bank``): the preset of
    :data:`~imm_gym.sim.presets.BANK_PRESETS` whose bank the checked ``overrides`` build (by
    name or written out, compared as built: a model's unwritten fields at their defaults;
    ``"paper"`` where they give none), else ``"env-config"``: a bank of the file's own."""
    bank = plain(EnvConfig.build(overrides).bank)
    for name in BANK_PRESETS:
        if plain(EnvConfig.build(expand_presets({"bank": name}, "bank")).bank) == bank:
            return name
    return "env-config"


def parse_env_config(data: Any, where: str) -> dict[str, Any]:
    """The checked overrides of a file's parsed content (plain data, bank presets expanded).

    Raises:
        ConfigError: ``data`` is not a mapping or is not a valid EnvConfig; the message starts
            with ``where`` and names the key.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(
            f"{where}: must hold a mapping of EnvConfig fields, got {type(data).__name__}"
        )
    overrides = expand_presets(data, where)
    try:
        EnvConfig.build(overrides)
    except ConfigError as err:
        raise ConfigError(f"{where}: {err}") from None
    return overrides


def read_env_config(path: str | Path) -> dict[str, Any]:
    """The EnvConfig overrides of the YAML (``.yaml``, ``.yml``) or JSON file ``path``, checked
    (:func:`parse_env_config`) before anything runs. A relative ``detector_weights`` is taken
    from the file's directory and made absolute (links resolved), so that every process opens
    the same file whatever its working directory (a Ray worker's is its node's).

    Raises:
        ConfigError: the file cannot be read or parsed, or its content is invalid; the message
            names the file and the key.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path}: cannot read ({err})") from None
    if path.suffix in (".yaml", ".yml"):
        import yaml

        try:
            data = load_yaml(text)
        except yaml.YAMLError as err:
            raise ConfigError(f"{path}: not valid YAML ({' '.join(str(err).split())})") from None
    elif path.suffix == ".json":
        try:
            data = json.loads(text, object_pairs_hook=unique_keys)
        except ValueError as err:  # JSONDecodeError is one, as is a key given twice
            raise ConfigError(f"{path}: not valid JSON ({err})") from None
        except RecursionError:
            raise ConfigError(f"{path}: not valid JSON (nested too deeply)") from None
    else:
        raise ConfigError(f"{path}: a configuration file ends in .yaml, .yml or .json")
    weights = data.get("detector_weights") if isinstance(data, Mapping) else None
    if isinstance(weights, str):
        # a detector file named relative to the configuration file, wherever it is run from
        try:
            data = {**data, "detector_weights": str((path.parent / weights).resolve())}
        except (OSError, ValueError, RuntimeError) as err:  # a NUL byte, a loop of links
            raise ConfigError(
                f"{path}: detector_weights {shown(weights)} is not a path ({err})"
            ) from None
    return parse_env_config(data, str(path))


def env_config_dict(config: EnvConfig) -> dict[str, Any]:
    """Every field of ``config`` as plain data: ``EnvConfig.build(env_config_dict(c)) == c``."""
    return plain(config)  # type: ignore[no-any-return]


def write_env_config(config: EnvConfig, path: str | Path) -> None:
    """Write every field of ``config`` to ``path``: YAML (``.yaml``, ``.yml``) or JSON."""
    import yaml

    path = Path(path)
    data = env_config_dict(config)
    if path.suffix in (".yaml", ".yml"):
        path.write_text(yaml.safe_dump(data, sort_keys=False))
    elif path.suffix == ".json":
        path.write_text(json.dumps(data, indent=2))
    else:
        raise ConfigError(f"{path}: a configuration file ends in .yaml, .yml or .json")


def tracker_of(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """The :data:`TRACKER_FIELDS` of the EnvConfig that ``overrides`` give, as plain data."""
    config = EnvConfig.build({k: v for k, v in overrides.items() if k in TRACKER_FIELDS})
    return {name: plain(getattr(config, name)) for name in TRACKER_FIELDS}
