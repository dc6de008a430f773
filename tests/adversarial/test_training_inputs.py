"""``train.py``'s inputs: every bad hyperparameter, environment id or resume request is a usage
error (status 2) naming the file and the key before any training; hyperparameter YAML is plain
data (``1e-3`` a number, ``policy_kwargs`` structured)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from helpers import SMALL

import train
from agents.checkpoint import read_validation
from agents.training import read_yaml


def usage_error(argv: list[str], tmp_path: Path, capsys) -> str:
    """``train.py ARGV --out TMP/out``: status 2 and nothing written; the message."""
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        train.main([*argv, "--out", str(out), "--no-eval", "--no-progress"])
    assert exc.value.code == 2
    assert not out.exists()
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err.strip().splitlines()[-1]


@pytest.mark.parametrize(
    ("yaml", "message"),
    [
        ("policy_kwargs: 'dict(net_arch=[64])'", "policy_kwargs must be a mapping in YAML"),
        ("policy_kwargs: {activation_fn: selu}", "policy_kwargs.activation_fn must be one of"),
        ("policy_kwargs: {activation_fn: torch.nn.Tanh}", "policy_kwargs.activation_fn"),
        ("policy_kwargs: {net_arch: [64, '64']}", "net_arch[1] must be a positive integer"),
        ("policy_kwargs: {net_arch: {pi: [64]}}", "net_arch must have the keys pi and vf"),
        ("policy_kwargs: {optimizer_class: SGD}", "unknown policy_kwargs ['optimizer_class']"),
        ("policy_kwargs: {lstm_hidden_size: 32}", "unknown policy_kwargs ['lstm_hidden_size']"),
        ("policy_kwargs: {ortho_init: 'no'}", "policy_kwargs.ortho_init must be true or false"),
        ("n_steps: '32'", "n_steps must be a positive integer, got '32'"),
        ("n_envs: true", "n_envs must be a positive integer, got True"),
        ("n_envs: 10001", "n_envs must be in [1, 10000]"),
        ("n_timesteps: 1.5", "n_timesteps must be a whole number >= 1"),
        ("gamma: 1.5", "gamma must be in (0, 1]"),
        ("gae_lambda: '0.9'", "gae_lambda must be a finite number"),
        ("learning_rate: fast", "learning_rate must be a positive number or 'lin_<number>'"),
        ("clip_range: lin_x", "clip_range must be a number or 'lin_<number>'"),
        ("ent_coef: .nan", "ent_coef must be a finite number"),
        ("frame_stack: 65", "frame_stack must be in [1, 64] (the most frames an agent is loaded"),
        ("max_grad_norm: -0.5", "max_grad_norm must be a finite number > 0, got -0.5"),
        ("max_grad_norm: 0", "max_grad_norm must be a finite number > 0, got 0"),
        ("vf_coef: -1.0", "vf_coef must be a finite number >= 0, got -1.0"),
        ("target_kl: -1.0", "target_kl must be a finite number > 0, got -1.0"),
        ("target_kl: 0.0", "target_kl must be a finite number > 0, got 0.0"),
        ("frobnicate: 1", "unknown hyperparameters ['frobnicate']"),
        ("policy: CnnPolicy", "policy must be one of ['MlpPolicy', 'PerModelPolicy'] for ppo"),
        ("env_kwargs: [1, 2]", "env_kwargs must be a mapping"),
        ("env_kwargs: {no_such_field: 1}", "unknown key(s) ['no_such_field']"),
        ("env_kwargs: {p_min: '0.01'}", "p_min must be a real number"),
        ("[1, 2]", "must hold a mapping, got list"),
        ("n_envs: [", "not valid YAML"),
        ("n_envs: " + "[" * 5000 + "]" * 5000, "not valid YAML (nested too deeply)"),
    ],
)
def test_a_bad_hyperparameter_is_a_usage_error_naming_it(yaml, message, tmp_path, capsys) -> None:
    config = tmp_path / "bad.yml"
    config.write_text(yaml + "\n")
    line = usage_error(["--config", str(config)], tmp_path, capsys)
    assert message in line
    if "env_kwargs of" not in line:
        assert str(config) in line


@pytest.mark.parametrize(
    ("key", "value", "allowed"),
    [("max_grad_norm", -0.5, "> 0"), ("max_grad_norm", 0, "> 0"), ("vf_coef", -1.0, ">= 0"),
     ("target_kl", -1.0, "> 0"), ("target_kl", 0.0, "> 0")],
)
def test_the_optimizer_coefficients_are_refused_outside_their_ranges(key, value, allowed):
    """A negative max_grad_norm flips the clipped gradient (PPO climbs its loss), a negative
    vf_coef the critic's; no KL is below 0."""
    from agents.training import check_hyperparams
    from imm_gym.validation import ConfigError

    with pytest.raises(ConfigError, match=f"f: {key} must be a finite number {allowed}"):
        check_hyperparams("f", {key: value}, "ppo", complete=False)


