"""``python train.py``'s setup called directly (:mod:`agents.train_setup`), no step trained: each
refusal of an argument by the function that makes it (``check_args``: a usage error, status 2;
``hyperparams``: a ConfigError), so that a refusal lost is seen at once rather than after a full
training run; the merge of a ``--config`` file over the entry, the run a checkpoint belongs to
and what an ``--out`` holding an earlier run says."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from agents.train_setup import (
    build_parser,
    check_args,
    checkpoint_run,
    hyperparams,
    on_preset,
    with_config,
)
from agents.training import (
    DEFAULT_ENTRY,
    MAX_SEED,
    algo_kwargs,
    check_hyperparams,
    load_hyperparams,
)
from imm_gym.validation import ConfigError


def parsed(argv: list[str], tmp_path: Path) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    """The parser and ``argv`` parsed, ``--out TMP/out`` unless ``argv`` gives its own."""
    parser = build_parser()
    out = [] if "--out" in argv else ["--out", str(tmp_path / "out")]
    return parser, parser.parse_args([*argv, *out])


def refusal(argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """``check_args`` of ``argv``: a usage error (status 2), nothing made; its message."""
    parser, args = parsed(argv, tmp_path)
    with pytest.raises(SystemExit) as exc:
        check_args(parser, args)
    assert exc.value.code == 2
    assert not (tmp_path / "out").exists()
    return capsys.readouterr().err.strip().splitlines()[-1]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--timesteps", "0"], "--timesteps must be >= 1, got 0"),
        (["--timesteps", "-256"], "--timesteps must be >= 1, got -256"),
        (["--seed", "-1"], f"--seed values must be distinct integers in [0, {2**32 - 1}]"),
        (["--seed", str(2**32)], f"integers in [0, {2**32 - 1}] (2**32 - 1: numpy's global"),
        (["--seed", "3", "1", "3"], "--seed values must be distinct integers in [0, "),
        (["--env", "CartPole-v1"], "--env 'CartPole-v1' is not an imm_gym environment; availa"),
        (["--env", "imm_gym/Nope-v0"], "--env 'imm_gym/Nope-v0' is not registered; available:"),
        (["--resume", "does/not/exist"], "--resume does/not/exist is not a checkpoint"),
        (["--config", "missing.yml"], "--config file 'missing.yml' does not exist"),
        (["--jobs", "0"], "--jobs must be >= 1, got 0"),
        (["--jobs", "2", "--engine", "rllib"], "--jobs is for --engine sb3; RLlib runs its own"),
        (["--checkpoint-every", "0"], "--checkpoint-every must be >= 1, got 0"),
        (["--validate-every", "-1"], "--validate-every must be >= 0, got -1"),
        (["--validation-runs", "0"], "--validation-runs must be in [1, 50000000], got 0: "),
        (["--paper-runs", "0"], "--paper-runs must be in [1, 1000000], got 0: the evaluation"),
        (["--random-runs", "0"], "--random-runs must be in [1, 1000000], got 0: the evaluation"),
        (["--paper-runs", "-3"], "--paper-runs must be in [1, 1000000], got -3"),
        (["--ray-address", "auto"], "--ray-address and --env-runners apply to --engine rllib"),
        (["--env-runners", "2"], "--ray-address and --env-runners apply to --engine rllib"),
        (["--engine", "rllib", "--algo", "recurrent-ppo"], "--engine rllib trains --algo ppo"),
        (["--env-shares", "1", "1"], "--env-shares gives one weight per --env-config file"),
        (["--env-config", "X", "Y", "--env-shares", "1", "0"], "must be positive numbers, got"),
    ],
)
def test_each_bad_argument_is_refused_by_check_args(argv, message, tmp_path, capsys) -> None:
    """The refusals ``train.main`` makes before any work, each by ``check_args`` itself: none of
    them reaches the hyperparameters, let alone a training step."""
    assert message in refusal(argv, tmp_path, capsys)


def test_an_algorithm_outside_the_choices_is_refused_by_the_parser(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["--algo", "dqn"])
    assert exc.value.code == 2
    assert "argument --algo: invalid choice: 'dqn'" in capsys.readouterr().err


def test_every_count_is_taken_at_its_least_and_the_seeds_at_their_ends(tmp_path) -> None:
    """One step, one run of each evaluation, one validation run, checkpoints every step, no
    validation, one job, and the seeds 0 and 2**32 - 1 together pass; the omitted --env,
    --algo and --out are filled in."""
    argv = ["--timesteps", "1", "--seed", "0", str(MAX_SEED), "--paper-runs", "1"]
    argv += ["--random-runs", "1", "--validation-runs", "1", "--checkpoint-every", "1"]
    argv += ["--validate-every", "0", "--jobs", "1"]
    parser, args = parsed(argv, tmp_path)
    assert check_args(parser, args) is None
    assert (args.env, args.algo, args.seed) == (DEFAULT_ENTRY, "ppo", [0, 2**32 - 1])
    assert args.out == tmp_path / "out" and not args.out.exists()


# --- a --config file over the entry ----------------------------------------------------------

ENTRY = {
    "n_envs": 8,
    "gamma": 0.9,
    "env_kwargs": {"reward": "error", "sensor": {"sigma_r": 30.0}},
    "policy_kwargs": {"net_arch": [64, 64], "log_std_init": -1.0},
    "env_mixture": [
        {"env_kwargs": {"sensor": {"sigma_r": 80.0}, "reward": "error"}, "share": 0.25},
    ],
}


def test_a_config_file_changes_the_keys_it_gives_and_keeps_the_entrys_others() -> None:
    """By hand: gamma replaced, n_envs kept; env_kwargs and policy_kwargs key by key (the
    entry's sensor and net_arch stay beside the file's); the file's reward reaches the mixture's
    part, whose own tracker (its sensor) stays."""
    extra = {"gamma": 0.5, "env_kwargs": {"reward": "measurement", "tpm_cost": 0.1},
             "policy_kwargs": {"log_std_init": 0.0}}
    assert with_config(ENTRY, extra) == {
        "n_envs": 8,
        "gamma": 0.5,
        "env_kwargs": {"reward": "measurement", "sensor": {"sigma_r": 30.0}, "tpm_cost": 0.1},
        "policy_kwargs": {"net_arch": [64, 64], "log_std_init": 0.0},
        "env_mixture": [
            {"env_kwargs": {"sensor": {"sigma_r": 80.0}, "reward": "measurement",
                            "tpm_cost": 0.1}, "share": 0.25},
        ],
    }
    assert ENTRY["env_kwargs"]["reward"] == "error"  # the entry itself is left as it was


def test_a_config_file_giving_its_own_mixture_keeps_it_as_it_stands() -> None:
    mixture = [{"env_kwargs": {"reward": "error"}, "share": 0.5}]
    extra = {"env_kwargs": {"reward": "measurement"}, "env_mixture": mixture}
    updated = with_config(ENTRY, extra)
    assert updated["env_mixture"] == mixture
    assert updated["env_kwargs"]["reward"] == "measurement"


def test_a_config_file_without_env_kwargs_leaves_the_entrys_whole() -> None:
    assert with_config(ENTRY, {"n_envs": 16}) == {**ENTRY, "n_envs": 16}


# --- the run a checkpoint belongs to ---------------------------------------------------------


def test_the_run_of_a_checkpoint_is_the_directory_above_its_seed(tmp_path, monkeypatch) -> None:
    """OUT/seed_S/checkpoints/NAME of seed S belongs to OUT (relative where it lies below the
    working directory); a checkpoint of another seed's directory, or not in checkpoints/, to
    no run."""
    run = tmp_path / "a" / "run"
    assert checkpoint_run(run / "seed_3" / "checkpoints" / "latest", 3) == run
    assert checkpoint_run(run / "seed_3" / "checkpoints" / "step_256", 3) == run
    assert checkpoint_run(run / "seed_3" / "checkpoints" / "latest", 4) is None
    assert checkpoint_run(run / "seed_3" / "saved" / "latest", 3) is None
    assert checkpoint_run(run / "checkpoints" / "latest", 3) is None
    monkeypatch.chdir(tmp_path)
    relative = checkpoint_run(Path("a/run/seed_3/checkpoints/latest"), 3)
    assert relative == Path("a/run") and not relative.is_absolute()


# --- an --out that holds an earlier run -----------------------------------------------------


def test_an_out_holding_a_seed_s_run_is_refused_with_the_command_to_continue_it(
    tmp_path, capsys
) -> None:
    """Where the earlier run left checkpoints/latest/resume.json the refusal ends with the
    command that continues it; where it did not, it names only the directory to remove."""
    out = tmp_path / "runs"
    latest = out / "seed_1" / "checkpoints" / "latest"
    latest.mkdir(parents=True)
    argv = ["--out", str(out), "--seed", "0", "1"]
    line = refusal(argv, tmp_path, capsys)
    assert line.endswith(f"give another --out, or remove {out / 'seed_1'}")
    (latest / "resume.json").write_text("{}")
    line = refusal(argv, tmp_path, capsys)
    assert line.endswith(
        f"or remove {out / 'seed_1'}; to continue that run: python train.py --resume {latest}"
    )
    assert not (out / "seed_0").exists()
    parser, args = parsed(["--out", str(out), "--seed", "0", "2"], tmp_path)
    assert check_args(parser, args) is None  # seed_1 is not one of these seeds


# --- the hyperparameters: refusals without training -------------------------------------------


def config_refusal(yaml: str, tmp_path: Path) -> str:
    """``hyperparams`` of a run with ``yaml`` as ``--config``: a ConfigError; its message."""
    config = tmp_path / "c.yml"
    config.write_text(yaml)
    parser, args = parsed(["--config", str(config)], tmp_path)
    resume = check_args(parser, args)
    with pytest.raises(ConfigError) as err:
        hyperparams(args, resume)
    return str(err.value)


@pytest.mark.parametrize(
    ("yaml", "message"),
    [
        ("batch_size: 1\n", "batch_size must be >= 2 with normalize_advantage"),
        ("n_envs: 1\nn_steps: 1\n", "n_envs * n_steps must be >= 2 with normalize_advantage"),
        ("learning_rate: lin_inf\n", "learning_rate must be a number or 'lin_<number>', the "),
        ("frame_stack: 65\n", "frame_stack must be in [1, 64]"),
        ("vf_coef: -1.0\n", "vf_coef must be a finite number >= 0, got -1.0"),
        ("sde_sample_freq: -2\n", "sde_sample_freq must be an integer >= -1, got -2"),
        ("critic_state: 'yes'\n", "critic_state must be true or false, got 'yes'"),
        ("n_timesteps: 0\n", "n_timesteps must be a whole number >= 1, got 0"),
        ("n_timesteps: 1.5\n", "n_timesteps must be a whole number >= 1, got 1.5"),
    ],
)
def test_a_bad_config_value_is_refused_by_hyperparams(yaml, message, tmp_path) -> None:
    assert message in config_refusal(yaml, tmp_path)


# --- --resume: a checkpoint's record stood in for -------------------------------------------


@pytest.fixture
def resumed(monkeypatch: pytest.MonkeyPatch) -> dict:
    """The record ``check_args`` reads from any ``--resume`` checkpoint: a 256-step run of seed
    3 of the default entry with a small PPO."""
    import agents.checkpoint

    record = {
        "env_id": DEFAULT_ENTRY, "algo": "ppo", "seed": 3, "num_timesteps": 256,
        "evaluation_config": None,
        "hyperparams": {"n_envs": 8, "n_timesteps": 256, "policy": "MlpPolicy", "n_steps": 32,
                        "batch_size": 128, "n_epochs": 1, "gamma": 0.9, "env_kwargs": {}},
    }
    monkeypatch.setattr(agents.checkpoint, "read_checkpoint", lambda directory: dict(record))
    return record


def test_a_resumed_run_may_write_to_its_own_run_but_not_to_another_holding_its_seed(
    resumed, tmp_path, capsys
) -> None:
    """--resume A/seed_3/checkpoints/latest continues A (its seed_3/ is its own), but --out B
    whose seed_3/ is another run is refused, without the hint to resume B (a --resume is
    given)."""
    own = tmp_path / "A" / "seed_3" / "checkpoints" / "latest"
    own.mkdir(parents=True)
    (own / "resume.json").write_text("{}")
    parser, args = parsed(["--resume", str(own), "--out", str(tmp_path / "A")], tmp_path)
    assert check_args(parser, args) == resumed
    assert args.seed == [3] and args.out == tmp_path / "A"
    other = tmp_path / "B" / "seed_3" / "checkpoints" / "latest"
    other.mkdir(parents=True)
    (other / "resume.json").write_text("{}")
    line = refusal(["--resume", str(own), "--out", str(tmp_path / "B")], tmp_path, capsys)
    assert line.endswith(f"give another --out, or remove {tmp_path / 'B' / 'seed_3'}")


def test_a_resumed_run_is_evaluated_on_the_configuration_it_recorded(resumed, tmp_path) -> None:
    """The --env-config file a run was started with (its recorded evaluation_config) is the
    resumed run's without being given again; a run started without one has none."""
    parser, args = parsed(["--resume", "ckpt"], tmp_path)
    check_args(parser, args)
    assert args.env_overrides == {} and args.env_mixture == []
    resumed["evaluation_config"] = {"sensor": {"sigma_r": 40.0}}
    parser, args = parsed(["--resume", "ckpt"], tmp_path)
    check_args(parser, args)
    assert args.env_overrides == {"sensor": {"sigma_r": 40.0}}


