"""Training the learned detector (agents.detector): what it collects is what the env's detector
reads, its targets are the true turn rates' beliefs, the fit is repeatable and beats a constant
belief on held-out episodes, and the command writes a file the env loads."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from safetensors import safe_open

from agents.detector import Samples, collect, collect_runs, cross_entropy, fit, main
from imm_gym import EnvConfig, TrackingCore
from imm_gym.seeding import DETECTOR_SEED_BASE
from imm_gym.sim.detectors import TurnRateBelief
from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS, WINDOW, DetectorNetwork
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.validation import ConfigError

M = 3
PAPER_RATES = np.radians([0.0, 4.0, -4.0])
ORDER = np.argsort(PAPER_RATES)


def test_it_collects_what_the_env_s_detector_reads_and_the_true_turn_rates(tmp_path) -> None:
    seeds = [5, 6]
    family = {"horizon": 40, "min_duration": 5}
    samples = collect({"scenario": "random", "family": family}, seeds, window=6)
    assert samples.inputs.shape == (80, 6 * 8) and samples.targets.shape == (80, M)
    # the env's own detector, stepped by the core on the same episodes: the same windows
    net = DetectorNetwork((np.zeros((M, 6 * 8)),), (np.zeros(M),), 6)
    net.save(tmp_path / "d.safetensors")
    core = TrackingCore(EnvConfig(
        scenario="random", family=family, action_mode="stay", detector="learned",
        detector_share=0.5, detector_weights=str(tmp_path / "d.safetensors"),
    ), 2)
    core.reset(np.arange(2), seeds)
    windows = []
    for _ in range(40):
        windows.append(core.learned_detector.inputs().copy())
        core.step(np.zeros((2, M)))
    # step-major: every episode's window before step k, then before step k + 1
    np.testing.assert_allclose(samples.inputs.reshape(40, 2, -1), np.stack(windows), rtol=1e-5,
                               atol=1e-6)
    assert np.all(samples.inputs.reshape(40, 2, -1)[0] == 0.0)  # before the first measurement
    # the targets: the heading change from state k to k + 1, interpolated between the models
    truth = core.truth
    heading = np.arctan2(truth[..., 3], truth[..., 2])
    step = (heading[:, 1:] - heading[:, :-1] + np.pi) % (2 * np.pi) - np.pi
    belief = TurnRateBelief(PAPER_RATES)(step.T.ravel())[:, ORDER]
    np.testing.assert_allclose(samples.targets, belief, rtol=1e-6, atol=1e-7)
    assert np.ptp(step) > np.radians(1.0)  # turns among them


def test_the_fit_is_repeatable_and_beats_a_constant_belief_on_held_out_episodes() -> None:
    family = {"scenario": "random", "family": {"horizon": 100}}
    train = collect(family, range(1000, 1080))
    held_out = collect(family, range(2000, 2030))
    nets = [fit(train, (32,), 5, seed=0, batch=128) for _ in range(2)]
    for a, b in zip(nets[0].weights, nets[1].weights, strict=True):
        np.testing.assert_array_equal(a, b)
    score = cross_entropy(nets[0](held_out.inputs.astype(np.float64)), held_out.targets)
    constant = cross_entropy(np.broadcast_to(train.targets.mean(axis=0), held_out.targets.shape),
                             held_out.targets)
    assert score < 0.9 * constant


def test_cross_entropy_by_hand() -> None:
    belief = np.array([[0.5, 0.25, 0.25], [0.1, 0.1, 0.8]])
    targets = np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 0.5]])
    expected = -(np.log(0.5) + 0.5 * np.log(0.1) + 0.5 * np.log(0.8)) / 2
    assert cross_entropy(belief, targets) == pytest.approx(expected, rel=1e-12)
    assert isinstance(Samples(np.zeros((1, 2), np.float32), np.zeros((1, 3), np.float32)), Samples)


def test_the_command_writes_a_file_the_env_loads(tmp_path, capsys) -> None:
    config = tmp_path / "family.yaml"
    config.write_text("scenario: random\nfamily: {horizon: 30, min_duration: 5}\n")
    out = tmp_path / "det" / "d.safetensors"
    main(["--env-config", str(config), "--runs", "12", "--held-out-runs", "4", "--epochs", "1",
          "--hidden", "8", "--out", str(out)])
    assert "wrote" in capsys.readouterr().out
    with safe_open(str(out), framework="np") as f:
        notes = json.loads(f.metadata()["notes"])
    assert notes["runs"] == 12 and notes["samples"] == 12 * 30 and notes["hidden"] == [8]
    # the held-out episodes are a block of their own, no seed's training episodes
    assert notes["held_out_seeds"][0] == notes["seeds"][0] + 2**60
    assert notes["held_out_seeds"][1] - notes["held_out_seeds"][0] == 3
    core = TrackingCore(EnvConfig(action_mode="stay", detector="learned", detector_share=0.5,
                                  detector_weights=str(out)), 1)
    core.reset(np.array([0]), [0])
    assert np.isfinite(core.step(np.zeros((1, M))).info["tpm"]).all()


def test_the_shipped_detector_says_how_it_was_trained() -> None:
    network = DetectorNetwork.load(DEFAULT_WEIGHTS)
    assert network.n_models == M and network.window == WINDOW
    with safe_open(str(DEFAULT_WEIGHTS), framework="np") as f:
        notes = json.loads(f.metadata()["notes"])
    assert notes["command"].startswith("python -m agents.detector --env-config")
    assert notes["held_out_cross_entropy"] < 0.8 * notes["constant_cross_entropy"]


def test_bad_arguments_fail_before_any_work(tmp_path) -> None:
    config = tmp_path / "hetero.yaml"
    config.write_text(json.dumps({"scenario": "random", **BANK_PRESETS["hetero"]}))
    out = str(tmp_path / "d.safetensors")
    with pytest.raises(ConfigError, match="runs must be"):
        main(["--env-config", str(config), "--runs", "0", "--out", out])
    with pytest.raises(ConfigError, match=r"hidden: 8 hidden layers and the output are 9 layers"):
        main(["--env-config", str(config), "--hidden", *["8"] * 8, "--out", out])
    with pytest.raises(ConfigError, match="needs a linear bank"):
        main(["--env-config", str(config), "--runs", "5", "--out", out])
    linear = tmp_path / "paper.yaml"
    linear.write_text("scenario: random\n")
    with pytest.raises(ConfigError, match=r"hidden: a network of 34234371 numbers for 3 models, "
                                          r"above the 16777216 a detector file may hold"):
        main(["--env-config", str(linear), "--hidden", "4096", "4096", "4096", "--out", out])


def test_the_command_line_says_a_refused_argument_in_one_line(tmp_path) -> None:
    """python -m agents.detector: a ConfigError before any work is a usage error (exit 2, one
    line naming the option), not a traceback."""
    done = subprocess.run(
        [sys.executable, "-m", "agents.detector", "--env-config", "none.yaml", "--hidden", "0",
         "--out", str(tmp_path / "d.safetensors")],
        cwd=Path(__file__).resolve().parents[2], capture_output=True, text=True, check=False,
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.startswith("python -m agents.detector: error: hidden")


def _bank_file(path: Path, rates: list[float]) -> str:
    """A configuration file of a CV model and CT models of ``rates`` (°/s)."""
    bank = [{"kind": "cv", "noise": "continuous", "intensity": 0.1}] + [
        {"kind": "ct", "turn_rate_deg": r, "noise": "continuous", "intensity": 0.05}
        for r in rates
    ]
    path.write_text(json.dumps({"scenario": "random", "bank": bank}))
    return str(path)


def test_what_every_file_and_the_output_need_is_refused_before_any_episode(
    tmp_path, monkeypatch
) -> None:
    # a later file's bank, the runs each file gets and the output were found out after the
    # first file's episodes (or after the training): now before any
    def no_work(*args, **kwargs):
        raise AssertionError("an episode was run before the refusal")

    monkeypatch.setattr("agents.detector.collect", no_work)
    paper = _bank_file(tmp_path / "paper.yaml", [4.0, -4.0])
    out = str(tmp_path / "d.safetensors")
    hetero = tmp_path / "hetero.yaml"
    hetero.write_text(json.dumps({"scenario": "random", "bank": "hetero"}))
    for files, extra, message in [
        ([paper, _bank_file(tmp_path / "two.yaml", [4.0])], [],
         r"env_config: the files' banks have \[3, 2\] models"),
        ([paper, _bank_file(tmp_path / "twice.yaml", [4.0, 4.0])], [],
         r"env_config '.*twice.yaml': detector 'learned' needs models of distinct turn rates"),
        ([paper, str(hetero)], [],  # the file was not named
         r"env_config '.*hetero.yaml': the learned detector needs a linear bank"),
        ([paper, paper, paper], ["--runs", "2"], r"runs must be at least the 3 --env-config"),
        ([paper, paper], ["--held-out-runs", "1"], r"held_out_runs must be at least the 2"),
    ]:
        with pytest.raises(ConfigError, match=message):
            main(["--env-config", *files, *extra, "--out", out])
    with pytest.raises(ConfigError, match=r"out: '.*' is a directory"):
        main(["--env-config", paper, "--out", str(tmp_path)])
    blocked = tmp_path / "file"
    blocked.write_text("")
    with pytest.raises(ConfigError, match=r"out: cannot write .* is not a writable directory"):
        main(["--env-config", paper, "--out", str(blocked / "d.safetensors")])


def test_fewer_runs_than_configurations_are_refused() -> None:
    # the later configurations got no episode, silently
    family = {"scenario": "random", "family": {"horizon": 30, "min_duration": 5}}
    with pytest.raises(ValueError, match="1 runs for 2 configurations"):
        collect_runs([family, family], 1, 2**61)


def test_the_same_arguments_give_the_same_file(tmp_path, capsys) -> None:
    # the writer's metadata came out in another key order each run: now sorted, byte-identical
    config = tmp_path / "family.yaml"
    config.write_text("scenario: random\nfamily: {horizon: 30, min_duration: 5}\n")
    out = tmp_path / "d.safetensors"
    files = []
    for _ in range(3):
        main(["--env-config", str(config), "--runs", "4", "--held-out-runs", "2", "--epochs", "1",
              "--hidden", "4", "--seed", "3", "--out", str(out)])
        files.append(out.read_bytes())
    assert files[0] == files[1] == files[2]
    size = int.from_bytes(files[0][:8], "little")
    assert size % 8 == 0
    metadata = json.loads(files[0][8 : 8 + size])["__metadata__"]
    assert list(metadata) == sorted(metadata) == ["format", "notes", "window"]
    network = DetectorNetwork.load(out)  # still a detector file the env reads
    assert network.window == WINDOW and network.n_models == M


def test_the_episodes_seeds_are_the_detector_s_block(tmp_path, monkeypatch, capsys) -> None:
    # training episodes DETECTOR_SEED_BASE + 10**6 seed .., held-out ones 2**60 above: no
    # evaluation, validation or training seed
    import agents.detector

    seen = []

    def spy(overrides, seeds, window=WINDOW):
        seen.append(list(seeds))
        return collect(overrides, seeds, window)

    monkeypatch.setattr(agents.detector, "collect", spy)
    config = tmp_path / "family.yaml"
    config.write_text("scenario: random\nfamily: {horizon: 30, min_duration: 5}\n")
    out = tmp_path / "d.safetensors"
    main(["--env-config", str(config), str(config), "--runs", "5", "--held-out-runs", "2",
          "--epochs", "1", "--hidden", "4", "--seed", "7", "--out", str(out)])
    first = DETECTOR_SEED_BASE + 10**6 * 7
    assert seen == [[first, first + 1, first + 2], [first + 3, first + 4],
                    [first + 2**60], [first + 2**60 + 1]]
    with safe_open(str(out), framework="np") as f:
        notes = json.loads(f.metadata()["notes"])
    assert notes["seeds"] == [first, first + 4]
    assert notes["held_out_seeds"] == [first + 2**60, first + 2**60 + 1]


def test_the_episodes_are_collected_in_batches_of_batch_runs(monkeypatch) -> None:
    # each file's share of the episodes in batches of BATCH_RUNS, the last batch the rest: as
    # many episodes as asked, each seed once
    import agents.detector

    seen = []

    def spy(overrides, seeds, window=WINDOW):
        seen.append(list(seeds))
        return collect(overrides, seeds, window)

    monkeypatch.setattr(agents.detector, "collect", spy)
    monkeypatch.setattr(agents.detector, "BATCH_RUNS", 2)
    family = {"scenario": "random", "family": {"horizon": 30, "min_duration": 5}}
    samples = collect_runs([family, family], 5, 100)
    assert seen == [[100, 101], [102], [103, 104]]
    assert len(samples.inputs) == len(samples.targets) == 5 * 30


def test_a_network_just_above_the_file_s_bound_and_a_negative_seed_are_refused(
    tmp_path, monkeypatch
) -> None:
    # 34 M numbers were refused, 17 M were not checked against the 16 777 216 bound; a negative
    # seed's episodes would be below the detector's block
    monkeypatch.setattr("agents.detector.collect", None)  # no episode may run
    config = tmp_path / "paper.yaml"
    config.write_text("scenario: random\n")
    out = str(tmp_path / "d.safetensors")
    # window 10 of 2 M + 2 = 8 entries, two layers of 4096, 3 models: weights and biases
    count = (160 + 1) * 4096 + (4096 + 1) * 4096 + (4096 + 1) * 3
    assert count == 17453059
    with pytest.raises(ConfigError, match=rf"hidden: a network of {count} numbers for 3 models"):
        main(["--env-config", str(config), "--hidden", "4096", "4096", "--out", out])
    # 16 660 003 numbers are within the bound: refused only for the output that is a directory
    with pytest.raises(ConfigError, match=r"out: '.*' is a directory"):
        main(["--env-config", str(config), "--hidden", "4000", "4000", "--out", str(tmp_path)])
    with pytest.raises(ConfigError, match=r"seed must be an integer in \[0, "):
        main(["--env-config", str(config), "--seed", "-1", "--out", out])


def test_an_output_directory_it_may_not_write_is_refused_before_any_episode(
    tmp_path, monkeypatch
) -> None:
    # the permission bits, as a user other than root sees a read-only directory
    import agents.detector

    monkeypatch.setattr("agents.detector.collect", None)  # no episode may run
    monkeypatch.setattr(agents.detector.os, "access", lambda path, mode: False)
    config = tmp_path / "paper.yaml"
    config.write_text("scenario: random\n")
    with pytest.raises(ConfigError, match=r"out: cannot write .* is not a writable directory"):
        main(["--env-config", str(config), "--out", str(tmp_path / "d.safetensors")])


def test_a_diverged_episode_s_steps_after_it_ended_are_left_out() -> None:
    # a cap of 5 m ends every episode within a few steps; the steps after were recorded
    from agents.detector import collection_config

    family = {"horizon": 30, "min_duration": 5}
    over = {"scenario": "random", "divergence_error": 5.0, "family": family}
    samples = collect(over, [5, 6, 7])
    core = TrackingCore(collection_config(over), 3)  # the tracker the collection runs
    core.reset(np.arange(3), [5, 6, 7])
    steps = 0
    for _ in range(30):
        live = ~core.done
        steps += int(live.sum())
        if live.any():
            core.step(np.zeros((3, core.action_dim)), active=live)
    assert core.done.all() and steps < 3 * 30
    assert len(samples.inputs) == len(samples.targets) == steps


def test_the_constant_belief_is_the_training_episodes_mean(tmp_path, capsys) -> None:
    # the score's baseline: the training targets' mean belief, scored on the held-out targets
    config = tmp_path / "family.yaml"
    config.write_text("scenario: random\nfamily: {horizon: 30, min_duration: 5}\n")
    out = tmp_path / "d.safetensors"
    main(["--env-config", str(config), "--runs", "4", "--held-out-runs", "2", "--epochs", "1",
          "--hidden", "4", "--seed", "3", "--out", str(out)])
    with safe_open(str(out), framework="np") as f:
        notes = json.loads(f.metadata()["notes"])
    family = {"scenario": "random", "family": {"horizon": 30, "min_duration": 5}}
    first, held = notes["seeds"][0], notes["held_out_seeds"][0]
    train = collect(family, range(first, first + 4)).targets.astype(np.float64)
    held_out = collect(family, range(held, held + 2)).targets.astype(np.float64)
    mean = train.mean(axis=0)
    expected = -np.mean(held_out @ np.log(mean))
    assert notes["constant_cross_entropy"] == pytest.approx(expected, rel=1e-5)
    assert not np.allclose(held_out.mean(axis=0), mean, rtol=1e-2)  # the two means differ
