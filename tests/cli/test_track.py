"""python -m imm_gym.track: recorded measurements in (CSV, NPZ), per-step estimates, covariances,
mode probabilities and TPMs out, equal to the env's episode and to imm_gym.run_policy; --env-config
sets the tracker; bad inputs are usage errors naming the file and the column or key."""

from __future__ import annotations

import csv
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import imm_gym
from agents import PRETRAINED
from agents.ensemble import load_policy
from baselines import make_baseline
from imm_gym import EnvConfig, Sonar, TrackingCore
from imm_gym.cli.arguments import MAX_SEED
from imm_gym.cli.policies import agent_overrides
from imm_gym.cli.track import main

SEEDS = [5, 6]
ROOT = Path(__file__).resolve().parents[2]


def _episodes(config: EnvConfig, policy_name: str) -> tuple[TrackingCore, dict[str, np.ndarray]]:
    """Two episodes of the env's core run by a policy: the core and the per-step outputs."""
    policy = make_baseline(policy_name)
    core = TrackingCore(config.replace(**policy.env_overrides), n_envs=len(SEEDS))
    core.reset(np.arange(len(SEEDS)), SEEDS)
    obs, state, start = core.observe(), None, np.ones(len(SEEDS), dtype=bool)
    rows: dict[str, list[np.ndarray]] = {"estimate": [], "covariance": [], "mode_probs": [],
                                         "tpm": []}
    for _ in range(core.horizon):
        action, state = policy.predict(obs, state=state, episode_start=start, deterministic=True)
        start[:] = False
        result = core.step(action)
        obs = result.obs
        for key in rows:
            rows[key].append(result.info[key])
    return core, {key: np.stack(value, axis=1) for key, value in rows.items()}


def _write_csv(path: Path, core: TrackingCore) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["sequence", "z0", "z1", "detected", "vx", "vy"])
        for n, seed in enumerate(SEEDS):
            vx, vy = core.truth[n, 0, 2:4]
            for k in range(core.z.shape[1]):
                z0, z1 = (repr(float(v)) for v in core.z[n, k])
                if not core.detected[n, k]:
                    z0 = z1 = ""
                writer.writerow([f"run{seed}", z0, z1, int(core.detected[n, k]), vx, vy])


def _read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    with path.open(newline="") as handle:
        rows = list(csv.reader(handle))
    return rows[0], np.array([[float(v) for v in row[1:]] for row in rows[1:]])


def _write_sequences(path: Path, core: TrackingCore, lengths: tuple[int, ...]) -> None:
    """A CSV of sequence n: the first ``lengths[n] + 1`` measurements of the core's slot n."""
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["z0", "z1", "sequence"])
        for n, length in enumerate(lengths):
            for k in range(length + 1):
                writer.writerow([repr(float(core.z[n, k, 0])), repr(float(core.z[n, k, 1])), n])


