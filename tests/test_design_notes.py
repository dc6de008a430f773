"""The code docs/design.md names by name is there: every private function it quotes
(```_name```) and every ```file.py::name``` is defined in the repository's code, so a renamed
kernel shows here, not to a reader who searches for it."""

from __future__ import annotations

import re
from pathlib import Path

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
