"""Runs at varied conditions (EnvConfig.vary) drawn at once hold the run-by-run reference bit
for bit.

``draw_batch`` with a :class:`~imm_gym.sim.conditions.Variation` draws the randomized family's
targets for all runs in one call (each run at its own ``T`` and speed). The reference below is
the former code: one family per run (``dataclasses.replace``), one ``draw_episodes`` per run.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from imm_gym import RandomFamily, paper_scenario
from imm_gym.seeding import streams
from imm_gym.sim.conditions import Variation, draw_conditions
from imm_gym.sim.episodes import draw_batch, draw_episodes
from imm_gym.tracking.sensors import PositionSensor, Sonar
from imm_gym.validation import ConfigError


def _reference(source, sensor, runs: int, seed: int, variation: Variation) -> dict:
    scen, noise = zip(*(streams(seed + r) for r in range(runs)), strict=True)
    conditions = draw_conditions(variation, source.T, sensor, scen)
    parts = []
    for r, (scen_rng, noise_rng) in enumerate(zip(scen, noise, strict=True)):
        changes: dict[str, object] = {}
        if conditions.T[r] != source.T:
            changes["T"] = float(conditions.T[r])
        if conditions.speed is not None and not np.isnan(conditions.speed[r]):
            changes["speed"] = (float(conditions.speed[r]),) * 2
        run_source = dataclasses.replace(source, **changes) if changes else source
        parts.append(
            draw_episodes(run_source, conditions.sensors[r], [scen_rng], [noise_rng], 5.0)
        )
    return {
        "states": np.concatenate([b.truth.states for b in parts]),
        "turn_rate": np.concatenate([b.truth.turn_rate for b in parts]),
        "accel": np.concatenate([b.truth.accel for b in parts]),
        "z": np.concatenate([b.measurements.z for b in parts]),
        "detected": np.concatenate([b.measurements.detected for b in parts]),
        "outlier": np.concatenate([b.measurements.outlier for b in parts]),
        "x0": np.concatenate([b.x0 for b in parts]),
        "P0": np.concatenate([b.P0 for b in parts]),
    }


CASES = {
    "broad": (
        RandomFamily(range_m=(2000.0, 20000.0), speed=(5.0, 60.0), turn_rate_deg=(0.5, 4.0)),
        Sonar(),
        Variation(T=(0.5, 5.0), sigma_r=(10.0, 100.0), sigma_theta_deg=(0.02, 0.2),
                  outlier_prob=(0.0, 0.05), detection_prob=(0.8, 1.0)),
    ),
    "speed, share": (
        RandomFamily(),
        Sonar(outlier_prob=0.1),
        Variation(T=(0.5, 5.0), speed=(5.0, 300.0), q_scale=(0.3, 30.0), share=0.5),
    ),
    "position sensor": (
        RandomFamily(n_segments=(1, 8), min_duration=5),
        PositionSensor(sigma_vel=1.0),
        Variation(speed=(1.0, 10.0), sigma_pos=(5.0, 50.0)),
    ),
    "truth noise": (
        RandomFamily(truth_q=(1.0, 1.0, 0.1, 0.1)),
        Sonar(),
        Variation(T=(0.5, 5.0), sigma_r=(10.0, 100.0), speed=(5.0, 300.0)),
    ),
    "scenario": (paper_scenario(), Sonar(), Variation(sigma_r=(10.0, 100.0), share=0.7)),
}


@pytest.mark.parametrize("case", list(CASES))
def test_varied_batch_equals_run_by_run(case: str) -> None:
    source, sensor, variation = CASES[case]
    batch = draw_batch(source, sensor, 40, 123, variation=variation)
    expected = _reference(source, sensor, 40, 123, variation)
    got = {
        "states": batch.truth.states,
        "turn_rate": batch.truth.turn_rate,
        "accel": batch.truth.accel,
        "z": batch.measurements.z,
        "detected": batch.measurements.detected,
        "outlier": batch.measurements.outlier,
        "x0": batch.x0,
        "P0": batch.P0,
    }
    for name, value in expected.items():
        assert got[name].dtype == value.dtype and got[name].shape == value.shape, name
        assert got[name].tobytes() == value.tobytes(), name
    np.testing.assert_array_equal(batch.truth.T, batch.conditions.T)


@pytest.mark.parametrize(
    ("variation", "field"),
    [(Variation(T=(0.5, 2.0)), "vary.T"), (Variation(speed=(5.0, 10.0)), "vary.speed")],
)
def test_varied_period_or_speed_of_a_fixed_scenario_is_refused(
    variation: Variation, field: str
) -> None:
    """A fixed scenario's segments are counted in steps (timed for its own T) and its speed is its
    initial velocity: draw_batch refuses a varied T or speed for it, as EnvConfig.vary does,
    rather than moving every turn in time (T) or failing inside dataclasses.replace (speed)."""
    with pytest.raises(ConfigError, match=f"{field} needs scenario 'random'"):
        draw_batch(paper_scenario(), Sonar(), 3, 0, variation=variation)
    scen, noise = streams(0)
    with pytest.raises(ConfigError, match=f"{field} needs scenario 'random'"):
        draw_episodes(paper_scenario(), Sonar(), [scen], [noise], variation=variation)


@pytest.mark.parametrize("variation", [None, Variation(sigma_r=(10.0, 100.0))])
def test_generator_lists_of_different_lengths_are_refused(variation: Variation | None) -> None:
    """Three scenario generators and two noise generators: refused up front, both counts named
    (the varied path returned three truths and two measurement runs)."""
    scenario = [streams(s)[0] for s in range(3)]
    noise = [streams(s)[1] for s in range(2)]
    with pytest.raises(ConfigError, match="3 scenario_rngs and 2 noise_rngs"):
        draw_episodes(RandomFamily(), Sonar(), scenario, noise, variation=variation)


@pytest.mark.parametrize(
    ("runs", "seed", "message"),
    [
        (0, 0, "runs must be an integer in \\[1, inf\\), got 0"),
        (2, -1, "seed must be an integer in \\[0, inf\\), got -1"),
        (2, 2.5, "seed must be an integer in \\[0, inf\\), got 2.5"),
    ],
)
def test_no_runs_or_a_seed_that_is_not_a_count_is_refused_by_name(runs, seed, message) -> None:
    """draw_batch refuses an empty batch and a seed that is not a non-negative integer, naming
    it (a seed of 2.5 silently drew the runs of seed 2); an integral float seed is that seed:
    run r the streams of seed 3 + r."""
    with pytest.raises(ConfigError, match=message):
        draw_batch(RandomFamily(horizon=20, n_segments=(1, 2)), Sonar(), runs, seed)
    batch = draw_batch(RandomFamily(horizon=20, n_segments=(1, 2)), Sonar(), 2, 3.0)
    scen, noise = zip(streams(3), streams(4), strict=True)
    alone = draw_episodes(RandomFamily(horizon=20, n_segments=(1, 2)), Sonar(), scen, noise)
    np.testing.assert_array_equal(batch.measurements.z, alone.measurements.z)


def test_a_source_without_truth_is_refused_by_name() -> None:
    """A scenario's name or None in place of a truth source is refused naming its type (it
    failed with an AttributeError deep inside the draw)."""
    for source, name in (("paper", "str"), (None, "NoneType")):
        with pytest.raises(ConfigError, match=f"truth source, got {name}"):
            draw_batch(source, Sonar(), 2, 0)


@pytest.mark.parametrize("variation", [None, Variation(sigma_r=(10.0, 100.0))])
def test_a_designed_family_without_the_bank_is_refused_asking_for_it(variation) -> None:
    """A family that draws its turns for the tracker (designed_share > 0) needs the tracker's
    bank: without it the draw asks for ``bank=...`` (not a complaint about a bank of no CT
    model), on the fixed and the varied path."""
    family = RandomFamily(horizon=20, n_segments=(1, 2), designed_share=0.5)
    with pytest.raises(ConfigError, match=r"designed_share .*pass its bank \(bank=\.\.\.\)"):
        draw_batch(family, Sonar(), 2, 0, variation=variation)
