"""The commands the README and docs/ give in their ``bash`` blocks still parse: every
``python -m imm_gym.evaluate``, ``python -m imm_gym.track`` and ``python train.py`` line is put
through the tool's own argument parser (nothing runs), and every file of the repository it names
exists — so a renamed flag or a moved example shows here, not in a user's terminal."""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

import train
from imm_gym.cli import evaluate, track

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: The tools a documented command may call, by the words that call them.
TOOLS: dict[tuple[str, ...], Callable] = {
    ("-m", "imm_gym.evaluate"): evaluate.build_parser,
    ("-m", "imm_gym.track"): track.build_parser,
    ("train.py",): train.build_parser,
}
#: Where a documented path must exist (the rest are the user's: runs/, radar.csv, ...).
TRACKED = ("examples/", "agents/hyperparams/", "imm_gym/scenarios/")
#: Words that end a command on a shell line.
SHELL_OPERATORS = {";", "&&", "||", "|", "&", "do", "done", "then", "fi"}


def documented_commands() -> Iterator[tuple[str, tuple[str, ...], list[str]]]:
    """``(where, tool, argv)`` for every call of a tool of :data:`TOOLS` in a ``bash`` block."""
    for document in DOCUMENTS:
        for block in re.findall(r"```bash\n(.*?)```", document.read_text(), re.S):
            for line in block.replace("\\\n", " ").splitlines():
                # a command substitution is one word to the tool
                line = re.sub(r"\$\([^)]*\)", "X", line)
                lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|")
                lexer.whitespace_split = True
                lexer.commenters = "#"
                words = list(lexer)
                for i, word in enumerate(words):
                    if not word.endswith("python"):
                        continue
                    for tool in TOOLS:
                        if tuple(words[i + 1 : i + 1 + len(tool)]) != tool:
                            continue
                        argv = []
                        for arg in words[i + 1 + len(tool) :]:
                            if arg in SHELL_OPERATORS:
                                break
                            argv.append(arg)
                        yield f"{document.name}: {line.strip()}", tool, argv


COMMANDS = list(documented_commands())


def test_the_documents_give_commands_of_every_tool() -> None:
    """The extraction finds what the documents show (it cannot pass by finding nothing)."""
    assert len(COMMANDS) >= 20
    assert {tool for _, tool, _ in COMMANDS} == set(TOOLS)


@pytest.mark.parametrize(("where", "tool", "argv"), COMMANDS, ids=[c[0][:80] for c in COMMANDS])
def test_a_documented_command_parses(where: str, tool: tuple[str, ...], argv: list[str]) -> None:
    """It runs as shown (no ``[optional]`` usage brackets) and the tool's parser accepts it."""
    assert not [a for a in argv if a.startswith("[")], f"{where}: usage syntax in a bash block"
    stderr = io.StringIO()
    try:
        with contextlib.redirect_stderr(stderr):
            TOOLS[tool]().parse_args(argv)
    except SystemExit:
        pytest.fail(f"{where}\n{stderr.getvalue().strip()}")


@pytest.mark.parametrize(("where", "tool", "argv"), COMMANDS, ids=[c[0][:80] for c in COMMANDS])
def test_a_documented_file_exists(where: str, tool: tuple[str, ...], argv: list[str]) -> None:
    named = [a for a in argv if a.startswith(TRACKED) and not set(a) & set("*{}$")]
    missing = [a for a in named if not (ROOT / a).exists()]
    assert not missing, f"{where}: {missing} not in the repository"