def test_a_frame_stack_no_agent_loads_is_refused_before_training(tmp_path, capsys, monkeypatch):
    """An agent is loaded with at most MAX_FRAMES frames and MAX_INPUT entries: a run that
    stacks more would train its budget, then fail to load its own agent and checkpoints."""
    import agents.training
    from agents.policy import MAX_FRAMES
    from agents.training import check_hyperparams
    from imm_gym.validation import ConfigError

    assert check_hyperparams("f", {"frame_stack": MAX_FRAMES}, "ppo", complete=False)
    with pytest.raises(ConfigError, match=rf"f: frame_stack must be in \[1, {MAX_FRAMES}\]"):
        check_hyperparams("f", {"frame_stack": MAX_FRAMES + 1}, "ppo", complete=False)
    # the default entry's frames: 44 observed entries and 11 of the critic's ground truth
    monkeypatch.setattr(agents.training, "MAX_INPUT", 4 * 55 - 1)
    config = tmp_path / "fs.yml"
    config.write_text("frame_stack: 4\ncritic_state: true\n")
    line = usage_error(["--config", str(config), "--timesteps", "64"], tmp_path, capsys)
    assert "frame_stack must be in [1, 3] for frames of 55 entries (an agent's input is at " in line


@pytest.mark.parametrize(
    ("yaml", "message"),
    [
        ("learning_rate: lin_inf", "learning_rate must be a number or 'lin_<number>', the number"),
        ("clip_range: lin_1e999", "clip_range must be a number or 'lin_<number>', the number"),
        ("policy_kwargs: {log_std_init: 1000.0}", "policy_kwargs.log_std_init must be in [-20, "),
        ("policy_kwargs: {log_std_init: -20.5}", "policy_kwargs.log_std_init must be in [-20, "),
        ("batch_size: 1", "batch_size must be >= 2 with normalize_advantage"),
        ("n_envs: 1\nn_steps: 1", "n_envs * n_steps must be >= 2 with normalize_advantage"),
    ],
)
def test_values_that_would_crash_training_are_refused_before_it(yaml, message, tmp_path, capsys):
    """Each passed the checks, then made the weights NaN or tripped an SB3 assertion with a
    traceback once OUT/seed_0/config.json existed (which refused the rerun)."""
    config = tmp_path / "bad.yml"
    config.write_text(yaml + "\n")
    line = usage_error(["--config", str(config), "--timesteps", "64"], tmp_path, capsys)
    assert message in line


def test_one_sample_batches_are_allowed_without_advantage_normalization() -> None:
    """SB3 needs two samples only to normalize the advantages."""
    from agents.training import check_batches

    check_batches({"n_envs": 1, "n_steps": 1, "batch_size": 1, "normalize_advantage": False})
    check_batches({"n_envs": 2, "n_steps": 1, "batch_size": 2})


def test_the_optimizer_coefficients_take_their_working_ranges() -> None:
    """vf_coef 0 (no critic loss), a small max_grad_norm and target_kl null (no early stop, as
    SB3 allows) are kept; the refusals are in the table above."""
    from agents.training import check_hyperparams

    given = {"vf_coef": 0.0, "max_grad_norm": 1e-3, "target_kl": None}
    assert check_hyperparams("f", given, "ppo", complete=False) == given


def test_yaml_numbers_without_a_dot_are_numbers(tmp_path) -> None:
    """PyYAML (YAML 1.1) reads 1e-3 as the string '1e-3'; these files read it as YAML 1.2 does."""
    file = tmp_path / "h.yml"
    file.write_text("learning_rate: 1e-3\nn_timesteps: 4e6\nenv_kwargs: {p_min: 5E-2}\nx: 1e\n")
    data = read_yaml(file)
    assert data == {
        "learning_rate": 0.001,
        "n_timesteps": 4e6,
        "env_kwargs": {"p_min": 0.05},
        "x": "1e",
    }
    assert isinstance(data["learning_rate"], float)


def test_a_non_imm_gym_id_is_a_usage_error_listing_the_ids(tmp_path, capsys) -> None:
    line = usage_error(["--env", "CartPole-v1"], tmp_path, capsys)
    assert "'CartPole-v1' is not an imm_gym environment; available:" in line
    assert "imm_gym/TPMAdaptPaper-v0" in line