def test_csv_in_csv_out_is_the_env_episode(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    config = EnvConfig(sensor=Sonar(detection_prob=0.9))
    core, env = _episodes(config, "tip-imm")
    _write_csv(tmp_path / "z.csv", core)
    assert main(["--measurements", str(tmp_path / "z.csv"), "--policy", "tip-imm",
                 "--out", str(tmp_path / "out.csv")]) == 0
    assert "2 sequence(s) tracked" in capsys.readouterr().out
    # a missed detection is an empty cell, a prediction step (the tracker does not use the
    # detection probability: the default configuration replays the episode)
    header, table = _read_csv(tmp_path / "out.csv")
    K, M = core.horizon, core.M
    assert header[:6] == ["sequence", "step", "x", "y", "vx", "vy"]
    assert header[-2:] == [f"tpm{M - 1}{M - 1}", "diverged"]
    assert len(header) == 2 + 4 + 16 + M + M * M + 1
    assert table.shape == (len(SEEDS) * K, len(header) - 1)
    assert not table[:, -1].any()
    steps = table.reshape(len(SEEDS), K, -1)
    np.testing.assert_array_equal(steps[..., 0], np.tile(np.arange(1, K + 1), (2, 1)))
    np.testing.assert_array_equal(steps[..., 1:5], env["estimate"])
    np.testing.assert_array_equal(steps[..., 5:21], env["covariance"].reshape(2, K, 16))
    np.testing.assert_array_equal(steps[..., 21:21 + M], env["mode_probs"])
    np.testing.assert_array_equal(steps[..., 21 + M:-1], env["tpm"].reshape(2, K, M * M))


def test_npz_through_python_m_with_the_agent_and_a_config_file(tmp_path: Path) -> None:
    """``python -m imm_gym.track`` (the shim) with the shipped agent on a tracker given by a
    YAML file: the NPZ holds what imm_gym.run_policy returns for that configuration."""
    config = EnvConfig(sensor=Sonar(sigma_r=20.0))
    core = TrackingCore(config, n_envs=2)
    core.reset(np.arange(2), SEEDS)
    np.savez(tmp_path / "z.npz", z=core.z, velocity=core.truth[:, 0, 2:4])
    (tmp_path / "tracker.yaml").write_text("sensor:\n  sigma_r: 20.0\n")
    done = subprocess.run(
        [sys.executable, "-m", "imm_gym.track", "--measurements", str(tmp_path / "z.npz"),
         "--policy", "pretrained", "--env-config", str(tmp_path / "tracker.yaml"),
         "--out", str(tmp_path / "out.npz")],
        cwd=ROOT, capture_output=True, text=True, check=False,
    )
    assert done.returncode == 0, done.stderr
    agent = load_policy(PRETRAINED)
    kept, _ = agent_overrides(agent, agent.env_overrides, config)  # the agent's own settings
    expected = imm_gym.run_policy(core.z, agent, config, velocity=core.truth[:, 0, 2:4],
                                  overrides=kept)
    default = imm_gym.run_policy(core.z, load_policy(PRETRAINED), velocity=core.truth[:, 0, 2:4])
    with np.load(tmp_path / "out.npz") as out:
        for key in ("estimate", "covariance", "mode_probs", "tpm", "x0", "P0", "diverged"):
            np.testing.assert_array_equal(out[key], getattr(expected, key), err_msg=key)
        assert not np.array_equal(out["covariance"], default.covariance)  # the file was read


def test_velocity_flag_and_sequences_of_different_lengths(tmp_path: Path) -> None:
    """``--velocity`` starts sequences that give none; a short and a long sequence both come
    back, each as imm_gym.run_policy gives it alone."""
    core = TrackingCore(EnvConfig(), n_envs=2)
    core.reset(np.arange(2), SEEDS)
    _write_sequences(tmp_path / "z.csv", core, (30, 50))
    assert main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
                 "--velocity", "3", "-4", "--out", str(tmp_path / "out.csv")]) == 0
    _, table = _read_csv(tmp_path / "out.csv")
    assert table.shape[0] == 30 + 50
    for n, (first, length) in enumerate(((0, 30), (30, 50))):
        alone = imm_gym.run_policy(core.z[n, : length + 1], make_baseline("fixed"),
                              velocity=[3.0, -4.0])
        np.testing.assert_array_equal(table[first:first + length, 1:5], alone.estimate[0])


def test_csv_sequences_come_back_in_the_input_order(tmp_path: Path) -> None:
    """Sequences run in batches of equal length and with or without a velocity, and are written
    in the order the input lists them; an empty vx, vy is no velocity; a repeated one is read."""
    core = TrackingCore(EnvConfig(), n_envs=3)
    core.reset(np.arange(3), [5, 6, 7])
    lengths, names = (40, 20, 40), ("c", "a", "b")
    velocities = (("", ""), ("3", "-4"), ("", ""))
    with (tmp_path / "z.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["sequence", "z0", "z1", "vx", "vy"])
        for n, length in enumerate(lengths):
            for k in range(length + 1):
                z0, z1 = (repr(float(v)) for v in core.z[n, k])
                writer.writerow([names[n], z0, z1, *velocities[n]])
    assert main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
                 "--out", str(tmp_path / "out.csv")]) == 0
    with (tmp_path / "out.csv").open(newline="") as handle:
        rows = list(csv.reader(handle))[1:]
    assert [row[0] for row in rows] == [
        name for name, length in zip(names, lengths, strict=True) for _ in range(length)
    ]
    first = 0
    for n, length in enumerate(lengths):
        velocity = None if velocities[n][0] == "" else [3.0, -4.0]
        alone = imm_gym.run_policy(core.z[n, : length + 1], make_baseline("fixed"),
                                   velocity=velocity)
        table = np.array([[float(v) for v in row[2:6]] for row in rows[first:first + length]])
        np.testing.assert_array_equal(table, alone.estimate[0])
        first += length