def test_a_resumed_run_is_refused_to_rllib(resumed, tmp_path, capsys) -> None:
    """RLlib writes no checkpoints and reads none: --resume with --engine rllib is a usage error
    (before any question of Ray)."""
    line = refusal(["--resume", "ckpt", "--engine", "rllib"], tmp_path, capsys)
    assert line.endswith("--resume continues SB3 runs; --engine rllib writes no checkpoints")


def test_a_resumed_run_takes_a_larger_budget_only(resumed, tmp_path) -> None:
    """The checkpoint's 256 steps: --timesteps 257 trains on, 256 and the checkpoint's own
    budget are refused naming what gave the budget."""
    def budget(*argv: str) -> int:
        parser, args = parsed(["--resume", "ckpt", *argv], tmp_path)
        return hyperparams(args, check_args(parser, args))["n_timesteps"]

    assert budget("--timesteps", "257") == 257
    with pytest.raises(ConfigError, match=r"^--timesteps 256 is not above the 256 steps the "):
        budget("--timesteps", "256")
    with pytest.raises(ConfigError, match=r"^the budget 256 \(n_timesteps of the checkpoint\) "):
        budget()
    config = tmp_path / "budget.yml"
    config.write_text("n_timesteps: 200\n")
    with pytest.raises(ConfigError, match=r"^the budget 200 \(n_timesteps of --config\) is not"):
        budget("--config", str(config))
    config.write_text("n_timesteps: 512\n")
    assert budget("--config", str(config)) == 512
    config.write_text("gamma: 0.9\n")  # the checkpoint's own: the budget is still the checkpoint's
    with pytest.raises(ConfigError, match=r"^the budget 256 \(n_timesteps of the checkpoint\) "):
        budget("--config", str(config))
    config.write_text("n_timesteps: 512\ngamma: 0.5\n")
    with pytest.raises(ConfigError, match=r"changes \['gamma'\] of the resumed run"):
        budget("--config", str(config))


