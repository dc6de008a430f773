"""Shared fixtures: the IMM engines.

:class:`imm_gym.IMM` runs the same equations on two engines (``engine="numpy"``, the vectorized
reference, and ``"compiled"``, the fused numba cycle). Tests that build an IMM take the
``make_imm`` fixture and run once per engine.
"""

from __future__ import annotations

import pytest

from imm_gym import IMM

#: the engines every ``make_imm`` test runs on (``"auto"`` only picks one of them)
ENGINES = ["numpy", "compiled"]


@pytest.fixture(params=ENGINES)
def engine(request: pytest.FixtureRequest) -> str:
    return request.param


@pytest.fixture
def make_imm(engine: str):
    """``make_imm(models, sensor, filter="ukf")`` on the parametrized engine."""

    def _make(models, sensor, filter="ukf", **kwargs) -> IMM:
        return IMM(models, sensor, filter, engine=engine, **kwargs)

    return _make
