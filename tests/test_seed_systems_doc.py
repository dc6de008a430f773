"""docs/seed-systems.md's grid scan of seed 003's tuning objective: the code the document gives
prints the local minima its text describes (one minimum and two other dips, at the J it quotes)."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

DOCUMENT = (Path(__file__).resolve().parents[1] / "docs" / "seed-systems.md").read_text()


def test_the_grid_scan_prints_the_dips_the_text_gives() -> None:
    (code,) = [b for b in re.findall(r"```python\n(.*?)```", DOCUMENT, re.S) if "objective(" in b]
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(code, "docs/seed-systems.md", "exec"), {})
    minima = re.findall(r"10\^(\S+), Q_CA = 10\^(\S+): J (\d\.\d+)", printed.getvalue())
    assert [(cv, ca) for cv, ca, _ in minima] == [("-2", "-0.5"), ("0.5", "-2"), ("2", "-2")]
    text = " ".join(DOCUMENT.split())
    assert "its minimum there (J 1.0996 at `Q_CA` = 10^−0.5) and two other dips" in text
    for _, _, J in minima:
        assert f"J {J}" in text or f"J {float(J):.3f}" in text, J
