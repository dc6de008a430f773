"""The batches of ``python -m imm_gym.track`` at their bounds, worked by hand: a sequence joins
a batch while the batch's padded steps stay within (at most, equal included) twice its own or
the floor, and the floor :func:`~imm_gym.cli.track.run` uses is 100 000 padded steps."""

from __future__ import annotations

import numpy as np
import pytest

import imm_gym.cli.track as track
from baselines import make_baseline
from imm_gym import EnvConfig
from imm_gym.cli.track import batches, run


def _lengths(*rows: int) -> list[tuple[int, dict[str, np.ndarray]]]:
    return [(i, {"name": str(i), "z": np.zeros((n, 2))}) for i, n in enumerate(rows)]


def test_a_batch_padded_to_exactly_twice_its_steps_or_the_floor_is_kept_whole() -> None:
    """10, 3, 2 (floor 1): the 3 makes 2 x 10 = 20 padded steps against twice 13 = 26; the 2
    makes 3 x 10 = 30 against twice 15 = 30, equal: it joins. 40, 2, 2 with floor 120: the
    third makes 3 x 40 = 120 padded steps against twice 44 = 88 and the floor 120, equal: it
    joins; with floor 119 it starts a batch of its own."""
    assert [[i for i, _ in b] for b in batches(_lengths(10, 3, 2), 1)] == [[0, 1, 2]]
    assert [[i for i, _ in b] for b in batches(_lengths(40, 2, 2), 120)] == [[0, 1, 2]]
    assert [[i for i, _ in b] for b in batches(_lengths(40, 2, 2), 119)] == [[0, 1], [2]]


class _Stop(Exception):
    pass


def test_run_pads_a_batch_to_at_most_100_000_steps(monkeypatch: pytest.MonkeyPatch) -> None:
    """A 1000-row recording beside 100 of 2 rows: twice their steps is 2 x 1200 = 2400, so the
    floor decides: 100 sequences padded to 1000 rows are 100 000 steps, the floor exactly; a
    101st would make 101 000. The first batch tracked is (100, 1000, 2)."""
    shapes = []

    def first(z, *args, **kwargs):
        shapes.append(np.shape(z))
        raise _Stop

    monkeypatch.setattr(track, "run_policy", first)
    sequences = [seq for _, seq in _lengths(1000, *[2] * 100)]
    with pytest.raises(_Stop):
        run(sequences, make_baseline("fixed"), EnvConfig(), None, {})
    assert shapes == [(100, 1000, 2)]
