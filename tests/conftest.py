"""Shared fixtures: the IMM backends.

:class:`imm_gym.IMM` may offer several backends computing the same equations (``backend="numpy"``,
the vectorized reference, and ``"numba"``, the fused compiled cycle). Tests that build an IMM take
the ``make_imm`` fixture and run once per backend; without a ``backend`` argument they run once.
"""

from __future__ import annotations

import inspect

import pytest

from imm_gym import IMM

HAS_BACKENDS = "backend" in inspect.signature(IMM).parameters
BACKENDS = ["numpy", "numba"] if HAS_BACKENDS else [None]


def build_imm(models, sensor, filter="ukf", backend=None, **kwargs) -> IMM:
    if backend is None:
        return IMM(models, sensor, filter, **kwargs)
    return IMM(models, sensor, filter, backend=backend, **kwargs)


@pytest.fixture(params=BACKENDS, ids=lambda b: b or "default")
def backend(request: pytest.FixtureRequest) -> str | None:
    return request.param


@pytest.fixture
def make_imm(backend: str | None):
    """``make_imm(models, sensor, filter="ukf")`` with the parametrized backend."""

    def _make(models, sensor, filter="ukf", **kwargs) -> IMM:
        return build_imm(models, sensor, filter, backend, **kwargs)

    return _make
