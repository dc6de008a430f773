"""``python -m imm_gym.precompile``: each entry point compiles the kernels it names, the command
runs them in parallel processes, and a bad ``--jobs`` is refused naming it."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from imm_gym.cli.precompile import JOBS, main

#: The dispatchers (``module:name``) each entry point must leave compiled (or loaded from the
#: cache).
KERNELS = {
    "batch": ("imm_gym.sim.kernels:imm_step", "imm_gym.sim.kernels:env_step"),
    "single": (
        "imm_gym.tracking.kernels.imm:checked_step_one",
        "imm_gym.sim.kernels:env_step_one",
        "imm_gym.sim.solo:solo_step",
    ),
}

_PROBE = """
import importlib, json, sys
from imm_gym.cli.precompile import JOBS
kernels = [
    getattr(importlib.import_module(module), name)
    for module, name in (arg.split(":") for arg in sys.argv[2:])
]
before = [len(k.signatures) for k in kernels]
JOBS[sys.argv[1]]()
after = [len(k.signatures) for k in kernels]
print(json.dumps([before, after]))
"""


@pytest.mark.parametrize("job", list(JOBS))
def test_each_entry_point_compiles_the_kernels_it_names(job: str) -> None:
    # a fresh interpreter, so the dispatchers start with nothing compiled
    names = KERNELS[job]
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, job, *names],
        capture_output=True, text=True, check=True, timeout=900,
    ).stdout
    before, after = json.loads(out)
    assert before == [0] * len(names)
    assert all(k >= 1 for k in after), out


def test_the_command_runs_every_entry_point_in_parallel_processes(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["--jobs", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert sorted(line.split(":")[0] for line in lines[:-1]) == sorted(JOBS)
    assert lines[-1].startswith("compiled batch, single in ")


def test_only_runs_the_named_entry_point_here(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--jobs", "1", "--only", "single"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in lines[:-1]] == ["single"]


def test_jobs_below_one_is_refused_naming_the_flag(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--jobs", "0"])
    assert "--jobs must be at least 1, got 0" in capsys.readouterr().err


def test_a_repeated_only_runs_its_entry_point_once(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    calls: list[str] = []
    monkeypatch.setitem(JOBS, "single", lambda: calls.append("single"))
    monkeypatch.setitem(JOBS, "batch", lambda: calls.append("batch"))
    argv = ["--jobs", "1", "--only", "single", "--only", "batch", "--only", "single"]
    assert main(argv) == 0
    assert calls == ["single", "batch"]
    assert capsys.readouterr().out.splitlines()[-1].startswith("compiled single, batch in ")