# --- the hyperparameter entries and their values ---------------------------------------------


def test_an_id_without_an_entry_keeps_the_entrys_features_and_adds_its_presets_after() -> None:
    """TPMAdaptParallel-v0's preset observes bank_b: after the entry's features, once; the
    entry's reward stays, its tracker (sensor) and mixture give way to the preset's."""
    entry = {"n_envs": 8, "env_mixture": [{"env_kwargs": {}, "share": 0.5}],
             "env_kwargs": {"obs_features": ["loglik", "speed"], "reward": "error",
                            "sensor": {"sigma_r": 30.0}}}
    params = on_preset(entry, "imm_gym/TPMAdaptParallel-v0")
    assert params == {"n_envs": 8, "env_kwargs": {
        "obs_features": ["loglik", "speed", "bank_b"], "reward": "error", "scenario": "random",
        "parallel": True, "p_min": 0.05}}
    entry["env_kwargs"]["obs_features"] = ["bank_b", "loglik"]
    features = on_preset(entry, "imm_gym/TPMAdaptParallel-v0")["env_kwargs"]["obs_features"]
    assert features == ["bank_b", "loglik"]


@pytest.mark.parametrize("value", [-1, 0, 4])
def test_sde_sample_freq_takes_minus_one_and_up(value) -> None:
    """-1: gSDE's noise drawn once a rollout (SB3's value for that), 0 or more: every N steps."""
    assert check_hyperparams("f", {"sde_sample_freq": value}, "ppo", complete=False) == {
        "sde_sample_freq": value
    }


