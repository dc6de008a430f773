"""Validation helpers shared by every configuration dataclass.

Every configurable object of imm_gym is a frozen dataclass that validates its fields in
``__post_init__`` and raises :class:`ConfigError` naming the field and the allowed range.
Dictionaries
(JSON/YAML files, ``gymnasium.make(..., config={...})``) are turned into dataclasses by
:func:`from_dict`, which rejects unknown keys instead of silently ignoring a misspelling.

**Numbers are numbers.** A numeric field accepts a real number (``int``, ``float`` or a numpy
scalar) and nothing else: a string such as ``"0.01"`` is rejected, never parsed, and so is a
boolean (``True`` is not 1 m). The helpers return the converted value — ``float`` for a real
field, ``int`` for an integer field (``50`` and ``50.0`` give ``50``; ``50.5`` and ``"50"`` are
rejected) — and every dataclass stores that value (:func:`store`), so a validated configuration
holds only Python floats and ints. The one place where text becomes a number is reading a file:
JSON already types its numbers, and YAML files are read with :func:`load_yaml`, whose YAML 1.2
float rule reads ``1e-3`` as the float 0.001 (PyYAML's default YAML 1.1 rule reads it as the
string ``"1e-3"``). A number quoted in a file (``p_min: "0.01"``) stays a string and is rejected.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import re
import reprlib
import sys
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration field or an input array is invalid; the message names it."""


#: The largest distance (m) a configuration may place anything at, or give as a sensor's noise:
#: 1e9 m, 2.6 times the Moon's distance, beyond any sensor's reach. Within it a position in
#: float64 resolves 1e-7 m, so that an error taken from two positions — a diverged run's held
#: estimate, the truth plus the divergence cap — keeps its metres (at 1e19 m the cap would round
#: away and a lost track score 0 m).
MAX_DISTANCE = 1e9
#: The largest target speed (m/s) a configuration may give, or drift to by its accelerations:
#: 1e5 m/s, thirteen times a low orbit's, beyond any tracked target.
MAX_SPEED = 1e5


#: How a refused value is shown in a message: at most 6 entries of a list, tuple or mapping, 3
#: levels deep, 60 characters of a string — a YAML file of nested aliases is a few hundred bytes
#: whose value would print in gigabytes.
class _Short(reprlib.Repr):
    """:class:`reprlib.Repr` that shows an integer too long to turn into text (Python refuses
    more than ``sys.get_int_max_str_digits()`` digits) by its size, wherever it is nested."""

    def repr_int(self, x: int, level: int) -> str:
        try:
            return super().repr_int(x, level)
        except ValueError:
            return f"an integer of {x.bit_length()} bits"


_SHORT = _Short()
_SHORT.maxlevel = 3
_SHORT.maxtuple = _SHORT.maxlist = _SHORT.maxdict = _SHORT.maxset = _SHORT.maxfrozenset = 6
_SHORT.maxstring = _SHORT.maxother = 60
_SHORT.maxlong = 40
#: The longest a refused value is shown, in characters.
SHOWN_CHARS = 200


def shown(value: Any) -> str:
    """``repr(value)`` shortened for a message: entries past the sixth and nesting past the third
    level are ``...``, and the text is cut at :data:`SHOWN_CHARS` characters."""
    text = _SHORT.repr(value)
    return text if len(text) <= SHOWN_CHARS else text[: SHOWN_CHARS - 3] + "..."


def _real(name: str, value: Any, expected: str) -> float:
    """``value`` as float if it is a real number (not a bool, not a string), else raise."""
    if type(value) is float:
        return value
    if isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "iuf":
        value = value[()]
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ConfigError(
            f"{name} must be {expected}, got {shown(value)} ({type(value).__name__})"
        )
    try:
        return float(value)
    except OverflowError:  # an integer such as 10**400, beyond the floats
        raise ConfigError(f"{name} must be {expected}, got an integer beyond the floats "
                          f"({int(value).bit_length()} bits)") from None


