"""Ctrl-C never loses training: SIGINT (or SIGTERM) at any point of a run — an environment step
in the compiled kernel, a PPO update, a checkpoint being written, a validation — saves
``checkpoints/latest`` and exits 130 (143); ``--resume`` continues from its step count.

The runs are real ``python train.py`` processes signalled after the line that starts training,
several at once (each waits for its own delay)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from helpers import SMALL

import train

ROOT = Path(__file__).resolve().parents[2]
#: checkpoints every 512 steps and validations every 1024: every phase of a run is frequent
RUN = ["--no-eval", "--no-progress", "--checkpoint-every", "512", "--validate-every", "1024"]
RUN += ["--validation-runs", "3", "--timesteps", "10000000"]


def interrupted_runs(tmp_path: Path, signals: list[tuple[float, int]]) -> list[dict]:
    """Start one ``train.py`` per ``(delay, signal)``, send it the signal ``delay`` seconds after
    its ``training ... from step`` line; each run's exit status, output and directory."""
    config = tmp_path / "small.yml"
    config.write_text(SMALL)
    runs = []
    for i, (delay, signum) in enumerate(signals):
        out = tmp_path / f"run_{i}"
        argv = [sys.executable, "train.py", "--config", str(config), "--out", str(out), *RUN]
        proc = subprocess.Popen(
            argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        runs.append({"proc": proc, "delay": delay, "signal": signum, "out": out, "lines": []})

    def signal_after_start(run: dict) -> None:
        proc = run["proc"]
        for line in proc.stdout:
            run["lines"].append(line)
            if "training ppo" in line:
                time.sleep(run["delay"])
                proc.send_signal(run["signal"])
                break
        run["lines"] += proc.stdout.readlines()
        run["status"] = proc.wait(timeout=120)

    threads = [threading.Thread(target=signal_after_start, args=(run,)) for run in runs]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=300)
    for run in runs:
        if run["proc"].poll() is None:
            run["proc"].kill()
    return runs


def check_interrupted(run: dict, status: int) -> int:
    """The run exited with ``status``, said where its checkpoint is, and the checkpoint loads;
    returns the checkpoint's step count."""
    output = "".join(run["lines"])
    assert run["status"] == status, output
    latest = run["out"] / "seed_0" / "checkpoints" / "latest"
    assert f"checkpoint saved to {latest}" in output, output
    assert "Traceback" not in output and "SystemError" not in output, output
    steps = json.loads((latest / "resume.json").read_text())["num_timesteps"]
    assert steps == json.loads((latest / "agent.json").read_text())["num_timesteps"] > 0
    return steps


def resume(run: dict, steps: int) -> None:
    """``--resume`` the run's checkpoint (no --config, --env, --seed: all recorded) for 256 more
    steps: it starts at ``steps`` and ends past ``steps + 256``."""
    latest = run["out"] / "seed_0" / "checkpoints" / "latest"
    out = run["out"] / "resumed"
    argv = ["--resume", str(latest), "--out", str(out), "--timesteps", str(steps + 256)]
    assert train.main([*argv, "--no-eval", "--no-progress", "--validate-every", "0"]) == 0
    stats = json.loads((out / "seed_0" / "training.json").read_text())
    assert stats["timesteps"] >= steps + 256
    assert stats["trained_this_call"] == 256


def test_sigint_and_sigterm_save_a_checkpoint_that_resumes(tmp_path) -> None:
    """Fast variant: an early and a later Ctrl-C, and a SIGTERM."""
    signals = [(0.0, signal.SIGINT), (2.5, signal.SIGINT), (1.0, signal.SIGTERM)]
    early, late, term = interrupted_runs(tmp_path, signals)
    check_interrupted(early, 130)
    resume(late, check_interrupted(late, 130))
    check_interrupted(term, 143)


@pytest.mark.slow
def test_sigint_at_eight_points_always_leaves_a_checkpoint_that_resumes(tmp_path) -> None:
    delays = [0.0, 0.1, 0.3, 0.6, 1.0, 1.7, 2.6, 4.0]
    runs = interrupted_runs(tmp_path, [(delay, signal.SIGINT) for delay in delays])
    for run in runs:
        resume(run, check_interrupted(run, 130))


def test_a_signal_to_the_parent_of_jobs_stops_every_worker_at_a_checkpoint(tmp_path) -> None:
    """``--jobs 2 --seed 0 1 2``: SIGTERM to the parent process alone, once both workers train,
    reaches them (each saves its checkpoint), seed 2 never starts, and the job exits 143."""
    config = tmp_path / "small.yml"
    config.write_text(SMALL)
    out = tmp_path / "run"
    argv = [sys.executable, "train.py", "--config", str(config), "--out", str(out), *RUN]
    argv += ["--jobs", "2", "--seed", "0", "1", "2"]
    proc = subprocess.Popen(
        argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    assert proc.stdout is not None
    lines, started = [], 0
    for line in proc.stdout:
        lines.append(line)
        started += "training ppo" in line
        if started == 2:
            time.sleep(1.0)
            proc.send_signal(signal.SIGTERM)
            break
    lines += proc.stdout.readlines()
    output = "".join(lines)
    assert proc.wait(timeout=120) == 143, output
    for seed in (0, 1):
        latest = out / f"seed_{seed}" / "checkpoints" / "latest"
        assert f"checkpoint saved to {latest}" in output, output
        assert json.loads((latest / "resume.json").read_text())["num_timesteps"] > 0
    assert not (out / "seed_2").exists()
    assert "interrupted: seeds trained: none; not finished: [0, 1, 2]" in output, output
    assert "Traceback" not in output, output