@pytest.mark.parametrize("value", [-2, True, 1.5, "4"])
def test_sde_sample_freq_refuses_other_values(value) -> None:
    with pytest.raises(ConfigError, match=r"^f: sde_sample_freq must be an integer >= -1, got "):
        check_hyperparams("f", {"sde_sample_freq": value}, "ppo", complete=False)


def test_critic_state_is_a_flag_for_ppo_only() -> None:
    assert check_hyperparams("f", {"critic_state": True}, "ppo", complete=False)
    with pytest.raises(ConfigError, match=r"^f: critic_state must be true or false, got 1$"):
        check_hyperparams("f", {"critic_state": 1}, "ppo", complete=False)
    with pytest.raises(ConfigError, match=r"^f: critic_state: true needs --algo ppo, got --algo r"):
        check_hyperparams("f", {"critic_state": True}, "recurrent-ppo", complete=False)
    assert check_hyperparams("f", {"critic_state": False}, "recurrent-ppo", complete=False)


def test_an_id_takes_its_own_entry_and_else_the_default_one(tmp_path) -> None:
    """A file with entries for the default id and for TPMAdaptPaper-v0: each id its own, another
    id the default's; a file without the default entry names both missing."""
    small = "n_envs: 8, n_timesteps: 256, policy: MlpPolicy"
    file = tmp_path / "h.yml"
    file.write_text(f"{DEFAULT_ENTRY}: {{{small}}}\nimm_gym/TPMAdaptPaper-v0: {{{small}, "
                    "gamma: 0.5}\n")
    paper = load_hyperparams("imm_gym/TPMAdaptPaper-v0", path=file)
    assert paper == ({"n_envs": 8, "n_timesteps": 256, "policy": "MlpPolicy", "gamma": 0.5},
                     "imm_gym/TPMAdaptPaper-v0")
    assert load_hyperparams("imm_gym/TPMAdaptHetero-v0", path=file)[1] == DEFAULT_ENTRY
    assert "gamma" not in load_hyperparams(DEFAULT_ENTRY, path=file)[0]
    file.write_text(f"imm_gym/TPMAdaptPaper-v0: {{{small}}}\n")
    with pytest.raises(ConfigError, match=f"no entry for 'imm_gym/TPMAdaptHetero-v0' nor "
                                          f"'{DEFAULT_ENTRY}'"):
        load_hyperparams("imm_gym/TPMAdaptHetero-v0", path=file)