def check_finite(name: str, value: float) -> float:
    """Return ``value`` as float, or raise if it is not a finite real number."""
    v = _real(name, value, "a finite real number")
    if not math.isfinite(v):
        raise ConfigError(f"{name} must be finite, got {shown(value)}")
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
    """Return ``value`` as float, or raise naming ``name`` and the allowed interval.

    The interval is ``[lo, hi]``, open at ``lo`` with ``lo_open`` and at ``hi`` with ``hi_open``;
    NaN and infinities are outside it.
    """
    interval = _interval(lo, hi, lo_open, hi_open)
    v = _real(name, value, f"a real number in {interval}")
    bad_lo = v <= lo if lo_open else v < lo
    bad_hi = v >= hi if hi_open else v > hi
    if bad_lo or bad_hi or not math.isfinite(v):
        raise ConfigError(f"{name} must be in {interval}, got {shown(value)}")
    return v


def _interval(lo: float, hi: float, lo_open: bool, hi_open: bool) -> str:
    """``[lo, hi]`` with its open ends as parentheses (an infinite end is always open: NaN and
    infinities are refused)."""
    left = "(" if lo_open or lo == -math.inf else "["
    right = ")" if hi_open or hi == math.inf else "]"
    return f"{left}{lo}, {hi}{right}"


def check_int(name: str, value: int, lo: int, hi: float = math.inf) -> int:
    """Return ``value`` as int, or raise if it is not an integer in ``[lo, hi]``.

    An integral float (``50.0``) is the integer 50; ``50.5``, strings and booleans are rejected.
    """
    interval = _interval(lo, hi, False, False)
    integral = isinstance(value, (int, np.integer)) or (
        isinstance(value, (float, np.floating)) and float(value).is_integer()
    )
    if isinstance(value, (bool, np.bool_)) or not integral:
        raise ConfigError(
            f"{name} must be an integer in {interval}, got {shown(value)} ({type(value).__name__})"
        )
    v = int(value)
    if v < lo or v > hi:
        raise ConfigError(f"{name} must be an integer in {interval}, got {shown(value)}")
    return v


def check_choice(name: str, value: str, choices: tuple[str, ...]) -> str:
    """Return ``value`` if it is one of ``choices``, else raise listing them."""
    if not isinstance(value, str) or value not in choices:
        raise ConfigError(f"{name} must be one of {list(choices)}, got {shown(value)}")
    return value


def check_sequence(name: str, value: Any, length: int | None = None) -> tuple[Any, ...]:
    """Return ``value`` as a tuple if it is a list, tuple or 1-d array (of ``length`` entries).

    A string or a mapping is not a sequence of entries here: ``"ab"`` is rejected, not read as
    ``("a", "b")``.
    """
    if isinstance(value, np.ndarray) and value.ndim == 1:
        value = tuple(value.tolist())
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, Sequence):
        raise ConfigError(f"{name} must be a list, got {shown(value)} ({type(value).__name__})")
    if length is not None and len(value) != length:
        raise ConfigError(f"{name} must have {length} entries, got {len(value)}: {shown(value)}")
    return tuple(value)


def store(obj: object, name: str, value: T) -> T:
    """Set the field ``name`` of the frozen dataclass ``obj`` to its checked ``value``.

    ``__post_init__`` stores what the ``check_*`` helpers return (``float``, ``int``, ``tuple``)
    instead of what it was given, and returns it for further checks.
    """
    object.__setattr__(obj, name, value)
    return value