def test_an_id_without_an_entry_trains_with_the_default_entry_and_says_so(tmp_path, capsys) -> None:
    config = tmp_path / "small.yml"
    config.write_text(SMALL)
    argv = ["--env", "imm_gym/TPMAdaptPaper-v0", "--config", str(config), "--timesteps", "256"]
    argv += ["--out", str(tmp_path), "--no-eval", "--no-progress", "--validate-every", "0"]
    assert train.main(argv) == 0
    out = capsys.readouterr().out
    assert (
        "no hyperparameter entry for imm_gym/TPMAdaptPaper-v0: using the imm_gym/TPMAdapt-v0 "
        "entry" in out
    )
    meta = json.loads((tmp_path / "seed_0" / "agent" / "agent.json").read_text())
    assert meta["env_id"] == "imm_gym/TPMAdaptPaper-v0"


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """checkpoints/latest of a 256-step run of seed 3."""
    out = tmp_path_factory.mktemp("run")
    (out / "small.yml").write_text(SMALL)
    argv = ["--config", str(out / "small.yml"), "--out", str(out), "--timesteps", "256"]
    argv += ["--seed", "3", "--no-eval", "--no-progress", "--validate-every", "0"]
    assert train.main(argv) == 0
    return out / "seed_3" / "checkpoints" / "latest"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--seed", "5"], "continues a run started with --seed 3; got --seed 5"),
        (["--seed", "3", "4"], "continues a run started with --seed 3; got --seed 3 4"),
        (["--env", "imm_gym/TPMAdaptPaper-v0"], "started with --env imm_gym/TPMAdapt-v0"),
        (["--algo", "recurrent-ppo"], "started with --algo ppo; got --algo recurrent-ppo"),
    ],
)
def test_resume_refuses_another_seed_env_or_algo(checkpoint, argv, message, tmp_path, capsys):
    line = usage_error(["--resume", str(checkpoint), *argv], tmp_path, capsys)
    assert message in line and "leave" in line


def test_resume_refuses_other_hyperparameters_but_takes_a_new_budget(
    checkpoint, tmp_path, capsys
) -> None:
    config = tmp_path / "other.yml"
    config.write_text(SMALL + "gamma: 0.5\nn_timesteps: 100\n")
    line = usage_error(["--resume", str(checkpoint), "--config", str(config)], tmp_path, capsys)
    assert "changes ['gamma'] of the resumed run" in line
    config.write_text(SMALL + "n_timesteps: 512\n")
    argv = ["--resume", str(checkpoint), "--config", str(config), "--out", str(tmp_path / "r")]
    assert train.main([*argv, "--no-eval", "--no-progress", "--validate-every", "0"]) == 0
    stats = json.loads((tmp_path / "r" / "seed_3" / "training.json").read_text())
    assert stats["timesteps"] >= 512 and stats["trained_this_call"] == 512 - 256


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{", "not valid JSON"),
        ("[" * 5000 + "]" * 5000, "not valid JSON"),
        ("[1]", "must hold an object, got list"),
        ('{"armse_pos": 1.0, "step": 3}', "unknown keys ['step']"),
        ('{"timesteps": 3}', "armse_pos must be null or a finite number >= 0"),
        ('{"armse_pos": "17"}', "armse_pos must be null or a finite number >= 0, got '17'"),
        ('{"armse_pos": 1.0, "timesteps": -1}', "timesteps must be an integer >= 0, got -1"),
        ('{"armse_pos": 1.0, "history": {}}', "history must be a list, got dict"),
        ('{"armse_pos": 1.0, "history": [{"timesteps": 5}]}', "history[0] must be"),
        ('{"armse_pos": null, "history": [{"timesteps": 5, "armse_pos": NaN}]}', "history[0]"),
    ],
)
def test_a_damaged_validation_record_is_refused_naming_it(content, message, tmp_path) -> None:
    from imm_gym.validation import ConfigError

    file = tmp_path / "validation.json"
    file.write_text(content)
    with pytest.raises(ConfigError) as err:
        read_validation(file)
    assert str(err.value).startswith(f"{file}: ") and message in str(err.value)
    assert "\n" not in str(err.value)


def test_a_validation_record_as_training_writes_it_is_read_back(tmp_path) -> None:
    record = {
        "armse_pos": 17.5,
        "timesteps": 1000,
        "history": [{"timesteps": 500, "armse_pos": 18.0}, {"timesteps": 1000, "armse_pos": 17.5}],
    }
    file = tmp_path / "validation.json"
    file.write_text(json.dumps(record, indent=2))
    assert read_validation(file) == record
    file.write_text(json.dumps({"armse_pos": None}))
    assert read_validation(file) == {"armse_pos": None}
