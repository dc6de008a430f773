"""train.py's entry point without a long training: the summary a run writes back, the
durations its progress lines read, the versions it records and its stop requests."""

from __future__ import annotations

import json
from pathlib import Path

import train


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
