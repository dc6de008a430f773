"""Configuration bounds at their edges: a closed end accepts its own value, the next value past
it is refused naming the field and the interval."""

from __future__ import annotations

import pytest

from imm_gym import ConfigError, MotionModel
from imm_gym.tracking.hetero import LinearModel
from imm_gym.validation import check_int


def test_an_integer_interval_includes_its_upper_end() -> None:
    # [4, 6] holds 4, 5 and 6 (written out: the documented closed interval)
    assert [check_int("n", n, 4, 6) for n in (4, 5, 6)] == [4, 5, 6]
    with pytest.raises(ConfigError, match=r"n must be an integer in \[4, 6\], got 7"):
        check_int("n", 7, 4, 6)
    # a six-dimensional linear model of the heterogeneous bank sits on that upper end
    assert LinearModel(MotionModel("cv"), dim=6).dim == 6
    with pytest.raises(ConfigError, match=r"model\.dim .* must be an integer in \[4, 6\], got 7"):
        LinearModel(MotionModel("cv"), dim=7)