@pytest.mark.parametrize("key", ["learning_rate", "clip_range", "clip_range_vf"])
def test_only_lin_and_a_positive_finite_number_is_a_schedule(key) -> None:
    """'lin_' then a number float() reads, above 0 and finite; anything else that starts alike
    would pass the check and fail the run once it is built (algo_kwargs parses value[4:])."""
    for good in ("lin_3e-4", "lin_1", "lin_0.5"):
        assert check_hyperparams("f", {key: good}, "ppo", complete=False) == {key: good}
        assert algo_kwargs({key: good})[key](1.0) == pytest.approx(float(good[4:]))
    for bad in ("lin-3e-4", "linX1", "lin__3", "lin_", "lin_-1", "lin_nan", "lin_0"):
        with pytest.raises(ConfigError, match=rf"^f: {key} must be a "):
            check_hyperparams("f", {key: bad}, "ppo", complete=False)


def test_each_rl_zoo_schedule_string_becomes_a_linear_schedule() -> None:
    """learning_rate, clip_range and clip_range_vf of 'lin_X' each fall from X at the start
    (1.0 of the training left) to 0 at the end: halfway, X / 2; a number stays a number."""
    given = {"learning_rate": "lin_3e-4", "clip_range": "lin_0.2", "clip_range_vf": "lin_10"}
    kwargs = algo_kwargs({**given, "n_envs": 8, "gamma": 0.9})
    assert kwargs.pop("gamma") == 0.9 and "n_envs" not in kwargs
    expected = {"learning_rate": [3e-4, 1.5e-4, 0.0], "clip_range": [0.2, 0.1, 0.0],
                "clip_range_vf": [10.0, 5.0, 0.0]}
    assert sorted(kwargs) == sorted(expected)
    for key, values in expected.items():
        assert [kwargs[key](left) for left in (1.0, 0.5, 0.0)] == pytest.approx(values)
    assert algo_kwargs({"clip_range_vf": 0.5}) == {"clip_range_vf": 0.5}


