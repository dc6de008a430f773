"""train.py: a short training run gives a loadable agent that the evaluation scores; resume
continues the step count; bad arguments are rejected with a clear message."""

from __future__ import annotations

import json
import re
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import SMALL, train_small

import train
from agents.policy import load_agent
from imm_gym import EnvConfig, TrackingCore
from imm_gym.cli.evaluate import main as evaluate_main


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    argv = ["--timesteps", "512", "--no-eval", "--checkpoint-every", "256", "--keep-checkpoints"]
    assert train_small(out, *argv) == 0
    return out, out / "small.yml"


def test_short_run_gives_an_agent_the_evaluation_scores(trained, tmp_path) -> None:
    out, _ = trained
    agent_dir = out / "seed_0" / "agent"
    meta = json.loads((agent_dir / "agent.json").read_text())
    assert meta["num_timesteps"] >= 512
    policy = load_agent(agent_dir)
    core = TrackingCore(EnvConfig.build(policy.env_overrides), 1)
    obs = np.zeros((2, core.obs_dim), dtype=np.float32)
    actions, _ = policy.predict(obs, None, np.ones(2, bool))
    assert actions.shape == (2, core.action_dim) and np.all(np.abs(actions) <= 1.0)
    result = tmp_path / "res.json"
    code = evaluate_main(
        [
            "--policy",
            str(agent_dir),
            "--policy",
            "fixed",
            "--scenario",
            "paper",
            "--runs",
            "3",
            "--json",
            str(result),
            "--quiet",
            "--no-clairvoyant",
        ]
    )
    assert code == 0
    data = json.loads(result.read_text())
    assert np.isfinite(data["policies"][str(agent_dir)]["armse_pos"])
    assert (out / "seed_0" / "tb").is_dir()


def test_keep_checkpoints_keeps_every_checkpoint_by_its_step(trained) -> None:
    out, _ = trained
    ckpts = out / "seed_0" / "checkpoints"
    assert sorted(p.name for p in ckpts.iterdir()) == ["latest", "step_256", "step_512"]
    for step in (256, 512):
        meta = json.loads((ckpts / f"step_{step}" / "agent.json").read_text())
        assert meta["num_timesteps"] == step


def test_keep_checkpoints_keeps_the_final_state_between_checkpoint_steps(tmp_path) -> None:
    argv = ("--timesteps", "768", "--checkpoint-every", "512", "--keep-checkpoints")
    assert train_small(tmp_path, *argv, "--no-eval", "--validate-every", "0") == 0
    ckpts = tmp_path / "seed_0" / "checkpoints"
    assert sorted(p.name for p in ckpts.iterdir()) == ["latest", "step_512", "step_768"]
    latest, kept = ckpts / "latest", ckpts / "step_768"
    for name in ("policy.safetensors", "resume.json"):
        assert (kept / name).read_bytes() == (latest / name).read_bytes()


def test_a_resumed_run_keeps_its_own_final_state_over_the_earlier_runs(tmp_path) -> None:
    """Resumed from step_512 of a run that went on to step_768, a run whose budget also ends at
    768 writes its own step_768 (it kept the earlier run's, another budget's)."""
    argv = ("--checkpoint-every", "512", "--keep-checkpoints", "--no-eval", "--validate-every",
            "0")
    assert train_small(tmp_path, "--timesteps", "600", *argv) == 0
    ckpts = tmp_path / "seed_0" / "checkpoints"
    first = json.loads((ckpts / "step_768" / "resume.json").read_text())
    resume = ("--resume", str(ckpts / "step_512"))
    assert train_small(tmp_path, "--timesteps", "700", *resume, *argv) == 0
    kept, latest = (json.loads((ckpts / n / "resume.json").read_text())
                    for n in ("step_768", "latest"))
    assert kept == latest and kept != first


def test_resume_continues_the_step_count(trained) -> None:
    out, cfg = trained
    ckpt = out / "seed_0" / "checkpoints" / "latest"
    before = json.loads((ckpt / "agent.json").read_text())["num_timesteps"]
    argv = [
        "--timesteps",
        str(before + 256),
        "--config",
        str(cfg),
        "--out",
        str(out / "resumed"),
        "--resume",
        str(ckpt),
        "--no-eval",
        "--no-progress",
    ]
    assert train.main(argv) == 0
    after = json.loads((out / "resumed" / "seed_0" / "agent" / "agent.json").read_text())
    assert after["num_timesteps"] >= before + 256