@pytest.mark.parametrize(
    ("content", "extra", "message"),
    [
        ("z0,z1,range\n1,2,3\n", [], "columns must be z0, z1"),
        # an empty file, an empty header line: said (it was "columns must be ...; got ")
        ("", [], r"z.csv: the file is empty: it starts with a header of columns z0, z1 \(and "),
        ("\nz0,z1\n1000,0.1\n1010,0.1\n", [], r"z.csv: line 1, the header, is empty: it starts"),
        ("z0,z1\n1000,0.1\n1000,abc\n", [],
         r"z.csv:3: sequence '0': column z1: 'abc' is not a number"),
        ("sequence,z0,z1,vx,vy\na,1000,0,1,2\nb,1000,0,,2\nb,1000,0,,\n", [],
         r"z.csv:3: sequence 'b' gives only one of vx and vy"),
        ("sequence,z0,z1,vx,vy\na,1000,0,1,2\na,1000,0,1,2\na,1000,0,1,3\n", [],
         r"z.csv:4: vx, vy are the initial velocity, read from sequence 'a'"),
        ("sequence,z0,z1\na,1000,0\nb,,0\nb,1000,0\n", [],
         r"z.csv:3: the first row of sequence 'b' initiates the track"),
        # numbers in the first row do not make it a detection: detected 0 cannot initiate
        ("z0,z1,detected\n1000,0.1,0\n1010,0.1,1\n", [],
         r"z.csv:2: the first row of sequence '0' initiates the track: .* and detected 1"),
        ("sequence,z0,z1,detected\na,1000,0,1\na,,0,1\n", [],
         r"z.csv:3: sequence 'a': a detection \(detected 1\) needs a number"),
        ("sequence,z0,z1\na,1000,0\nb,1000,0\na,1000,0\n", [], "sequence 'a' are not consecut"),
        # a row of too few or too many cells, a z cell not finite, some z cells empty without
        # detected, detected not 0/1, an empty sequence cell, a sequence of one row: refused
        # naming the file, line and sequence (they were missed detections, ignored or merged)
        ("z0,z1\n1000,0.1\n1010\n1020,0.1\n", [],
         r"z.csv:3: sequence '0': 1 cell\(s\) where the header has 2 \(z0, z1\)"),
        ("sequence,z0,z1\na,1000,0.1\na,1010,0.1,7\n", [],
         r"z.csv:3: sequence 'a': 4 cell\(s\) where the header has 3"),
        ("z0,z1\n1000,0.1\ninf,0.1\n", [], r"z.csv:3: sequence '0': column z0: 'inf' is not a fin"),
        ("z0,z1,detected\n1000,0.1,1\n1010,nan,0\n", [],
         r"z.csv:3: sequence '0': column z1: 'nan' is not a finite number"),
        ("z0,z1\n1000,0.1\n1010,\n1020,0.1\n", [],
         r"z.csv:3: sequence '0': some z cells are empty and some not"),
        ("z0,z1,detected\n1000,0.1,1\n1010,0.1,2\n", [],
         r"z.csv:3: sequence '0': column detected: '2' is not 0 or 1"),
        ("z0,z1,detected\n1000,0.1,1\n1010,0.1,0.5\n", [], r"detected: '0.5' is not 0 or 1"),
        ("z0,z1,detected\n1000,0.1,1\n1010,0.1,\n", [], r"z.csv:3: .*detected: '' is not 0 or 1"),
        ("sequence,z0,z1\n0,1000,0\n0,1010,0\n,1000,0\n,1010,0\n", [],
         r"z.csv:4: the sequence cell is empty"),
        ("sequence,z0,z1\na,1000,0\nb,1000,0\nb,1010,0\n", [],
         r"z.csv:2: sequence 'a' has one row, the track's start"),
        ("z0,z1,vx,vy\n1000,0.1,inf,0\n1010,0.1,,\n", [],
         r"z.csv:2: sequence '0': column vx: 'inf' is not a finite number"),
        ("z0,z1\n1000,0.1\n\n1010,abc\n", [], r"z.csv:4: sequence '0': column z1: 'abc'"),
        ("z0,z1,z1\n1000,0.1,0.2\n1010,0.1,0.2\n", [], r"z.csv: column\(s\) z1 given more than"),
        ("z0,z1,vx\n1000,0.1,99\n1010,0.1,\n", [], "needs both columns vx and vy; got only vx"),
        ("z0,z1\n1000,0.1\n1010,0.1\n", ["--env-config", "{cfg}"],
         r"tracker.yaml: .*sensor.*sigma_rr"),
        ("z0,z1\n1000,0.1\n1010,0.1\n", ["--policy", "no-such"], "unknown policy 'no-such'"),
    ],
)
def test_bad_inputs_are_usage_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture, content: str, extra: list[str], message: str
) -> None:
    (tmp_path / "z.csv").write_text(content)
    (tmp_path / "tracker.yaml").write_text("sensor:\n  sigma_rr: 20.0\n")
    args = ["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
            "--out", str(tmp_path / "out.csv")]
    args += [a.format(cfg=tmp_path / "tracker.yaml") for a in extra]
    with pytest.raises(SystemExit) as exit_info:
        main(args)
    assert exit_info.value.code == 2
    assert re.search(message, capsys.readouterr().err)
    assert not (tmp_path / "out.csv").exists()