@pytest.mark.parametrize("key", ["n_envs", "n_timesteps", "policy"])
def test_an_entry_without_its_slots_budget_or_policy_is_refused(key) -> None:
    """An entry must say how many slots, how many steps and which policy; a --config file
    (complete=False) need not."""
    entry = {"n_envs": 8, "n_timesteps": 256, "policy": "MlpPolicy"}
    del entry[key]
    with pytest.raises(ConfigError, match=rf"^f: missing \['{key}'\]$"):
        check_hyperparams("f", entry, "ppo")
    assert check_hyperparams("f", entry, "ppo", complete=False) == entry


@pytest.mark.parametrize("key", ["gamma", "gae_lambda"])
def test_a_discount_of_zero_is_refused_and_one_taken(key) -> None:
    """gamma and gae_lambda in (0, 1]: 0 would weigh no reward beyond the step's own."""
    with pytest.raises(ConfigError, match=rf"^f: {key} must be in \(0, 1\], got 0.0$"):
        check_hyperparams("f", {key: 0.0}, "ppo", complete=False)
    assert check_hyperparams("f", {key: 1e-9}, "ppo", complete=False) == {key: 1e-9}


def test_an_empty_or_comment_only_config_file_changes_nothing(tmp_path) -> None:
    """A --config file with no key (empty, or comments only: YAML's null) is no change, not a
    refusal; the run's hyperparameters are the entry's."""
    from agents.training import read_yaml

    config = tmp_path / "c.yml"
    for text in ("", "# nothing changed yet\n"):
        config.write_text(text)
        assert read_yaml(config) == {}
        parser, args = parsed(["--config", str(config)], tmp_path)
        params = hyperparams(args, check_args(parser, args))
        assert params == load_hyperparams(DEFAULT_ENTRY)[0]


def test_an_algorithm_without_a_hyperparameter_file_is_refused_by_name() -> None:
    with pytest.raises(ConfigError, match=r"^algo must be one of \['ppo', 'recurrent-ppo'\], "):
        load_hyperparams(DEFAULT_ENTRY, "dqn")


@pytest.mark.parametrize("key", ["learning_rate", "clip_range", "clip_range_vf"])
def test_a_rate_of_zero_is_refused_and_a_small_one_taken(key) -> None:
    """A learning rate or clip range of 0 would train nothing: refused, as lin_0 is."""
    for zero in (0, 0.0, -1e-9):
        with pytest.raises(ConfigError, match=rf"^f: {key} must be a positive number or 'lin_"):
            check_hyperparams("f", {key: zero}, "ppo", complete=False)
    assert check_hyperparams("f", {key: 1e-9}, "ppo", complete=False) == {key: 1e-9}


def test_a_config_file_over_an_entry_without_env_kwargs_adds_none() -> None:
    """An entry without env_kwargs (a hand-written one) stays without them under a file that
    gives none, so resuming its run with a --config of only n_timesteps changes nothing else
    (an empty env_kwargs added was refused as a change of the resumed run)."""
    entry = {"n_envs": 8, "gamma": 0.9}
    assert with_config(entry, {"n_timesteps": 512}) == {**entry, "n_timesteps": 512}
    assert with_config(entry, {"env_kwargs": {"reward": "error"}})["env_kwargs"] == {
        "reward": "error"
    }