def test_resume_without_out_writes_to_the_checkpoints_own_run(
    trained, tmp_path, monkeypatch, capsys
) -> None:
    """``--resume RUN/seed_0/checkpoints/step_256`` alone continues RUN, not ./runs/default;
    a checkpoint outside a run directory needs ``--out``."""
    out, _ = trained
    run = tmp_path / "run"
    shutil.copytree(out / "seed_0" / "checkpoints" / "step_256", run / "seed_0" / "checkpoints"
                    / "step_256")
    monkeypatch.chdir(tmp_path)
    argv = ["--timesteps", "512", "--no-eval", "--no-progress", "--validate-every", "0"]
    assert train.main(["--resume", "run/seed_0/checkpoints/step_256", *argv]) == 0
    assert not (tmp_path / "runs").exists()
    assert json.loads((run / "seed_0" / "training.json").read_text())["timesteps"] == 512
    assert (run / "seed_0" / "agent" / "agent.json").is_file() and (run / "summary.json").is_file()
    assert "the run the checkpoint belongs to" in train.build_parser().format_help()
    shutil.copytree(run / "seed_0" / "checkpoints" / "step_256", tmp_path / "loose")
    with pytest.raises(SystemExit) as exc:
        train.main(["--resume", "loose", *argv])
    assert exc.value.code == 2
    assert "'loose' is not in a run directory (OUT/seed_0/checkpoints/NAME): give --out" in (
        capsys.readouterr().err
    )


def test_a_new_run_into_an_earlier_runs_directory_is_refused_before_training(tmp_path, capsys):
    """A seed_S/ already in --out (an earlier run: its best/ would select its network as the new
    agent) is a usage error before any seed trains, saying how to proceed; the earlier run is
    left as it was. --out must be a directory."""
    argv = ("--timesteps", "256", "--no-eval", "--validate-every", "128", "--validation-runs", "2")
    assert train_small(tmp_path, *argv) == 0
    files = {p: p.read_bytes() for p in (tmp_path / "seed_0").rglob("*") if p.is_file()}
    with pytest.raises(SystemExit) as exc:
        train_small(tmp_path, *argv, "--seed", "1", "0")
    assert exc.value.code == 2
    err = capsys.readouterr().err
    run = tmp_path / "seed_0"
    assert f"already holds {run} (an earlier run" in err
    assert f"give another --out, or remove {run}; to continue that run: python train.py " in err
    assert not (tmp_path / "seed_1").exists()
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == files
    (tmp_path / "afile").write_text("")
    for out in (tmp_path / "afile", tmp_path / "afile" / "below"):
        with pytest.raises(SystemExit) as exc:
            train.main(["--out", str(out), "--no-eval"])
        assert exc.value.code == 2
        assert f"{str(tmp_path / 'afile')!r} is a file, not a directory" in capsys.readouterr().err


def test_a_resumed_run_continues_its_own_directory_and_validation_record(trained, tmp_path):
    """--resume into the checkpoint's own run is allowed: its validation record continues from
    the checkpoint's step (what was kept after it is not this run's past) and an evaluation of
    the agent it replaces is removed (--no-eval), the seed's and the seeds' gathered one."""
    out, _ = trained
    run = tmp_path / "seed_0"
    shutil.copytree(out / "seed_0" / "checkpoints", run / "checkpoints")
    (run / "best").mkdir()
    history = [{"timesteps": 256, "armse_pos": 30.0}, {"timesteps": 512, "armse_pos": 1.0}]
    record = {"armse_pos": 1.0, "timesteps": 512, "history": history}
    (run / "best" / "validation.json").write_text(json.dumps(record))
    (run / "report.md").write_text("the earlier agent's\n")
    (tmp_path / "report.md").write_text("the earlier agents' across seeds\n")
    argv = ["--resume", str(run / "checkpoints" / "step_256"), "--timesteps", "512", "--no-eval"]
    argv += ["--no-progress", "--validate-every", "256", "--validation-runs", "2"]
    assert train.main(argv) == 0
    stats = json.loads((run / "training.json").read_text())
    assert [v["timesteps"] for v in stats["validation"]] == [256, 512]
    assert stats["validation"][0]["armse_pos"] == 30.0 and not (run / "report.md").exists()
    assert not (tmp_path / "report.md").exists()
    assert "across_seeds" not in json.loads((tmp_path / "summary.json").read_text())


