"""docs/design.md against the code: every private function it quotes (```_name```) and every
```file.py::name``` is defined in the repository's code, so a renamed kernel shows here, not to
a reader who searches for it; the figures it gives a command or code for are what they print."""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import pytest

from imm_gym.cli import evaluate

ROOT = Path(__file__).resolve().parents[1]
DESIGN = (ROOT / "docs" / "design.md").read_text()
SOURCES = [p for d in ("imm_gym", "baselines", "agents") for p in (ROOT / d).rglob("*.py")]


def defined(name: str, files: list[Path]) -> bool:
    """Whether one of ``files`` defines ``name`` (a function, class or module-level name)."""
    pattern = re.compile(rf"^\s*(?:def|class)\s+{name}\b|^{name}\s*[:=]", re.M)
    return any(pattern.search(f.read_text()) for f in files)


def test_the_private_functions_it_names_exist() -> None:
    names = set(re.findall(r"`(_[A-Za-z]\w*)`", DESIGN))
    assert names, "no private name found: the pattern no longer matches the document"
    missing = sorted(n for n in names if not defined(n, SOURCES))
    assert not missing, f"docs/design.md names {missing}, defined nowhere"


def test_the_file_and_name_pairs_it_names_exist() -> None:
    pairs = re.findall(r"`([\w/]+\.py)::(\w+)`", DESIGN)
    assert pairs, "no file::name found: the pattern no longer matches the document"
    missing = []
    for path, name in pairs:
        files = [p for p in SOURCES if p.as_posix().endswith(path)]
        if not files or not defined(name, files):
            missing.append(f"{path}::{name}")
    assert not missing, f"docs/design.md names {missing}, not in those files"


def test_tip_imm_without_its_floor_prints_the_figures_the_text_gives() -> None:
    """The code of "TIP-IMM without its floor" prints the losses the text quotes."""
    (code,) = [b for b in re.findall(r"```python\n(.*?)```", DESIGN, re.S) if "TIPIMM" in b]
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(code, "docs/design.md", "exec"), {})
    losses = dict(re.findall(r"(\w+): (\+\d+\.\d) %", printed.getvalue()))
    assert set(losses) == {"literal", "intent"}, printed.getvalue()
    text = " ".join(DESIGN.split())
    for reading, loss in losses.items():
        assert f"{loss} % with the {reading} reading" in text, (reading, loss)


@pytest.mark.parametrize(
    ("bank", "scenario", "armse"),
    [
        ("cv-ct-continuous", "paper", "18.342"),
        ("paper", "paper", "18.346"),
        ("cv-ct-continuous", "random", "21.157"),
        ("paper", "random", "21.152"),
    ],
)
def test_the_continuous_bank_at_one_second_tracks_as_the_text_says(
    bank: str, scenario: str, armse: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The command "Banks defined physically" gives (with its --bank and --scenario) prints the
    ARMSE the text quotes."""
    text = " ".join(DESIGN.split())
    command = ("python -m imm_gym.evaluate --bank cv-ct-continuous --policy fixed --scenario "
               "paper --runs 200 --seed 0")
    assert f"`{command}`, then `--bank paper`, and both with `--scenario random`" in text
    assert armse in text
    argv = command.split()[3:]
    argv[argv.index("--bank") + 1], argv[argv.index("--scenario") + 1] = bank, scenario
    out = tmp_path / "evaluation.json"
    assert evaluate.main([*argv, "--no-clairvoyant", "--quiet", "--json", str(out)]) == 0
    capsys.readouterr()
    assert f"{json.loads(out.read_text())['policies']['fixed']['armse_pos']:.3f}" == armse
