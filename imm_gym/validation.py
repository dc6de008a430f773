"""Validation helpers shared by every configuration dataclass.

Every configurable object of imm_gym is a frozen dataclass that validates its fields in
``__post_init__`` and raises :class:`ConfigError` naming the field and the allowed range.
Dictionaries
(JSON/YAML files, ``gymnasium.make(..., config={...})``) are turned into dataclasses by
:func:`from_dict`, which rejects unknown keys instead of silently ignoring a misspelling.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration field or an input array is invalid; the message names it."""


def check_finite(name: str, value: float) -> float:
    """Return ``value`` as float, or raise if it is not a finite real number."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ConfigError(f"{name} must be finite, got {value!r}")
    return v


def check_range(
    name: str,
    value: float,
    lo: float = -math.inf,
    hi: float = math.inf,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> float:
    """Return ``value`` as float, or raise naming ``name`` and the allowed interval."""
    v = check_finite(name, value)
    bad_lo = v <= lo if lo_open else v < lo
    bad_hi = v >= hi if hi_open else v > hi
    if bad_lo or bad_hi:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        raise ConfigError(f"{name} must be in {left}{lo}, {hi}{right}, got {value!r}")
    return v


def check_int(name: str, value: int, lo: int, hi: float = math.inf) -> int:
    """Return ``value`` as int, or raise if it is not an integer in ``[lo, hi]``."""
    integral = isinstance(value, (int, np.integer)) or (
        isinstance(value, (float, np.floating)) and float(value).is_integer()
    )
    if isinstance(value, (bool, np.bool_)) or not integral:
        raise ConfigError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if v < lo or v > hi:
        raise ConfigError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    return v


def check_choice(name: str, value: str, choices: tuple[str, ...]) -> str:
    """Return ``value`` if it is one of ``choices``, else raise listing them."""
    if value not in choices:
        raise ConfigError(f"{name} must be one of {list(choices)}, got {value!r}")
    return value


def from_dict(cls: type[T], data: Mapping[str, Any] | T, name: str | None = None) -> T:
    """Build the dataclass ``cls`` from a mapping, rejecting unknown keys.

    Nested dataclass fields are built recursively when their value is a mapping. An instance of
    ``cls`` is returned unchanged.
    """
    if isinstance(data, cls):
        return data
    label = name or cls.__name__
    if not isinstance(data, Mapping):
        raise ConfigError(
            f"{label} must be a mapping or a {cls.__name__}, got {type(data).__name__}"
        )
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{label}: unknown key(s) {unknown}; allowed keys are {sorted(fields)}")
    kwargs: dict[str, Any] = {}
    hints = _resolved_types(cls)
    for key, value in data.items():
        target = hints.get(key)
        if dataclasses.is_dataclass(target) and isinstance(value, Mapping):
            value = from_dict(target, value, f"{label}.{key}")  # type: ignore[arg-type]
        elif isinstance(value, list):
            value = tuple(value)
        kwargs[key] = value
    return cls(**kwargs)


def _resolved_types(cls: type) -> dict[str, Any]:
    import typing

    try:
        return typing.get_type_hints(cls)
    except Exception:  # pragma: no cover - unresolved forward references: no nesting
        return {}