def test_output_suffix_is_checked_first(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit):
        main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
              "--out", str(tmp_path / "out.txt")])
    assert "--out must end in .csv or .npz" in capsys.readouterr().err


def test_an_agent_tracks_with_the_configured_tracker(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A trained agent recorded with another sensor keeps its own settings and tracks with the
    configuration's sensor (said on stderr), and says so when the bank's models stand for others
    than its own; a bank whose size its network cannot take is refused before any work."""
    agent = load_policy(PRETRAINED)
    paper = agent.trained_across[0]  # the part of its training on the paper's tracker
    agent.trained_across = ()
    recorded = {**agent.env_overrides, **paper, "sensor": {"sigma_r": 20.0}}
    monkeypatch.setattr(
        "imm_gym.cli.track.make_policy", lambda name, base, seed: (agent, recorded, {})
    )
    core = TrackingCore(EnvConfig(), n_envs=1)
    core.reset(np.arange(1), SEEDS[:1])
    np.savez(tmp_path / "z.npz", z=core.z[0])
    out = ["--measurements", str(tmp_path / "z.npz"), "--policy", "pretrained",
           "--out", str(tmp_path / "out.npz")]
    assert main(out) == 0
    assert "trained on another tracker (its sensor differs)" in capsys.readouterr().err
    kept, _ = agent_overrides(agent, agent.env_overrides, EnvConfig())
    expected = imm_gym.run_policy(core.z[0], agent, overrides=kept)
    with np.load(tmp_path / "out.npz") as result:
        np.testing.assert_array_equal(result["estimate"], expected.estimate)
    (tmp_path / "ca.yaml").write_text(
        "bank: [{kind: cv}, {kind: ca, q: [0.1, 0.1, 0.1, 0.1, 0.1, 0.1]},\n"
        "       {kind: ct, turn_rate_deg: 3.0}]\n"
    )
    assert main([*out, "--env-config", str(tmp_path / "ca.yaml")]) == 0
    assert ("reads the evaluated bank's models (CV, CA, CT(+)) as those it was trained on "
            "(CV, CT(+), CT(−))") in capsys.readouterr().err
    (tmp_path / "two.yaml").write_text("bank: [{kind: cv}, {kind: ct, turn_rate_deg: 3.0}]\n")
    (tmp_path / "out.npz").unlink()
    with pytest.raises(SystemExit):
        main([*out, "--env-config", str(tmp_path / "two.yaml")])
    assert "cannot be evaluated on this configuration" in capsys.readouterr().err
    assert not (tmp_path / "out.npz").exists()


def test_a_files_agent_fields_are_each_policys_own(tmp_path: Path) -> None:
    """The configuration is built as the evaluation builds it: what the file says an agent is
    trained as (AGENT_FIELDS: action mode, stay base, detector share...) is dropped. A rule runs
    on a training file (it was refused: its action mode is not the file's) and the agent's
    estimates do not move with the file's detector_share."""
    core = TrackingCore(EnvConfig(), n_envs=1)
    core.reset(np.arange(1), SEEDS[:1])
    np.savez(tmp_path / "z.npz", z=core.z[0, :31])
    (tmp_path / "plain.yaml").write_text("scenario: paper\n")
    (tmp_path / "agent.yaml").write_text(
        "scenario: paper\naction_mode: stay\nstay_base: evidence\ndetector_share: 0.8\n"
        "detector: turn_rate\n"
    )
    for policy in ("fixed", "pretrained"):
        for name in ("plain", "agent"):
            assert main(["--measurements", str(tmp_path / "z.npz"), "--policy", policy,
                         "--env-config", str(tmp_path / f"{name}.yaml"),
                         "--out", str(tmp_path / f"{policy}_{name}.npz")]) == 0
        with np.load(tmp_path / f"{policy}_plain.npz") as plain, \
                np.load(tmp_path / f"{policy}_agent.npz") as agent:
            for key in ("estimate", "covariance", "mode_probs", "tpm"):
                np.testing.assert_array_equal(agent[key], plain[key], err_msg=f"{policy} {key}")


def test_a_missed_detection_is_empty_z_cells_or_detected_0(tmp_path: Path) -> None:
    """Every z cell of a row empty (no column detected) and detected 0 (its z cells, numbers or
    empty, unused) are the same missed detection."""
    core = TrackingCore(EnvConfig(), n_envs=1)
    core.reset(np.arange(1), SEEDS[:1])
    z = core.z[0, :21].tolist()
    missed = {4, 9, 10}
    files = {
        "empty": ["z0,z1"] + [
            "," if k in missed else f"{z[k][0]!r},{z[k][1]!r}" for k in range(len(z))
        ],
        "flag": ["z0,z1,detected"] + [
            f"{z[k][0]!r},{z[k][1]!r},{int(k not in missed)}" for k in range(len(z))
        ],
    }
    for name, lines in files.items():
        (tmp_path / f"{name}.csv").write_text("\n".join(lines) + "\n")
        assert main(["--measurements", str(tmp_path / f"{name}.csv"), "--policy", "fixed",
                     "--out", str(tmp_path / f"{name}_out.csv")]) == 0
    detected = np.array([k not in missed for k in range(len(z))])
    expected = imm_gym.run_policy(np.array(z), make_baseline("fixed"), detected=detected)
    for name in files:
        _, table = _read_csv(tmp_path / f"{name}_out.csv")
        np.testing.assert_array_equal(table[:, 1:5], expected.estimate[0], err_msg=name)


def test_unusable_outputs_and_unreadable_inputs_are_usage_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An --out that is a directory is refused before any work, one in a missing directory made;
    a CSV that is not UTF-8 and an .npz that is no NPZ archive (not unpickled) are refused
    naming the file (they were tracebacks, the output's after all the tracking)."""
    (tmp_path / "z.csv").write_text("z0,z1\n1000,0.1\n1010,0.1\n")
    (tmp_path / "dir.csv").mkdir()
    (tmp_path / "latin1.csv").write_bytes(b"sequence,z0,z1\ncaf\xe9,1000,0.1\ncaf\xe9,1010,0.1\n")
    (tmp_path / "bad.npz").write_text("not a zip\n")
    np.save(tmp_path / "array.npy", np.zeros((3, 2)))
    (tmp_path / "array.npy").rename(tmp_path / "array.npz")
    refused = {
        ("z.csv", "dir.csv"): r"--out '.*dir.csv': is a directory; give a file name",
        ("latin1.csv", "o.csv"): r"latin1.csv: not UTF-8 text",
        ("bad.npz", "o.csv"): r"bad.npz: not an NPZ archive of arrays",
        ("array.npz", "o.csv"): r"array.npz: one .npy array, not an NPZ archive",
    }
    real_make_policy = imm_gym.cli.track.make_policy

    def no_work(*args, **kwargs):
        raise AssertionError("a policy was made before the input and output were checked")

    monkeypatch.setattr("imm_gym.cli.track.make_policy", no_work)
    for (source, out), message in refused.items():
        with pytest.raises(SystemExit) as exit_info:
            main(["--measurements", str(tmp_path / source), "--policy", "fixed",
                  "--out", str(tmp_path / out)])
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert re.search(message, err) and "Traceback" not in err, err
    monkeypatch.setattr("imm_gym.cli.track.make_policy", real_make_policy)
    # a byte order mark (a spreadsheet's UTF-8) is no part of the first column's name
    (tmp_path / "bom.csv").write_bytes(b"\xef\xbb\xbf" + (tmp_path / "z.csv").read_bytes())
    for source in ("z.csv", "bom.csv"):
        out = tmp_path / "new" / "dirs" / f"{source}.out.csv"
        assert main(["--measurements", str(tmp_path / source), "--policy", "fixed",
                     "--out", str(out)]) == 0
    assert (tmp_path / "new/dirs/z.csv.out.csv").read_text() == (
        tmp_path / "new/dirs/bom.csv.out.csv").read_text()


def test_an_npz_output_merges_the_starts_in_the_input_order(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Sequences of one length, some with a velocity and some without, run in two batches and
    come back in one NPZ in the input's order (it was refused as 'of one length only' after the
    tracking); sequences of several lengths are refused before any work."""
    core = TrackingCore(EnvConfig(), n_envs=3)
    core.reset(np.arange(3), [5, 6, 7])
    velocities = (("", ""), ("3", "-4"), ("", ""))
    with (tmp_path / "z.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["sequence", "z0", "z1", "vx", "vy"])
        for n, name in enumerate("cab"):
            for k in range(21):
                z0, z1 = (repr(float(v)) for v in core.z[n, k])
                writer.writerow([name, z0, z1, *(velocities[n] if k == 0 else ("", ""))])
    assert main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
                 "--out", str(tmp_path / "out.npz")]) == 0
    with np.load(tmp_path / "out.npz") as out:
        assert out["estimate"].shape == (3, 20, 4)
        for n in range(3):
            velocity = None if velocities[n][0] == "" else [3.0, -4.0]
            alone = imm_gym.run_policy(core.z[n, :21], make_baseline("fixed"), velocity=velocity)
            for key in ("estimate", "covariance", "mode_probs", "tpm", "x0", "P0", "diverged"):
                np.testing.assert_array_equal(out[key][n], getattr(alone, key)[0], err_msg=key)

    def no_work(*args, **kwargs):
        raise AssertionError("a policy was made before the output was checked")

    monkeypatch.setattr("imm_gym.cli.track.make_policy", no_work)
    with (tmp_path / "z.csv").open("a", newline="") as handle:
        csv.writer(handle).writerow(["d", *(repr(float(v)) for v in core.z[0, 0]), "", ""])
        csv.writer(handle).writerow(["d", *(repr(float(v)) for v in core.z[0, 1]), "", ""])
    with pytest.raises(SystemExit) as exit_info:
        main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
              "--out", str(tmp_path / "two.npz")])
    assert exit_info.value.code == 2
    assert "holds sequences of one length (its arrays are (N, K, ...)); the input's have 1, 20 " \
        "steps: write a CSV" in " ".join(capsys.readouterr().err.split())


_Z = np.array([[1000.0, 0.1], [1010.0, 0.1], [1020.0, 0.1]])


@pytest.mark.parametrize(
    ("arrays", "message"),
    [
        ({"z": np.array([["a", "b"], ["c", "d"]])}, r"z must hold numbers, got dtype <U1"),
        ({"z": _Z[:, 0]}, r"z must be \(N, K\+1, 2\) or \(K\+1, 2\) with K >= 1.*got \(3,\)"),
        ({"z": _Z[:1]}, r"z must be .*got \(1, 2\)"),
        ({"z": np.stack([_Z, _Z]), "velocity": np.array([3.0, -4.0])},
         r"velocity must be \(2, 2\) for z of shape \(2, 3, 2\), got \(2,\)"),
        ({"z": _Z, "velocity": np.array([np.nan, 0.0])}, r"velocity must be finite"),
        ({"z": _Z, "detected": np.array([1, 2, 1])}, r"detected must be 0 or 1"),
        ({"z": _Z, "x0": np.zeros(4)}, r"a track starts from velocity, or .*, got x0"),
        ({"z": np.where([[False], [True], [False]], np.inf, _Z)}, r"z\[1, 0\] is infinite"),
        ({"z": np.stack([_Z, np.where([[True], [False], [False]], np.nan, _Z)])},
         r"sequence 1: z's first row initiates the track"),
        ({"z": np.where([[False], [True], [False]], np.nan, _Z), "detected": np.ones(3)},
         r"z's row 1 is a detection and not finite"),
        # without detected, a row partly NaN is refused as in a CSV (it was a missed detection)
        ({"z": np.where([[False, False], [False, True], [False, False]], np.nan, _Z)},
         r"z's row 1 has some cells NaN and some not; a missed detection is NaN in every cell"),
        ({"z": np.stack([_Z, np.where([[False, False], [False, False], [True, False]], np.nan,
                                      _Z)])},
         r"sequence 1: z's row 2 has some cells NaN and some not"),
    ],
)
def test_bad_npz_arrays_are_usage_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture, arrays: dict[str, np.ndarray], message: str
) -> None:
    """An NPZ's arrays are checked naming the file (strings were a traceback; a velocity (2,)
    for two sequences was read as one number each, detected 2 as 1, z inf as a missed
    detection)."""
    np.savez(tmp_path / "z.npz", **arrays)
    with pytest.raises(SystemExit) as exit_info:
        main(["--measurements", str(tmp_path / "z.npz"), "--policy", "fixed",
              "--out", str(tmp_path / "out.npz")])
    assert exit_info.value.code == 2
    err = " ".join(capsys.readouterr().err.split())
    assert re.search(f"z.npz: {message}", err), err


def test_a_diverged_track_is_flagged_in_the_csv_and_on_stderr(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A finite but absurd range sends the track to NaN: the rows say so from that step on
    (column diverged) and stderr names the sequence (it was written as NaN rows, silently)."""
    rows = ["sequence,z0,z1", "a,1000,0.1", "a,1010,0.1", "a,1e300,0.1", "a,1030,0.1",
            "b,1000,0.1", "b,1010,0.1", "b,1020,0.1", "b,1030,0.1"]
    (tmp_path / "z.csv").write_text("\n".join(rows) + "\n")
    assert main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
                 "--out", str(tmp_path / "out.csv")]) == 0
    err = capsys.readouterr().err
    assert "warning: 1 track(s) diverged" in err and "'a' at step 2" in err
    header, table = _read_csv(tmp_path / "out.csv")
    assert header[-1] == "diverged"
    np.testing.assert_array_equal(table[:, -1], [0, 1, 1, 0, 0, 0])


