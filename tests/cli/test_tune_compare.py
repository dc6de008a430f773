"""benchmarks/tune_compare.py's command line: a decay outside BBSCA's range is a usage error."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.mark.parametrize("decay", ["0", "-1", "nan", "inf", "x"])
def test_a_decay_outside_its_range_is_a_usage_error(
    decay: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Exit status 2 naming --decay and its range, before any tuning (even where only SCA, which
    has no decay, runs) — it was TunerConfig's ConfigError traceback after the setup."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    tune_compare = importlib.import_module("tune_compare")
    monkeypatch.setattr(sys, "argv", ["tune_compare.py", "--decay", decay, "--methods", "sca"])
    with pytest.raises(SystemExit) as stop:
        tune_compare.main()
    assert stop.value.code == 2
    assert "argument --decay: must be a real number in (0.0, inf)" in capsys.readouterr().err