@pytest.mark.parametrize(
    ("argv", "given"),
    [
        (["--timesteps", "200"], "--timesteps 200"),
        (["--timesteps", "512"], "--timesteps 512"),
        ([], "the budget 512 (n_timesteps of the checkpoint)"),
    ],
)
def test_resume_refuses_a_budget_the_checkpoint_has_reached(trained, argv, given, tmp_path, capsys):
    out, _ = trained
    ckpt = out / "seed_0" / "checkpoints" / "latest"  # 512 steps
    with pytest.raises(SystemExit) as exc:
        train.main(["--resume", str(ckpt), *argv, "--out", str(tmp_path / "r"), "--no-eval"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"{given} is not above the 512 steps the checkpoint {ckpt} was trained for" in err
    assert "give --timesteps N with N > 512" in err and not (tmp_path / "r").exists()


def test_training_json_counts_the_steps_trained_in_whole_rollouts(tmp_path) -> None:
    """--timesteps 100 with rollouts of 8 x 32 steps trains 256: training.json says 256 and
    rates them."""
    assert train_small(tmp_path, "--timesteps", "100", "--no-eval", "--validate-every", "0") == 0
    stats = json.loads((tmp_path / "seed_0" / "training.json").read_text())
    assert stats["timesteps"] == stats["trained_this_call"] == 256
    assert stats["fps"] == pytest.approx(256 / stats["seconds"])


@pytest.fixture(scope="module")
def resumed_and_evaluated(trained, tmp_path_factory):
    """``trained``'s 512-step checkpoint resumed to 768 steps and evaluated on one run of each
    scenario."""
    out, _ = trained
    resumed = tmp_path_factory.mktemp("resumed")
    argv = ["--resume", str(out / "seed_0" / "checkpoints" / "latest"), "--timesteps", "768"]
    argv += ["--out", str(resumed), "--paper-runs", "1", "--random-runs", "1", "--no-progress"]
    assert train.main([*argv, "--validate-every", "0"]) == 0
    return resumed


def test_a_resumed_runs_report_gives_this_calls_steps_in_its_seconds_and_the_total(
    resumed_and_evaluated,
) -> None:
    run = resumed_and_evaluated / "seed_0"
    stats = json.loads((run / "training.json").read_text())
    assert stats["trained_this_call"] == 256 and stats["timesteps"] == 768
    seconds, fps = f"{stats['seconds']:.0f}", f"{stats['fps']:,.0f}"
    assert (
        f"Training: 256 steps in {seconds} s ({fps} steps/s, SB3 on 1 thread); 768 steps in all, "
        "resumed at step 512." in (run / "report.md").read_text()
    )


def test_validation_keeps_the_best_checkpoint_as_the_agent(tmp_path) -> None:
    argv = ("--timesteps", "1024", "--validate-every", "256", "--validation-runs", "3")
    assert train_small(tmp_path, *argv, "--no-eval", extra="swa_start: null\n") == 0
    run = tmp_path / "seed_0"
    stats = json.loads((run / "training.json").read_text())
    scores = [v["armse_pos"] for v in stats["validation"]]
    assert len(scores) >= 4 and all(np.isfinite(scores))  # 256, 512, 768, 1024 and the end
    best = min(range(len(scores)), key=scores.__getitem__)
    assert stats["selected"]["armse_pos"] == scores[best]
    assert stats["selected"]["timesteps"] == stats["validation"][best]["timesteps"]
    agent = json.loads((run / "agent" / "agent.json").read_text())
    assert agent["num_timesteps"] == stats["selected"]["timesteps"]
    agent, best = run / "agent" / "policy.safetensors", run / "best" / "policy.safetensors"
    assert agent.read_bytes() == best.read_bytes()


def test_the_checkpoint_and_validation_of_step_n_hold_the_weights_of_the_update_reaching_n(
    tmp_path,
) -> None:
    """Scheduled after each update: step 256's checkpoint and validation (one rollout of
    SMALL) are of the weights a 256-step run ends with, not the untrained network of before
    that rollout's update; the end is validated once."""
    argv = ("--validate-every", "256", "--validation-runs", "2", "--no-eval")
    argv += ("--checkpoint-every", "256", "--keep-checkpoints")
    one, two = tmp_path / "one", tmp_path / "two"
    for out, steps in ((one, "256"), (two, "512")):
        out.mkdir()
        assert train_small(out, "--timesteps", steps, *argv, extra="swa_start: null\n") == 0
    first = json.loads((one / "seed_0" / "training.json").read_text())["validation"]
    both = json.loads((two / "seed_0" / "training.json").read_text())["validation"]
    assert [v["timesteps"] for v in first] == [256]
    assert [v["timesteps"] for v in both] == [256, 512]
    assert both[0] == first[0]
    ended = one / "seed_0" / "checkpoints" / "latest" / "policy.safetensors"
    kept = two / "seed_0" / "checkpoints" / "step_256" / "policy.safetensors"
    assert kept.read_bytes() == ended.read_bytes()


def test_without_a_progress_bar_each_checkpoint_and_validation_prints_a_line(
    tmp_path, capsys
) -> None:
    argv = ("--timesteps", "1024", "--checkpoint-every", "256", "--validate-every", "512")
    assert train_small(tmp_path, *argv, "--validation-runs", "3", "--no-eval") == 0
    out = capsys.readouterr().out.splitlines()
    lines = [line for line in out if line.startswith("seed 0: step ")]
    pattern = r"seed 0: step ([\d,]+)/1,024, [\d,]+ steps/s"
    pattern += r"(, validation ARMSE \d+\.\d{3} m)?, .+ left"
    matches = [re.fullmatch(pattern, line) for line in lines]
    assert all(matches), lines
    assert [m[1] for m in matches] == ["256", "512", "768", "1,024"]
    assert [bool(m[2]) for m in matches] == [False, True, False, True]


@pytest.mark.parametrize(
    ("seconds", "text"),
    [(44.6, "45 s"), (510, "8 min 30 s"), (7500, "2 h 05 min"), (float("inf"), "?")],
)
def test_time_left_reads_as_a_duration(seconds, text) -> None:
    assert train._duration(seconds) == text


def test_the_progress_line_rates_the_steps_of_this_call() -> None:
    line = train.progress_line(3000, 1000, 5000, 4.0, 17.5)
    assert line == "step 3,000/5,000, 500 steps/s, validation ARMSE 17.500 m, 4 s left"


def test_a_progress_line_is_one_write(monkeypatch) -> None:
    """Seeds trained side by side share stdout: each line, newline included, goes out in one
    write, so lines of two processes cannot interleave within a line."""
    writes: list[str] = []

    class Recorder:
        def write(self, text: str) -> int:
            writes.append(text)
            return len(text)

        def flush(self) -> None:
            writes.append("<flush>")

    monkeypatch.setattr(train.sys, "stdout", Recorder())
    train.say("seed 3: step 1,000/2,000")
    assert writes == ["seed 3: step 1,000/2,000\n", "<flush>"]


def test_swa_agent_is_the_mean_of_the_weights_after_every_update(tmp_path) -> None:
    # 8 envs x 32 steps: an update every 256 steps; averaging from step 512 of 1024 takes the
    # weights after updates 2, 3 and 4, which checkpoints step_512, step_768 and step_1024 hold
    # (each saved after the update reaching its step)
    cfg = tmp_path / "swa.yml"
    cfg.write_text(SMALL + "swa_start: 0.5\n")
    common = ["--config", str(cfg), "--no-progress", "--no-eval", "--checkpoint-every", "256"]
    argv = ["--out", str(tmp_path), "--timesteps", "1024", "--keep-checkpoints"]
    assert train.main([*common, *argv, "--validate-every", "512", "--validation-runs", "3"]) == 0
    run = tmp_path / "seed_0"
    ckpts = run / "checkpoints"
    snapshots = [load_agent(ckpts / name).model for name in ("step_512", "step_768", "step_1024")]
    expected = {
        k: sum(m.state_dict()[k] for m in snapshots) / 3 for k in snapshots[0].state_dict()
    }
    agent = load_agent(run / "agent").model.state_dict()
    for k, v in expected.items():
        np.testing.assert_allclose(agent[k].numpy(), v.numpy(), rtol=1e-5, atol=1e-7)
    last = snapshots[-1].state_dict()["action_net.weight"]
    assert not np.allclose(agent["action_net.weight"], last)  # not an iterate
    stats = json.loads((run / "training.json").read_text())
    assert stats["selected"]["swa_start"] == 512 and stats["selected"]["snapshots"] == 3
    meta = json.loads((run / "agent" / "agent.json").read_text())
    assert meta["swa"] == {"swa_start": 512, "snapshots": 3}
    assert np.isfinite(stats["selected"]["armse_pos"])
    # resuming from the last checkpoint continues its mean: one more update, four snapshots
    argv = ["--out", str(tmp_path / "resumed"), "--timesteps", "1280", "--validate-every", "0"]
    assert train.main([*common, *argv, "--resume", str(ckpts / "latest")]) == 0
    stats = json.loads((tmp_path / "resumed" / "seed_0" / "training.json").read_text())
    assert stats["selected"]["snapshots"] == 4


def _hyperparams(tmp_path: Path, yaml: str) -> dict:
    """The run's hyperparameters with ``yaml`` as ``--config`` (nothing trained)."""
    config = tmp_path / "c.yml"
    config.write_text(yaml)
    parser = train.build_parser()
    args = parser.parse_args(["--config", str(config), "--out", str(tmp_path / "out")])
    return train.hyperparams(args, train.check_args(parser, args))


def test_config_env_kwargs_reach_every_part_of_the_mixture(tmp_path) -> None:
    """A reward change (or what the policy reads, logit_scale) in a --config file's env_kwargs
    reaches every slot, not only the entry's main part: the default entry has a mixture."""
    params = _hyperparams(tmp_path, "env_kwargs: {tpm_change_cost: 0.1, mode_reward: 0.0}\n")
    parts = [params["env_kwargs"]] + [p["env_kwargs"] for p in params["env_mixture"]]
    assert len(parts) > 1
    assert all((p["tpm_change_cost"], p["mode_reward"]) == (0.1, 0.0) for p in parts)
    params = _hyperparams(tmp_path, "env_kwargs: {logit_scale: 4.0}\n")
    assert {p["env_kwargs"]["logit_scale"] for p in params["env_mixture"]} == {4.0}
    assert params["env_kwargs"]["logit_scale"] == 4.0
    # a tracker field stays the main part's: the parts are there to vary the trackers
    params = _hyperparams(tmp_path, "env_kwargs: {sensor: {sigma_r: 30.0}}\n")
    assert params["env_kwargs"]["sensor"] == {"sigma_r": 30.0}
    before = _hyperparams(tmp_path, "{}\n")["env_mixture"]
    assert params["env_mixture"] == before


def test_config_policy_kwargs_apply_key_by_key_over_the_entrys(tmp_path) -> None:
    """A --config file giving one policy_kwargs key keeps the entry's others (its 128x128
    net_arch was dropped for SB3's 64x64 default); a key given replaces the entry's whole."""
    entry = _hyperparams(tmp_path, "{}\n")["policy_kwargs"]
    assert entry["net_arch"] == {"pi": [128, 128], "vf": [128, 128]}
    params = _hyperparams(tmp_path, "policy_kwargs: {log_std_init: -0.5}\n")
    assert params["policy_kwargs"] == {**entry, "log_std_init": -0.5}
    params = _hyperparams(tmp_path, "policy_kwargs: {net_arch: {pi: [64], vf: [32]}}\n")
    assert params["policy_kwargs"] == {**entry, "net_arch": {"pi": [64], "vf": [32]}}


def test_a_config_restating_the_mixture_keeps_its_own(tmp_path) -> None:
    from agents.training import DEFAULT_ENTRY, load_hyperparams

    mixture = load_hyperparams(DEFAULT_ENTRY)[0]["env_mixture"]
    mixture = [{**p, "env_kwargs": {**p["env_kwargs"], "mode_reward": 0.2}} for p in mixture]
    given = {"env_kwargs": {"mode_reward": 0.0}, "env_mixture": mixture}
    params = _hyperparams(tmp_path, json.dumps(given))
    assert params["env_mixture"] == mixture
    assert params["env_kwargs"]["mode_reward"] == 0.0


@pytest.mark.parametrize("value", ["1.0", "-0.1", "'late'", "false"])
def test_bad_swa_start_is_rejected(value, tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        train_small(tmp_path, "--timesteps", "256", extra=f"swa_start: {value}\n")
    assert exc.value.code == 2
    assert "swa_start must be a fraction of the budget in [0, 1)" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--timesteps", "0"], "--timesteps must be >= 1"),
        (["--seed", "-1"], "--seed values"),
        (["--seed", "1", "1"], "--seed values"),
        (["--seed", "0", str(2**32)], f"--seed values must be distinct integers in [0, {2**32-1}]"),
        (["--env", "imm_gym/Nope-v0"], "is not registered"),
        (["--resume", "does/not/exist"], "is not a checkpoint"),
        (["--config", "missing.yml"], "does not exist"),
        (["--algo", "dqn"], "invalid choice"),
        (["--validate-every", "-1"], "--validate-every must be >= 0"),
        (["--validation-runs", "0"], "--validation-runs must be in [1, 50000000], got 0"),
    ],
)
def test_bad_arguments(argv, message, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        train.main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("flag", "most", "beyond"),
    [
        ("--validation-runs", 50_000_000, "the training seeds (100000000+)"),
        ("--paper-runs", 1_000_000, "the tuners' training seeds (1000000+)"),
        ("--random-runs", 1_000_000, "the tuners' training seeds (1000000+)"),
    ],
)
def test_run_counts_whose_seeds_reach_another_range_are_refused(
    flag, most, beyond, tmp_path, capsys
) -> None:
    """Validation seeds 50,000,000 + r stay below the training slots, evaluation seeds
    0 .. R - 1 below the tuners' (imm_gym.seeding, imm_gym.cli.arguments.MAX_RUNS)."""
    parser = train.build_parser()
    out = ["--out", str(tmp_path / "out")]
    train.check_args(parser, parser.parse_args([flag, str(most), *out]))
    with pytest.raises(SystemExit) as exc:
        train.check_args(parser, parser.parse_args([flag, str(most + 1), *out]))
    assert exc.value.code == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"{flag} must be in [1, {most}], got {most + 1}: " in line and beyond in line


@pytest.mark.parametrize(
    ("flag", "least", "extra"),
    [("--checkpoint-every", 1, []), ("--validate-every", 0, []), ("--jobs", 1, [])],
)
def test_step_and_job_counts_are_refused_just_below_their_least(
    flag, least, extra, tmp_path, capsys
) -> None:
    """The least value each count takes is taken (check_args returns), one below it is a usage
    error naming the flag and the value."""
    parser = train.build_parser()
    out = ["--out", str(tmp_path / "out"), *extra]
    assert train.check_args(parser, parser.parse_args([flag, str(least), *out])) is None
    with pytest.raises(SystemExit) as exc:
        train.check_args(parser, parser.parse_args([flag, str(least - 1), *out]))
    assert exc.value.code == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"{flag} must be >= {least}, got {least - 1}" in line


def test_rllib_env_runners_take_zero_and_refuse_below(tmp_path, capsys) -> None:
    """--env-runners 0 (the driver samples) passes the count check; -1 is a usage error. Without
    Ray the zero goes on to the refusal that names Ray, not the count."""
    parser = train.build_parser()
    argv = ["--engine", "rllib", "--out", str(tmp_path / "out"), "--env-runners"]
    with pytest.raises(SystemExit) as exc:
        train.check_args(parser, parser.parse_args([*argv, "-1"]))
    assert exc.value.code == 2
    assert "--env-runners must be >= 0, got -1" in capsys.readouterr().err
    try:
        train.check_args(parser, parser.parse_args([*argv, "0"]))
    except SystemExit as refused:
        assert refused.code == 2
        assert "--engine rllib needs Ray" in capsys.readouterr().err.strip().splitlines()[-1]


def test_the_largest_seed_allowed_trains_and_validates(tmp_path) -> None:
    """Seed 2**32 - 1: every seed derived from it (the training slots' 100,000,000 + 10,000 s + i,
    the constructor's s + i) is one the streams take; 2**32 is refused (test_bad_arguments)."""
    argv = ("--seed", "4294967295", "--timesteps", "256", "--validate-every", "256")
    assert train_small(tmp_path, *argv, "--validation-runs", "2", "--no-eval") == 0
    stats = json.loads((tmp_path / "seed_4294967295" / "training.json").read_text())
    assert stats["timesteps"] == 256 and np.isfinite(stats["validation"][0]["armse_pos"])


def test_every_option_says_what_it_does() -> None:
    """--help gives every option a text; --validate-every's says what the agent is with a weight
    average (swa_start), validations or none."""
    actions = {a.option_strings[-1]: a.help for a in train.build_parser()._actions}
    assert all(actions.values()), [name for name, text in actions.items() if not text]
    validate_every = actions["--validate-every"]
    assert "the weight average when the hyperparameters set swa_start" in validate_every


def test_recurrent_variant_trains_and_evaluates(tmp_path) -> None:
    assert train_small(tmp_path, "--algo", "recurrent-ppo", "--timesteps", "256", "--no-eval") == 0
    agent = tmp_path / "seed_0" / "agent"
    assert json.loads((agent / "agent.json").read_text())["algo"] == "recurrent-ppo"
    assert (
        evaluate_main(
            [
                "--policy",
                str(agent),
                "--scenario",
                "paper",
                "--runs",
                "2",
                "--quiet",
                "--no-clairvoyant",
            ]
        )
        == 0
    )


def test_main_job_writes_results_and_reports(tmp_path) -> None:
    args = ("--timesteps", "256", "--paper-runs", "2", "--random-runs", "2")
    assert train_small(tmp_path, *args) == 0
    run = tmp_path / "seed_0"
    results = json.loads((run / "results.json").read_text())
    for scenario in ("paper", "random"):
        names = set(results[scenario]["policies"])
        assert {"learned", "fixed", "tip-imm", "best-fixed"} <= names
        d = results[scenario]["vs_tip_imm"]
        assert d["low"] <= d["diff"] <= d["high"]
        assert (run / "plots" / scenario / "rmse.png").is_file()
    report = (run / "report.md").read_text()
    assert "learned − tip-imm" in report and "clairvoyant (bound)" in report
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert "across_seeds" in summary and (tmp_path / "report.md").is_file()


def test_one_run_and_one_seed_are_reported_without_an_interval_or_a_spread(
    resumed_and_evaluated,
) -> None:
    """--paper-runs 1 --random-runs 1: the paired CIs are undefined (the report says so, as the
    evaluation's table does, and summary.json is written); one seed has no spread."""
    out = resumed_and_evaluated
    results = json.loads((out / "seed_0" / "results.json").read_text())
    assert results["paper"]["vs_tip_imm"]["low"] is None
    report = (out / "seed_0" / "report.md").read_text()
    assert "learned − tip-imm: " in report and "None" not in report
    lines = [line for line in report.splitlines() if line.startswith("- ")]
    assert lines and all("m undefined (1 run) (" in line for line in lines)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["across_seeds"]["paper"]["armse_pos_std"] is None
    overall = (out / "report.md").read_text()
    assert overall.count(" m, one seed (per seed: ") == 2 and "±" not in overall


def test_the_versions_name_the_package_its_commit_and_the_algorithms_library() -> None:
    import sb3_contrib

    import imm_gym

    versions = train._versions("sb3", "recurrent-ppo")
    assert versions["imm_gym"] == imm_gym.__version__
    assert versions["sb3-contrib"] == sb3_contrib.__version__
    assert "sb3-contrib" not in train._versions("sb3", "ppo")
    if (Path(train.__file__).parent / ".git").exists():
        assert re.fullmatch(r"[0-9a-f]{40}", versions["git_commit"])
        assert isinstance(versions["git_dirty"], bool)


def test_export_copies_the_acting_files(trained, tmp_path) -> None:
    from agents.export import FILES, export

    out, _ = trained
    copied = export(out / "seed_0" / "agent", tmp_path / "shipped")
    assert sorted(p.name for p in copied) == sorted(FILES)
    policy = load_agent(tmp_path / "shipped")
    core = TrackingCore(EnvConfig.build(policy.env_overrides), 1)
    actions, _ = policy.predict(np.zeros((1, core.obs_dim), dtype=np.float32))
    assert actions.shape == (1, core.action_dim)
    with pytest.raises(FileNotFoundError, match="no trained agent"):
        export(tmp_path / "nothing", tmp_path / "other")


def test_export_ships_an_ensemble_self_contained_and_replaces_its_target(trained, tmp_path):
    import shutil

    from agents.ensemble import EnsemblePolicy, load_policy, write_ensemble
    from agents.export import FILES, export
    from imm_gym.validation import ConfigError

    out, _ = trained
    first = out / "seed_0" / "agent"
    second = Path(shutil.copytree(first, tmp_path / "work" / "other"))
    meta = json.loads((second / "agent.json").read_text())
    (second / "agent.json").write_text(json.dumps({**meta, "seed": 7}))
    write_ensemble(tmp_path / "work" / "ens", [first, second])
    source = load_policy(tmp_path / "work" / "ens")
    core = TrackingCore(EnvConfig.build(source.env_overrides), 3)
    obs = np.random.default_rng(0).normal(size=(3, core.obs_dim)).astype(np.float32)

    target = tmp_path / "shipped"
    copied = export(tmp_path / "work" / "ens", target)
    shutil.rmtree(tmp_path / "work")  # the shipped ensemble holds its members
    assert {p.relative_to(target).parts[0] for p in copied} == {"ensemble.json", "seed_0", "seed_7"}
    shipped = load_policy(target)
    assert isinstance(shipped, EnsemblePolicy) and len(shipped.members) == 2
    np.testing.assert_array_equal(shipped.predict(obs)[0], source.predict(obs)[0])

    export(first, target)  # an agent over the ensemble: nothing of the ensemble stays
    assert sorted(p.name for p in target.iterdir()) == sorted(
        p.name for p in first.iterdir() if p.name in FILES
    )
    assert not isinstance(load_policy(target), EnsemblePolicy)

    unrelated = tmp_path / "notes"
    unrelated.mkdir()
    (unrelated / "todo.txt").write_text("keep me")
    with pytest.raises(ConfigError, match=r"notes.*must be absent, empty or a policy"):
        export(first, unrelated)
    assert (unrelated / "todo.txt").read_text() == "keep me"



def test_pretrained_policy_ships_small_and_scores(tmp_path) -> None:
    from agents import PRETRAINED

    size = sum(p.stat().st_size for p in PRETRAINED.rglob("*") if p.is_file())
    assert size < 2 * 1024 * 1024  # five agents of about 340 KiB
    result = tmp_path / "res.json"
    argv = ["--policy", "pretrained", "--policy", "fixed", "--scenario", "paper", "--runs", "3"]
    assert evaluate_main([*argv, "--json", str(result), "--quiet", "--no-clairvoyant"]) == 0
    row = json.loads(result.read_text())["policies"]["pretrained"]
    assert np.isfinite(row["armse_pos"]) and row["diverged"] == 0


def test_linear_schedules_from_rl_zoo_strings() -> None:
    from agents.training import algo_kwargs

    kwargs = algo_kwargs({"n_envs": 8, "learning_rate": "lin_3e-4", "clip_range": 0.2})
    assert "n_envs" not in kwargs and kwargs["clip_range"] == 0.2
    schedule = kwargs["learning_rate"]
    assert schedule(1.0) == pytest.approx(3e-4) and schedule(0.25) == pytest.approx(7.5e-5)
    assert schedule(0.0) == 0.0
    with pytest.raises(ValueError, match="learning_rate"):
        algo_kwargs({"learning_rate": "exp_3e-4"})


SUITE = Path(__file__).resolve().parents[2] / "imm_gym" / "scenarios" / "suite"


@pytest.mark.parametrize(
    ("scenario", "runs", "reference"),
    [
        ("random", 200, "tip-imm"),
        ("vsmm-s2", 100, "tip-imm"),
        ("atc", 100, "best-fixed"),
        ("vsmm-s3", 100, "best-fixed-rows"),
    ],
)
def test_pretrained_agent_beats_the_rule(scenario, runs, reference, tmp_path) -> None:
    """The shipped policy's README claims: below TIP-IMM on held-out random scenarios and on
    `vsmm-s2`, below the best fixed TPM on `atc` and, with a stay per model too
    (`best-fixed-rows`), on `vsmm-s3` (their suite files), 95 % CIs excluding zero."""
    result = tmp_path / "res.json"
    argv = ["--policy", "pretrained", "--policy", reference, "--env-config"]
    argv += [str(SUITE / f"{scenario}.yaml"), "--runs", str(runs), "--reference", reference]
    assert evaluate_main([*argv, "--json", str(result), "--quiet", "--no-clairvoyant"]) == 0
    paired = json.loads(result.read_text())["paired"]
    assert paired["reference"] == reference
    assert paired["differences"]["pretrained"]["high"] < 0.0


@pytest.mark.parametrize(("scenario", "runs"), [("paper", 100), ("random", 200)])
def test_pretrained_agent_keeps_the_mode_probabilities_meaning(scenario, runs, tmp_path) -> None:
    """Issue #15's mode integrity: the shipped policy's mode accuracy above TIP-IMM's and its
    mode probabilities moving by at most 0.15 a step (total variation) on average."""
    result = tmp_path / "res.json"
    argv = ["--policy", "pretrained", "--policy", "tip-imm", "--scenario", scenario]
    assert evaluate_main([*argv, "--runs", str(runs), "--json", str(result), "--quiet"]) == 0
    rows = json.loads(result.read_text())["policies"]
    assert rows["pretrained"]["mode_accuracy"] > rows["tip-imm"]["mode_accuracy"]
    assert rows["pretrained"]["mode_prob_tv"] <= 0.15


@pytest.mark.parametrize("scenario", ["vsmm-s1", "atc"])
def test_pretrained_agent_reads_a_tracker_however_its_models_are_listed(scenario, tmp_path):
    """The suite's tracker with its models listed CT(+), CV, CT(−): the shipped policy
    (``model_order: canonical``) scores what it scores on the file's own listing."""
    lines = (SUITE / f"{scenario}.yaml").read_text().splitlines()
    models = [i for i, line in enumerate(lines) if line.lstrip().startswith("- {kind")]
    assert len(models) == 3
    listed = list(lines)
    listed[models[0]], listed[models[1]] = lines[models[1]], lines[models[0]]
    assert "kind: ct" in listed[models[0]] and "kind: cv" in listed[models[1]]
    (tmp_path / "listed.yaml").write_text("\n".join(listed) + "\n")
    scores = []
    for name in (SUITE / f"{scenario}.yaml", tmp_path / "listed.yaml"):
        result = tmp_path / "res.json"
        argv = ["--policy", "pretrained", "--env-config", str(name), "--runs", "20"]
        assert evaluate_main([*argv, "--json", str(result), "--quiet", "--no-clairvoyant"]) == 0
        scores.append(json.loads(result.read_text())["policies"]["pretrained"])
    assert scores[1]["armse_pos"] == pytest.approx(scores[0]["armse_pos"], rel=1e-9)
    assert scores[1]["mode_accuracy"] == pytest.approx(scores[0]["mode_accuracy"], abs=1e-12)


def test_several_seeds_make_an_ensemble_of_their_agents(tmp_path) -> None:
    from agents.ensemble import load_ensemble

    assert train_small(tmp_path, "--timesteps", "256", "--no-eval", "--seed", "0", "1") == 0
    ensemble = load_ensemble(tmp_path / "ensemble")
    members = [load_agent(tmp_path / f"seed_{s}" / "agent") for s in (0, 1)]
    obs = np.random.default_rng(0).normal(size=(4, members[0].obs_size))
    each = [m.predict(obs)[0] for m in members]
    np.testing.assert_allclose(ensemble.predict(obs)[0], (each[0] + each[1]) / 2, atol=1e-7)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["ensemble"] == str(tmp_path / "ensemble")


def test_the_recorded_command_is_shell_quoted(tmp_path) -> None:
    out = tmp_path / "sp ace"
    out.mkdir()
    assert train_small(out, "--timesteps", "256", "--no-eval", "--validate-every", "0") == 0
    command = json.loads((out / "summary.json").read_text())["command"]
    assert shlex.split(command)[:2] == ["python", "train.py"]
    assert shlex.split(command)[2:] == ["--config", str(out / "small.yml"), "--out", str(out),
                                        "--no-progress", "--timesteps", "256", "--no-eval",
                                        "--validate-every", "0"]


def test_resuming_one_seed_of_several_keeps_the_others_in_the_summary(tmp_path) -> None:
    from agents.ensemble import load_ensemble

    argv = ("--timesteps", "256", "--no-eval", "--validate-every", "0", "--seed", "0", "1")
    assert train_small(tmp_path, *argv) == 0
    before = json.loads((tmp_path / "summary.json").read_text())
    latest = tmp_path / "seed_1" / "checkpoints" / "latest"
    argv = ("--timesteps", "512", "--no-eval", "--validate-every", "0", "--no-progress")
    assert train.main(["--resume", str(latest), *argv]) == 0
    after = json.loads((tmp_path / "summary.json").read_text())
    assert list(after["seeds"]) == ["0", "1"]
    assert after["seeds"]["0"] == before["seeds"]["0"]
    assert after["seeds"]["1"]["training"]["timesteps"] == 512
    assert after["ensemble"] == str(tmp_path / "ensemble")
    assert "--resume" in after["command"]
    assert len(load_ensemble(tmp_path / "ensemble").members) == 2
    ensemble = json.loads((tmp_path / "ensemble" / "ensemble.json").read_text())
    assert ensemble["members"] == ["../seed_0/agent", "../seed_1/agent"]


def test_jobs_train_seeds_in_parallel_processes_to_the_agents_they_get_alone(tmp_path) -> None:
    """``--jobs 2``: each seed in its own spawned process, its agent byte for byte the one a
    sequential run gives, the summary in ``--seed`` order and the ensemble written."""
    args = ("--timesteps", "256", "--no-eval", "--seed", "1", "0")
    for run in ("one_by_one", "parallel"):
        (tmp_path / run).mkdir()
    assert train_small(tmp_path / "one_by_one", *args) == 0
    assert train_small(tmp_path / "parallel", *args, "--jobs", "2") == 0
    for seed in (0, 1):
        weights = [
            (tmp_path / run / f"seed_{seed}" / "agent" / "policy.safetensors").read_bytes()
            for run in ("one_by_one", "parallel")
        ]
        assert weights[0] == weights[1]
    summary = json.loads((tmp_path / "parallel" / "summary.json").read_text())
    assert list(summary["seeds"]) == ["1", "0"]
    assert (tmp_path / "parallel" / "ensemble" / "ensemble.json").is_file()


def test_jobs_must_be_positive_and_are_for_sb3(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        train_small(tmp_path, "--jobs", "0")
    assert exit_info.value.code == 2
    assert "--jobs must be >= 1, got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        train_small(tmp_path, "--jobs", "2", "--engine", "rllib")
    assert "--jobs is for --engine sb3" in capsys.readouterr().err