def test_shorter_sequences_are_padded_into_one_batch_and_cut_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Sequences of different lengths run as one batch (one run_policy call per kind of
    start: they ran one batch per length, 12x slower on real recordings); the padding's
    prediction-only steps do not count toward a short sequence's divergence."""
    core = TrackingCore(EnvConfig(), n_envs=2)
    core.reset(np.arange(2), SEEDS)
    _write_sequences(tmp_path / "z.csv", core, (5, 60))
    # a divergence cap that 55 steps of prediction alone exceed, and 5 filtered steps do not
    (tmp_path / "tracker.yaml").write_text("divergence_cov: 2.0e5\n")
    import imm_gym.cli.track as track

    calls: list[tuple[int, ...]] = []

    def counted(z, *args, **kwargs):
        calls.append(np.shape(z))
        return imm_gym.run_policy(z, *args, **kwargs)

    monkeypatch.setattr(track, "run_policy", counted)
    assert main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
                 "--env-config", str(tmp_path / "tracker.yaml"),
                 "--out", str(tmp_path / "out.csv")]) == 0
    assert calls == [(2, 61, 2)]
    _, table = _read_csv(tmp_path / "out.csv")
    config = EnvConfig(divergence_cov=2.0e5)
    padded = imm_gym.run_policy(np.concatenate([core.z[0, :6], np.full((55, 2), np.nan)]),
                                make_baseline("fixed"), config)
    assert padded.diverged[0]  # the padding alone would have flagged it
    for first, n, length in ((0, 0, 5), (5, 1, 60)):
        alone = imm_gym.run_policy(core.z[n, : length + 1], make_baseline("fixed"), config)
        rows = table[first:first + length]
        np.testing.assert_array_equal(rows[:, 1:5], alone.estimate[0])
        np.testing.assert_array_equal(rows[:, -1], np.arange(length) >= alone.diverged_at[0])
    assert not table[:5, -1].any()