def from_dict(cls: type[T], data: Mapping[str, Any] | T, name: str | None = None) -> T:
    """Build the dataclass ``cls`` from a mapping, rejecting unknown and missing keys.

    Nested dataclass fields are built recursively when their value is a mapping. An instance of
    ``cls`` is returned unchanged.

    Raises:
        ConfigError: ``data`` is not a mapping, has a key ``cls`` does not know, lacks a key
            without a default, or a field's value is invalid (the message names ``name``).
    """
    if isinstance(data, cls):
        return data
    label = name or cls.__name__
    if not isinstance(data, Mapping):
        raise ConfigError(
            f"{label} must be a mapping or a {cls.__name__}, got {type(data).__name__}"
        )
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(str(k) for k in set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{label}: unknown key(s) {unknown}; allowed keys are {sorted(fields)}")
    required = [
        f.name
        for f in fields.values()
        if f.init and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    missing = [k for k in required if k not in data]
    if missing:
        raise ConfigError(f"{label}: missing key(s) {missing} (required: {required})")
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


#: YAML 1.2's float: a decimal point or an exponent (``1e-3``, ``.5``, ``2.``), ``.inf``, ``.nan``.
_YAML12_FLOAT = re.compile(
    r"""^(?:[-+]?(?:[0-9]+\.[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?
    |[-+]?[0-9]+[eE][-+]?[0-9]+
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""",
    re.X,
)


#: YAML 1.2's integer (core schema): decimal digits (a leading zero is still decimal), ``0o`` octal
#: or ``0x`` hexadecimal; not YAML 1.1's ``010`` octal, ``2:30`` base 60 or ``1_000``.
_YAML12_INT = re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$")
#: YAML 1.2's booleans: not YAML 1.1's ``yes``, ``no``, ``on``, ``off``.
_YAML12_BOOL = re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$")
_YAML11_TAGS = ("tag:yaml.org,2002:float", "tag:yaml.org,2002:int", "tag:yaml.org,2002:bool")


def load_yaml(text: str) -> Any:
    """Parse YAML ``text`` safely (no Python objects) with YAML 1.2's scalars, refusing a key
    given twice in one mapping.

    PyYAML follows YAML 1.1: ``1e-3`` is the string ``"1e-3"``, ``010`` is 8, ``2:30`` is 150
    and ``on`` is true. Here a plain scalar is typed as YAML 1.2's core schema types it: floats
    such as ``1e-3``, ``3.0e-4``, ``.5``; integers ``50`` and ``010`` (ten); booleans ``true``
    and ``false`` only. Anything else, and any quoted scalar, stays a string (which a numeric
    field then refuses by name).

    Raises:
        yaml.YAMLError: the text is not YAML, a mapping gives a key twice or an integer has
            more digits than Python reads (``sys.get_int_max_str_digits``; with its line), or
            the text nests deeper than Python's recursion limit lets it be built.
    """
    import yaml

    class Loader(yaml.SafeLoader):
        """SafeLoader with YAML 1.2's implicit float, int and bool, and unique keys."""

        def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:
            seen: set[Any] = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue  # '<<': keys merged in, which the mapping's own may override
                key = self.construct_object(key_node, deep=True)
                if not isinstance(key, (str, int, float)):
                    continue  # an unhashable key: the mapping's own construction refuses it
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {key!r} given twice in one mapping", key_node.start_mark
                    )
                seen.add(key)
            return super().construct_mapping(node, deep=deep)

    def construct_int(loader: Any, node: Any) -> int:
        text = loader.construct_scalar(node)
        if text[:2] in ("0o", "0x"):
            return int(text, 0)
        try:
            return int(text, 10)
        except ValueError:  # more digits than Python turns into an integer
            raise yaml.constructor.ConstructorError(
                None, None, f"an integer of {len(text.lstrip('+-'))} digits, more than the "
                f"{sys.get_int_max_str_digits()} Python reads", node.start_mark
            ) from None

    Loader.yaml_implicit_resolvers = {
        first: [(tag, rx) for tag, rx in resolvers if tag not in _YAML11_TAGS]
        for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }
    Loader.add_implicit_resolver("tag:yaml.org,2002:float", _YAML12_FLOAT, list("-+.0123456789"))
    Loader.add_implicit_resolver("tag:yaml.org,2002:int", _YAML12_INT, list("-+0123456789"))
    Loader.add_implicit_resolver("tag:yaml.org,2002:bool", _YAML12_BOOL, list("tTfF"))
    Loader.add_constructor("tag:yaml.org,2002:int", construct_int)
    try:
        return yaml.load(text, Loader=Loader)  # a SafeLoader: plain data only
    except RecursionError:
        raise yaml.YAMLError("nested too deeply") from None


def unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``json.loads``' ``object_pairs_hook``: an object, refusing a key given twice.

    Raises:
        ValueError: a key is given twice (callers name the file).
    """
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"key {key!r} given twice in one object")
        out[key] = value
    return out
