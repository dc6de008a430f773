"""The import contracts of pyproject.toml ``[tool.importlinter]``, checked by ``lint-imports``
(as ``make test`` does): the layers of imm_gym (cli > papers > evaluation | envs > sim >
scenarios > tracking > validation | seeding | kernel_cache), baselines and agents imported by
imm_gym.cli only, no import cycle between the children of any package of imm_gym."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_import_contracts_are_kept() -> None:
    lint_imports = Path(sys.executable).parent / "lint-imports"
    assert lint_imports.is_file(), f"{lint_imports} missing: pip install -e '.[dev]'"
    result = subprocess.run(
        [str(lint_imports), "--no-cache", "--no-logo"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    report = result.stdout + result.stderr
    assert "Contracts: 3 kept, 0 broken." in report, report
    assert result.returncode == 0, report


def test_the_docstring_names_the_layers_of_the_contract() -> None:
    """This module's docstring lists the layers pyproject.toml declares, top to bottom."""
    pyproject = (ROOT / "pyproject.toml").read_text()
    (block,) = re.findall(r"^layers = \[(.*?)\]", pyproject, re.S | re.M)
    layers = re.findall(r'"([^"]+)"', block)
    assert f"({' > '.join(layers)})" in " ".join(__doc__.split()), layers