def test_inputs_refused_before_the_policy_is_built(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """No measurements, a --velocity not finite, a P0 not positive definite, an output that is
    the input, family beside a named scenario, a --seed outside evaluate's range (a negative one
    was taken, a very negative one a traceback): refused before the policy (a tuned baseline's
    search took 16-18 s first) and before anything is written."""
    import imm_gym.cli.track as track

    def no_policy(*args, **kwargs):
        raise AssertionError("the policy was built")

    monkeypatch.setattr(track, "make_policy", no_policy)
    (tmp_path / "empty.csv").write_text("z0,z1\n")
    (tmp_path / "z.csv").write_text("z0,z1\n1000,0.1\n1010,0.1\n")
    np.savez(tmp_path / "z.npz", z=np.ones((1, 3, 2)) * [1000.0, 0.1], x0=np.zeros((1, 4)),
             P0=-np.eye(4)[None])
    (tmp_path / "t5.yaml").write_text("scenario: paper\nfamily:\n  T: 5.0\n")
    cases = [
        (["--measurements", str(tmp_path / "empty.csv")], r"empty.csv: no measurements"),
        (["--measurements", str(tmp_path / "z.csv"), "--velocity", "nan", "0"],
         r"--velocity must be two finite numbers"),
        (["--measurements", str(tmp_path / "z.npz")],
         r"z.npz: sequence 0: P0 must be positive definite"),
        (["--measurements", str(tmp_path / "z.csv"), "--env-config",
          str(tmp_path / "t5.yaml")],
         r"t5.yaml: family applies to scenario 'random' only, and the scenario \('paper'\)"),
        (["--measurements", str(tmp_path / "z.csv"), "--seed", "-5"],
         r"--seed must be >= 0, got -5"),
        (["--measurements", str(tmp_path / "z.csv"), "--seed", "-100000000000"],
         r"--seed must be >= 0, got -100000000000"),
        (["--measurements", str(tmp_path / "z.csv"), "--seed", str(MAX_SEED + 1)],
         rf"--seed must be in \[0, {MAX_SEED}\], got {MAX_SEED + 1}"),
    ]
    for argv, message in cases:
        with pytest.raises(SystemExit) as exit_info:
            main([*argv, "--policy", "bbsca", "--out", str(tmp_path / "out.csv")])
        assert exit_info.value.code == 2
        assert re.search(message, capsys.readouterr().err), message
        assert not (tmp_path / "out.csv").exists()
    before = (tmp_path / "z.csv").read_text()
    (tmp_path / "hard_link.csv").hardlink_to(tmp_path / "z.csv")  # it was overwritten
    for out in (tmp_path / ".." / tmp_path.name / "z.csv", tmp_path / "hard_link.csv"):
        with pytest.raises(SystemExit):
            main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
                  "--out", str(out)])
        assert "is the --measurements file" in capsys.readouterr().err
        assert (tmp_path / "z.csv").read_text() == before


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("z0,z1\n1000,0.1\n-5,0.1\n", r"warning: 1 detection\(s\) outside the sensor's units "
         r"\(it takes a range >= 0 m and a bearing in rad.*first at .*z.csv:3: sequence '0': "
         r"z \[-5.0, 0.1\]: tracked as given"),
        ("z0,z1\n1000,5.7\n1010,45\n1020,46\n", r"warning: 2 detection\(s\) .*z.csv:3: "),
    ],
    ids=["negative-range", "degrees"],
)
def test_measurements_outside_the_sensors_units_are_told_of(
    tmp_path: Path, capsys: pytest.CaptureFixture, content: str, message: str
) -> None:
    """A negative range or a bearing beyond 2 pi (degrees, likely) is named on stderr and
    tracked as given (the env itself draws negative ranges under heavy outliers)."""
    (tmp_path / "z.csv").write_text(content)
    assert main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
                 "--out", str(tmp_path / "out.csv")]) == 0
    assert re.search(message, capsys.readouterr().err)


