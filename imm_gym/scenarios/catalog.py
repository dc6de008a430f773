"""Named scenarios: what ``EnvConfig(scenario=NAME)`` and ``python -m imm_gym.evaluate --scenario
NAME`` accept besides ``"random"`` (the configuration's :class:`~.segments.RandomFamily`) and a
user's scenario file. Adding one is one :func:`register` call here with a factory of its
:class:`~imm_gym.scenarios.segments.TruthSource`.
"""

from __future__ import annotations

from collections.abc import Callable

from imm_gym.scenarios.segments import TruthSource, paper_scenario

#: Every named scenario's factory, in declaration order.
SCENARIOS: dict[str, Callable[[], TruthSource]] = {}


def register(name: str, factory: Callable[[], TruthSource]) -> None:
    """Add a named scenario (names are unique; ``"random"`` is the configured family)."""
    if name in SCENARIOS or name == "random":
        raise ValueError(f"scenario {name!r} is already defined")
    SCENARIOS[name] = factory


register("paper", paper_scenario)  # the TIP-IMM paper's Table 1 (SPEC §3)
