"""The import contracts of pyproject.toml ``[tool.importlinter]``, checked by ``lint-imports``
(as ``make test`` does): the layers of imm_gym (cli > papers > evaluation | envs > sim >
scenarios > tracking > validation | seeding | kernel_cache), baselines and agents imported by
imm_gym.cli only, no gymnasium import in the numerical core (tracking, scenarios, sim,
evaluation), no import cycle between the children of any package of imm_gym."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def lint_imports(root: Path) -> subprocess.CompletedProcess[str]:
    """``lint-imports`` on the packages and pyproject.toml under ``root``."""
    executable = Path(sys.executable).parent / "lint-imports"
    assert executable.is_file(), f"{executable} missing: pip install -e '.[dev]'"
    return subprocess.run(
        [str(executable), "--no-cache", "--no-logo"],
        cwd=root,
        env={**os.environ, "PYTHONPATH": str(root), "PYTHONDONTWRITEBYTECODE": "1"},
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_import_contracts_are_kept() -> None:
    result = lint_imports(ROOT)
    report = result.stdout + result.stderr
    assert "Contracts: 4 kept, 0 broken." in report, report
    assert result.returncode == 0, report


@pytest.mark.parametrize(
    "module",
    ["tracking/filters.py", "scenarios/catalog.py", "sim/core.py", "evaluation/metrics.py"],
)
def test_a_gymnasium_import_in_the_numerical_core_breaks_a_contract(
    module: str, tmp_path: Path
) -> None:
    """A copy of the sources with ``import gymnasium`` added to one module of the core fails."""
    for package in ("imm_gym", "baselines", "agents"):
        shutil.copytree(ROOT / package, tmp_path / package,
                        ignore=shutil.ignore_patterns("__pycache__", "pretrained*"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    with (tmp_path / "imm_gym" / module).open("a") as source:
        source.write("\nimport gymnasium  # noqa\n")
    result = lint_imports(tmp_path)
    report = result.stdout + result.stderr
    assert "no gymnasium import in the numerical core BROKEN" in report, report
    assert result.returncode != 0, report


def test_the_docstring_names_the_layers_of_the_contract() -> None:
    """This module's docstring lists the layers pyproject.toml declares, top to bottom."""
    pyproject = (ROOT / "pyproject.toml").read_text()
    (block,) = re.findall(r"^layers = \[(.*?)\]", pyproject, re.S | re.M)
    layers = re.findall(r'"([^"]+)"', block)
    assert f"({' > '.join(layers)})" in " ".join(__doc__.split()), layers