def test_a_repeated_velocity_is_compared_as_a_number_and_the_period_is_said(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    (tmp_path / "z.csv").write_text("z0,z1,vx,vy\n1000,0.1,3,4\n1010,0.1,3.0,4.00\n")
    assert main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
                 "--out", str(tmp_path / "out.csv")]) == 0
    assert "tracking at T = 1 s, the sampling period of the scenario ('random')" in (
        capsys.readouterr().err
    )


def test_tpm_columns_of_a_bank_of_more_than_ten_models_are_distinct() -> None:
    from imm_gym.cli.track import tpm_columns

    assert tpm_columns(3) == [f"tpm{i}{j}" for i in range(3) for j in range(3)]
    many = tpm_columns(12)
    assert len(set(many)) == 144 and "tpm1_10" in many and "tpm11_0" in many


def test_velocity_flag_leaves_a_sequences_own_velocity(tmp_path: Path) -> None:
    """``--velocity`` starts only the sequences that give no velocity: one whose vx, vy are
    3, 4 starts at that velocity, not the flag's."""
    (tmp_path / "z.csv").write_text(
        "z0,z1,vx,vy\n1000,0.1,3,4\n1010,0.1,,\n1020,0.1,,\n"
    )
    assert main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
                 "--velocity", "10", "-10", "--out", str(tmp_path / "o.npz")]) == 0
    with np.load(tmp_path / "o.npz") as out:
        np.testing.assert_array_equal(out["x0"][0, 2:4], [3.0, 4.0])


def test_a_missed_rows_unused_cells_are_not_checked_for_units(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A bearing of 45 (degrees, likely) in a missed detection's row (detected 0) is never
    tracked: no warning of detections outside the sensor's units; the same row as a detection
    is told of."""
    for flag, warned in (("0", False), ("1", True)):
        (tmp_path / "z.csv").write_text(
            f"z0,z1,detected\n1000,0.1,1\n1010,45,{flag}\n1020,0.1,1\n"
        )
        assert main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
                     "--out", str(tmp_path / f"o{flag}.csv")]) == 0
        err = capsys.readouterr().err
        assert ("outside the sensor's units" in err) is warned, err
        assert ("z.csv:3" in err) is warned, err
