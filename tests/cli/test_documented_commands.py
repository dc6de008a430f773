"""The commands the README and docs/ give in their ``bash`` blocks still parse: every call of a
tool of :data:`TOOLS` (``python -m imm_gym.evaluate``, ``imm_gym.track``, ``agents.detector``,
``agents.export``, ``agents.ensemble``, ``python train.py``, ``examples/stay_selector.py``,
``benchmarks/tune_compare.py``) is put through the tool's own argument parser (nothing runs), and
every file of the repository it names exists — so a renamed flag or a moved example shows here,
not in a user's terminal."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import io
import re
import shlex
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from unittest import mock

import pytest

import train
from agents import detector
from imm_gym.cli import evaluate, track
from imm_gym.validation import ConfigError

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


class Parsed(Exception):
    """Stops a tool's ``main`` once its parser has accepted the command line."""


def parsed_by_main(load: Callable[[], Callable[..., object]]) -> Callable[[list[str]], None]:
    """The parse of a tool whose parser is built inside its ``main`` (``load()`` returns it):
    ``main`` runs with ``argv`` (as its argument, or as ``sys.argv`` if it takes none) and
    ``ArgumentParser.parse_args`` ends it at the parse — the parser's refusal exits as it
    would, its acceptance raises :class:`Parsed` before any of the tool's work."""

    def parse(argv: list[str]) -> None:
        main = load()
        accept = argparse.ArgumentParser.parse_args

        def parse_then_stop(self: argparse.ArgumentParser, *args: object) -> argparse.Namespace:
            raise Parsed(accept(self, *args))

        with (
            mock.patch.object(argparse.ArgumentParser, "parse_args", parse_then_stop),
            mock.patch.object(sys, "argv", [main.__module__, *argv]),
        ):
            try:
                main(argv) if main.__code__.co_argcount else main()
            except Parsed:
                return
        raise AssertionError(f"{main.__module__}.main returned without parsing its arguments")

    return parse


def script_main(path: str) -> Callable[[], Callable[..., object]]:
    """The ``main`` of the script ``path`` (imported from its file, its folder on ``sys.path``
    while it imports: the benchmarks import ``harness`` beside them)."""

    def load() -> Callable[..., object]:
        name = Path(path).stem
        if name not in sys.modules:
            spec = importlib.util.spec_from_file_location(name, ROOT / path)
            assert spec is not None and spec.loader is not None, f"{path} not found"
            module = importlib.util.module_from_spec(spec)
            with mock.patch.object(sys, "path", [str((ROOT / path).parent), *sys.path]):
                spec.loader.exec_module(module)
            sys.modules[name] = module
        return sys.modules[name].main

    return load


def module_main(name: str) -> Callable[[], Callable[..., object]]:
    return lambda: importlib.import_module(name).main


#: The tools a documented command may call, by the words that call them, and each one's parse
#: of a command line (an exit, or a ConfigError of the detector's range checks, if it refuses it).
TOOLS: dict[tuple[str, ...], Callable[[list[str]], object]] = {
    ("-m", "imm_gym.evaluate"): lambda argv: evaluate.build_parser().parse_args(argv),
    ("-m", "imm_gym.track"): lambda argv: track.build_parser().parse_args(argv),
    ("train.py",): lambda argv: train.build_parser().parse_args(argv),
    ("-m", "agents.detector"): detector.parse_args,
    ("-m", "agents.export"): parsed_by_main(module_main("agents.export")),
    ("-m", "agents.ensemble"): parsed_by_main(module_main("agents.ensemble")),
    ("examples/stay_selector.py",): parsed_by_main(script_main("examples/stay_selector.py")),
    ("benchmarks/tune_compare.py",): parsed_by_main(script_main("benchmarks/tune_compare.py")),
}
#: Where a documented path must exist (the rest are the user's: runs/, radar.csv, ...).
TRACKED = ("examples/", "agents/hyperparams/", "imm_gym/scenarios/", "benchmarks/")
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


def cases() -> list:
    """:data:`COMMANDS` as test cases, named by their document and first line."""
    return [pytest.param(*command, id=command[0][:80]) for command in COMMANDS]


def test_the_documents_give_commands_of_every_tool() -> None:
    """The extraction finds what the documents show (it cannot pass by finding nothing)."""
    assert len(COMMANDS) >= 20
    assert {tool for _, tool, _ in COMMANDS} == set(TOOLS)


@pytest.mark.parametrize(("where", "tool", "argv"), cases())
def test_a_documented_command_parses(where: str, tool: tuple[str, ...], argv: list[str]) -> None:
    """It runs as shown (no ``[optional]`` usage brackets) and the tool's parser accepts it."""
    assert not [a for a in argv if a.startswith("[")], f"{where}: usage syntax in a bash block"
    stderr = io.StringIO()
    try:
        with contextlib.redirect_stderr(stderr):
            TOOLS[tool](argv)
    except SystemExit:
        pytest.fail(f"{where}\n{stderr.getvalue().strip()}")
    except ConfigError as err:
        pytest.fail(f"{where}\n{err}")


@pytest.mark.parametrize("tool", list(TOOLS), ids=[" ".join(t) for t in TOOLS])
def test_an_unknown_flag_is_refused(tool: tuple[str, ...]) -> None:
    """A documented command of each tool with an unknown flag added fails the parse (the check
    cannot pass by running nothing)."""
    where, argv = next((w, a) for w, t, a in COMMANDS if t == tool)
    with contextlib.redirect_stderr(io.StringIO()) as stderr, pytest.raises(SystemExit) as stop:
        TOOLS[tool]([*argv, "--no-such-flag"])
    assert stop.value.code == 2, where
    assert re.search(r"unrecognized arguments: .*--no-such-flag", stderr.getvalue()), where


@pytest.mark.parametrize(("where", "tool", "argv"), COMMANDS, ids=[c[0][:80] for c in COMMANDS])
def test_a_documented_file_exists(where: str, tool: tuple[str, ...], argv: list[str]) -> None:
    named = [a for a in argv if a.startswith(TRACKED) and not set(a) & set("*{}$")]
    missing = [a for a in named if not (ROOT / a).exists()]
    assert not missing, f"{where}: {missing} not in the repository"

