"""Shared fixtures: the IMM engines, and no SB3 log folders left in the system temp folder.

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


@pytest.fixture(scope="session", autouse=True)
def sb3_log_folder(tmp_path_factory: pytest.TempPathFactory):
    """SB3's logger folder inside pytest's temp tree.

    A model trained without ``tensorboard_log`` (the tests' small ``learn`` calls) makes an
    empty ``SB3-<date>`` folder in the system's temp folder unless ``SB3_LOGDIR`` names one.
    """
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("SB3_LOGDIR", str(tmp_path_factory.mktemp("sb3_logs")))
        yield
