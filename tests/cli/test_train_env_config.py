"""``python train.py --env-config FILE``: the agent trains on the file's configuration, records
it in ``env.json``, and the evaluation reports where it was trained and where it is evaluated."""

from __future__ import annotations

import json

import pytest

import train
from imm_gym.cli.comparison import evaluate
from imm_gym.sim.config_file import read_env_config

SMALL = "n_envs: 8\nn_steps: 32\nbatch_size: 128\nn_epochs: 1\n"
TRACKER = (
    "scenario: random\n"
    "family: {horizon: 60, min_duration: 5, T: 2.0}\n"
    "sensor: {sigma_r: 20.0}\n"
    "bank: cv-ct-continuous\n"
)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A 256-step agent trained with --env-config, and the file."""
    out = tmp_path_factory.mktemp("run")
    (out / "small.yml").write_text(SMALL)
    (out / "tracker.yaml").write_text(TRACKER)
    argv = ["--config", str(out / "small.yml"), "--env-config", str(out / "tracker.yaml")]
    argv += ["--out", str(out), "--timesteps", "256", "--no-eval", "--no-progress"]
    assert train.main([*argv, "--validate-every", "0"]) == 0
    return out / "seed_0" / "agent", out / "tracker.yaml"


def test_the_agent_records_the_configuration(trained) -> None:
    agent, file = trained
    recorded = json.loads((agent / "env.json").read_text())
    for key, value in read_env_config(file).items():
        assert recorded[key] == value, key
    # what the entry says the agent is stays, not its trackers (the default's vary)
    assert recorded["action_mode"] == "stay" and "vary" not in recorded


def test_trained_on_and_evaluated_on(trained) -> None:
    agent, file = trained
    same, _ = evaluate(
        [str(agent)], "random", 2, 0, clairvoyant=False, env_config=read_env_config(file)
    )
    row = same["policies"][str(agent)]
    assert row["tracker_differs"] == [] and row["trained_on"] == row["evaluated_on"]
    other, _ = evaluate([str(agent)], "paper", 2, 0, clairvoyant=False)
    row = other["policies"][str(agent)]
    assert row["tracker_differs"] == ["sensor", "bank"]
    assert row["trained_on"]["sensor"]["sigma_r"] == 20.0
    assert row["evaluated_on"]["sensor"]["sigma_r"] == 50.0


def test_a_bad_file_is_a_usage_error_before_training(tmp_path, capsys) -> None:
    file = tmp_path / "bad.yaml"
    file.write_text("sensor: {sigma_r: '20'}\n")
    with pytest.raises(SystemExit) as exc:
        train.main(["--env-config", str(file), "--out", str(tmp_path / "out"), "--no-eval"])
    assert exc.value.code == 2
    assert not (tmp_path / "out").exists()
    err = capsys.readouterr().err
    assert str(file) in err and "sensor.sigma_r" in err


def test_a_resumed_run_is_evaluated_on_the_file_it_was_started_with(trained, tmp_path) -> None:
    """The checkpoint records the file's configuration: ``--resume`` without ``--env-config``
    (as its own refusal says to do) evaluates the agent on that tracker, not the default one."""
    agent, file = trained
    checkpoint = agent.parent / "checkpoints" / "latest"
    recorded = json.loads((checkpoint / "resume.json").read_text())["evaluation_config"]
    assert recorded == json.loads(json.dumps(read_env_config(file)))
    parser = train.build_parser()
    args = parser.parse_args(["--resume", str(checkpoint)])
    train.check_args(parser, args)
    assert args.env_overrides == recorded
    out = tmp_path / "resumed"
    argv = ["--resume", str(checkpoint), "--timesteps", "512", "--out", str(out),
            "--paper-runs", "2", "--random-runs", "2", "--validate-every", "0", "--no-progress"]
    assert train.main(argv) == 0
    results = json.loads((out / "seed_0" / "results.json").read_text())
    row = results["random"]["policies"]["learned"]
    assert row["tracker_differs"] == [] and row["evaluated_on"]["sensor"]["sigma_r"] == 20.0
