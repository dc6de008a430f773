"""train.py's entry point without a long training: the summary a run writes back, the
durations its progress lines read, the versions it records and its stop requests."""

from __future__ import annotations

import argparse
import json
import shutil
import signal
from pathlib import Path
from types import SimpleNamespace

import pytest
from helpers import train_small

import train
from agents import PRETRAINED


def _earlier_run(out: Path, seeds: dict[str, dict[str, int]], agents: tuple[str, ...]) -> None:
    """``out/summary.json`` naming ``seeds``; an agent directory for the seeds in ``agents``."""
    (out / "summary.json").write_text(json.dumps({"command": "c", "seeds": seeds}))
    for key in agents:
        (out / f"seed_{key}" / "agent").mkdir(parents=True)


def test_a_resumed_seed_keeps_the_earlier_seeds_whose_agents_remain(tmp_path: Path) -> None:
    """Seeds 2 and 10 resumed over a summary of 0, 1, 2, 10 and an entry of another kind: seed
    1, whose agent was removed, and the other key are dropped; the seeds read in numeric
    order (10 after 2); the resumed seeds' entries replace their earlier ones."""
    earlier = {"0": {"n": 0}, "1": {"n": 1}, "2": {"n": 2}, "10": {"n": 10}, "best": {"n": -1}}
    _earlier_run(tmp_path, earlier, ("0", "2", "10"))
    merged = train.with_earlier_seeds(tmp_path, {"10": {"n": 100}, "2": {"n": 20}})
    assert list(merged) == ["0", "2", "10"]
    assert merged == {"0": {"n": 0}, "2": {"n": 20}, "10": {"n": 100}}


def test_without_an_earlier_summary_the_resumed_seed_stands_alone(tmp_path: Path) -> None:
    assert train.with_earlier_seeds(tmp_path, {"3": {"n": 3}}) == {"3": {"n": 3}}
    (tmp_path / "summary.json").write_text("[1, 2]")  # not one of ours
    assert train.with_earlier_seeds(tmp_path, {"3": {"n": 3}}) == {"3": {"n": 3}}


def test_one_seed_makes_no_ensemble_and_unevaluated_seeds_no_report(tmp_path: Path) -> None:
    """One seed: ``summary.json`` alone (no ensemble of one agent). Two seeds of which one was
    not evaluated: their ensemble, no statistics across seeds, and an earlier ``report.md``
    (of seeds evaluated before) removed."""
    args = argparse.Namespace(out=tmp_path / "one")
    args.out.mkdir()
    train.write_summary(args, {"0": {"training": {}}}, "python train.py", {"v": "1"})
    summary = json.loads((args.out / "summary.json").read_text())
    assert summary == {"command": "python train.py", "versions": {"v": "1"},
                       "seeds": {"0": {"training": {}}}}
    assert sorted(p.name for p in args.out.iterdir()) == ["summary.json"]

    args = argparse.Namespace(out=tmp_path / "two")
    for seed in (0, 1):
        shutil.copytree(PRETRAINED / f"seed_{seed}", args.out / f"seed_{seed}" / "agent")
    (args.out / "report.md").write_text("the seeds evaluated before\n")
    seeds = {"0": {"paper": {"armse_pos": 17.0}}, "1": {"training": {}}}
    train.write_summary(args, seeds, "python train.py", {})
    summary = json.loads((args.out / "summary.json").read_text())
    assert summary["ensemble"] == str(args.out / "ensemble") and "across_seeds" not in summary
    assert not (args.out / "report.md").exists()


@pytest.mark.parametrize(
    ("seconds", "text"),
    [(59.4, "59 s"), (60, "1 min 00 s"), (3599, "59 min 59 s"), (3600, "1 h 00 min"),
     (-3.0, "0 s")],
)
def test_a_duration_changes_unit_at_the_minute_and_the_hour(seconds: float, text: str) -> None:
    assert train._duration(seconds) == text


def test_the_versions_recorded_name_the_training_libraries() -> None:
    """numba (the compiled environment step), SB3 and torch for every run; sb3-contrib only
    for recurrent-ppo."""
    from importlib.metadata import version

    record = train._versions()
    for name in ("stable-baselines3", "torch", "numba"):
        assert record[name] == version(name)
    assert "sb3-contrib" not in record
    assert train._versions("sb3", "recurrent-ppo")["sb3-contrib"] == version("sb3-contrib")


def test_a_second_signal_while_stopping_is_ignored() -> None:
    """Ctrl-C, then SIGTERM while stopping: the stop is Ctrl-C's, exit status 130."""
    with train.StopRequest() as stop:
        assert not stop.requested
        signal.raise_signal(signal.SIGINT)
        signal.raise_signal(signal.SIGTERM)
        assert stop.requested and stop.signum == signal.SIGINT
        with pytest.raises(SystemExit) as exit_info:
            stop.exit("stopped")
    assert exit_info.value.code == 130


@pytest.mark.parametrize(("received", "status"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_worker_stops_as_its_parent_was_asked_to(received: int, status: int) -> None:
    """A ``--jobs`` worker reads the signal its parent received (0 until then) as its own."""
    parent = SimpleNamespace(value=0)
    stop = train.StopRequest(parent=parent)
    assert not stop.requested and stop.signum is None
    parent.value = int(received)
    assert stop.requested and stop.signum == received
    with pytest.raises(SystemExit) as exit_info:
        stop.exit("stopped")
    assert exit_info.value.code == status


def test_a_resume_with_jobs_continues_its_checkpoint(tmp_path: Path) -> None:
    """``--resume`` of one seed with ``--jobs 2`` continues the checkpoint (there is one seed
    to train: no worker process), not a fresh run of the budget."""
    argv = ("--timesteps", "256", "--no-eval", "--validate-every", "0")
    assert train_small(tmp_path, *argv) == 0
    latest = tmp_path / "seed_0" / "checkpoints" / "latest"
    resumed = ["--timesteps", "512", "--no-eval", "--validate-every", "0", "--no-progress"]
    assert train.main(["--resume", str(latest), *resumed, "--jobs", "2"]) == 0
    stats = json.loads((tmp_path / "seed_0" / "training.json").read_text())
    assert stats["timesteps"] == 512 and stats["trained_this_call"] == 256


def test_the_best_checkpoint_becomes_the_agent_and_its_record_the_selection(tmp_path) -> None:
    """The validated best's files replace the agent's (nothing of the earlier agent stays);
    what was selected is its validation record without the history (``training.json`` holds
    that under ``validation``)."""
    best, agent = tmp_path / "best", tmp_path / "agent"
    best.mkdir()
    agent.mkdir()
    (best / "agent.json").write_text("the best\n")
    (agent / "agent.json").write_text("the last\n")
    (agent / "stale.json").write_text("an earlier file\n")
    record = {"armse_pos": 17.5, "timesteps": 512,
              "history": [{"timesteps": 256, "armse_pos": 18.0}]}
    assert train.adopt_best(best, agent, record) == {"armse_pos": 17.5, "timesteps": 512}
    assert sorted(p.name for p in agent.iterdir()) == ["agent.json"]
    assert (agent / "agent.json").read_text() == "the best\n"
    assert (best / "agent.json").is_file() and "history" in record
