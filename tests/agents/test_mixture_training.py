"""Training across trackers end to end: the SB3 adapter over a
:class:`~imm_gym.sim.mixture.MixtureCore`, and ``train.py --env-config A B --env-shares``."""

from __future__ import annotations

import json

import numpy as np
import pytest

import train
from agents.report import admitted_rules
from imm_gym.envs import PRESETS
from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.mixture import AGENT_FIELDS, MixtureCore
from imm_gym.sim.presets import BANK_PRESETS

POLICY = {"action_mode": "stay", "obs_features": ("loglik", "shadow_probs", "stay_bank_evidence"),
          "stay_base": "evidence", "shadow_stay": None}


def test_the_sb3_adapter_trains_on_a_mixture_and_keeps_its_streams() -> None:
    scaled = {"bank": [dict(kind="cv", noise="continuous", intensity=0.12),
                       dict(kind="ct", turn_rate_deg=4.0, noise="continuous", intensity=0.06),
                       dict(kind="ct", turn_rate_deg=-4.0, noise="continuous", intensity=0.06)],
              "vary": {"T": [0.5, 5.0]}}
    env = TPMAdaptSB3VecEnv(
        4, env_id="imm_gym/TPMAdapt-v0", critic_state=True,
        mixture=[{"env_kwargs": {**POLICY, **scaled}, "share": 0.5}], **POLICY,
    )
    assert isinstance(env.core, MixtureCore) and env.core.cores[1].config.vary.active
    env.seed(3)
    obs = env.reset()
    assert obs.shape == (4, env.observation_space.shape[0])
    for _ in range(5):
        env.step_async(np.zeros((4, 3), dtype=np.float32))
        obs, _, _, infos = env.step_wait()
    assert np.all(np.isfinite(obs)) and len(infos) == 4
    streams = env.core.streams()[::-1]  # each slot's pair handed to another slot
    env.core.set_streams(streams)
    assert all(a is b for a, b in zip(env.core.streams(), streams, strict=True))


def test_train_py_records_the_mixture_and_trains_on_it(tmp_path) -> None:
    first, second = tmp_path / "a.yaml", tmp_path / "b.yaml"
    policy = json.dumps({**POLICY, "obs_features": list(POLICY["obs_features"])})
    first.write_text(policy)
    second.write_text(json.dumps({**json.loads(policy), "bank": "cv-ct-continuous",
                                  "sojourn": [60.0, 20.0, 20.0], "vary": {"T": [0.5, 5.0]}}))
    cfg = tmp_path / "small.yml"
    cfg.write_text("n_envs: 8\nn_steps: 32\nbatch_size: 128\nn_epochs: 1\n")
    argv = ["--config", str(cfg), "--out", str(tmp_path / "run"), "--no-progress", "--no-eval",
            "--timesteps", "256", "--env-config", str(first), str(second), "--env-shares", "3", "1"]
    assert train.main(argv) == 0
    run = json.loads((tmp_path / "run" / "seed_0" / "config.json").read_text())
    (part,) = run["hyperparams"]["env_mixture"]
    assert part["share"] == 0.25 and part["env_kwargs"]["sojourn"] == [60.0, 20.0, 20.0]
    assert part["env_kwargs"]["stay_base"] == "evidence"
    env = json.loads((tmp_path / "run" / "seed_0" / "agent" / "env.json").read_text())
    assert "sojourn" not in env and env["stay_base"] == "evidence"  # the first file's


def test_resume_takes_the_files_the_run_was_started_with_and_refuses_others(tmp_path, capsys):
    """--resume with the same two --env-config files continues the run (the recorded parts hold
    the entry's agent settings besides the files' fields); another file, a file fewer or other
    shares are refused before training, naming what differs."""
    files = {}
    for name, speed in (("a", 10.0), ("b", 20.0), ("c", 30.0)):
        files[name] = tmp_path / f"{name}.yaml"
        files[name].write_text(json.dumps({**POLICY, "obs_features": list(POLICY["obs_features"]),
                                           "velocity_std": speed}))
    cfg = tmp_path / "small.yml"
    cfg.write_text("n_envs: 8\nn_steps: 32\nbatch_size: 128\nn_epochs: 1\n")
    common = ["--no-eval", "--no-progress", "--validate-every", "0"]
    argv = ["--config", str(cfg), "--out", str(tmp_path / "run"), "--timesteps", "256", *common]
    assert train.main([*argv, "--env-config", str(files["a"]), str(files["b"])]) == 0
    ckpt = tmp_path / "run" / "seed_0" / "checkpoints" / "latest"
    resume = ["--resume", str(ckpt), "--timesteps", "512", *common]
    for given, shares, message in (
        (["a", "c"], [], f"{files['c']} is not the configuration the run recorded"),
        (["a"], [], "1 file(s) for its 2 configuration(s)"),
        (["a", "b"], ["--env-shares", "3", "1"], "shares [0.25] of the further files, not [0.5]"),
    ):
        with pytest.raises(SystemExit) as exc:
            train.main([*resume, "--env-config", *(str(files[f]) for f in given), *shares])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert "changes the environment of the resumed run" in err and message in err
    assert train.main([*resume, "--env-config", str(files["a"]), str(files["b"])]) == 0
    stats = json.loads((tmp_path / "run" / "seed_0" / "training.json").read_text())
    assert stats["timesteps"] == 512


def _train_and_evaluate(tmp_path, fields: dict) -> dict:
    """``results.json`` of a 256-step ``train.py --env-config`` run on a file of ``fields``,
    evaluated on two runs of each scenario."""
    file = tmp_path / "a.yaml"
    file.write_text(json.dumps(fields))
    cfg = tmp_path / "small.yml"
    cfg.write_text("n_envs: 8\nn_steps: 32\nbatch_size: 128\nn_epochs: 1\n")
    argv = ["--config", str(cfg), "--out", str(tmp_path / "run"), "--no-progress",
            "--timesteps", "256", "--env-config", str(file), "--paper-runs", "2",
            "--random-runs", "2"]
    assert train.main(argv) == 0
    return json.loads((tmp_path / "run" / "seed_0" / "results.json").read_text())


def test_train_py_evaluates_an_agent_of_a_configuration_file_against_every_rule(tmp_path) -> None:
    """The evaluation after training meets the file's tracker and targets; the file's training
    settings (here the evidence's base, which a rule's action mode does not admit) stay the
    agent's. The detector rules are compared where the tracker admits them."""
    results = _train_and_evaluate(
        tmp_path,
        {**POLICY, "obs_features": list(POLICY["obs_features"]), "sensor": {"sigma_r": 50.0},
         "mode_reward": 0.05},
    )
    for scenario in ("paper", "random"):
        assert {"learned", "fixed", "tip-imm", "best-fixed", "turn-rate-prior",
                "learned-prior"} <= set(results[scenario]["policies"])
        d = results[scenario]["vs_learned_prior"]
        assert d["low"] <= d["diff"] <= d["high"]
        learned = results[scenario]["policies"]["learned"]
        assert learned["evaluated_on"]["sensor"]["sigma_r"] == 50.0
    report = (tmp_path / "run" / "seed_0" / "report.md").read_text()
    assert "learned − learned-prior" in report and "learned − turn-rate-prior" in report
    hetero = EnvConfig.build({"scenario": "random", **BANK_PRESETS["hetero"]})
    assert admitted_rules(hetero) == ()


def test_a_file_that_draws_conditions_is_evaluated_on_the_paper_scenario_without_them(
    tmp_path,
) -> None:
    """A file with ``vary`` (the shipped across-trackers files draw the speed, broad.yaml the
    sampling period) is trained and then evaluated: on the randomized family with its drawn
    conditions, on the paper scenario (which refuses them) with its sensor and bank only, the
    results saying what was not applied there. The evaluation refused the file after training
    (exit 2, no results.json)."""
    results = _train_and_evaluate(
        tmp_path, {"sensor": {"sigma_r": 40.0}, "vary": {"speed": [10.0, 30.0]}}
    )
    assert results["paper"]["meta"]["not_applied"] == ["vary"]
    assert "not_applied" not in results["random"]["meta"]
    for scenario in ("paper", "random"):
        learned = results[scenario]["policies"]["learned"]
        assert learned["evaluated_on"]["sensor"]["sigma_r"] == 40.0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--env-shares", "1", "1"], "one weight per --env-config file"),
        (["--env-config", "X", "Y", "--env-shares", "1", "0"], "positive numbers"),
        (["--env-config", "X", "Y", "--env-shares", "1"], "2 file(s)"),
        (["--env-config", "X", "--env-shares", "1"], "got 1 weights for 1 file(s)"),
    ],
)
def test_bad_mixtures_on_the_command_line(extra, message, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        train.main(["--no-eval", *extra])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def _params(*argv: str) -> dict:
    """The run's hyperparameters for ``argv`` (nothing trains: the --out given is never made)."""
    parser = train.build_parser()
    args = parser.parse_args([*argv, "--out", "/nonexistent/out"])
    return train.hyperparams(args, train.check_args(parser, args))


def test_an_env_config_replaces_the_entrys_trackers_and_keeps_what_the_agent_is(tmp_path) -> None:
    """The default entry trains across trackers (its env_kwargs set a tracker, its env_mixture a
    second one); a user's file takes their place: only the entry's AGENT_FIELDS stay."""
    default = _params()
    assert default["env_mixture"] and default["env_kwargs"]["vary"]["T"] == [0.5, 5.0]
    file = tmp_path / "mine.yaml"
    file.write_text("scenario: paper\nsensor: {sigma_r: 30.0}\n")
    params = _params("--env-config", str(file))
    kwargs = params["env_kwargs"]
    assert "env_mixture" not in params
    assert not {"vary", "bank", "sojourn", "family", "velocity_std"} & set(kwargs)
    assert kwargs["scenario"] == "paper" and kwargs["sensor"] == {"sigma_r": 30.0}
    kept = {k: v for k, v in default["env_kwargs"].items() if k in AGENT_FIELDS}
    assert {k: kwargs[k] for k in kept} == kept and kwargs["action_mode"] == "stay"


@pytest.mark.parametrize(
    "env_id", [f"imm_gym/TPMAdapt{name}-v0" for name in ("Paper", "Parallel", "Hetero")]
)
def test_an_id_without_an_entry_trains_on_its_preset(env_id) -> None:
    """--env ID without an entry of its own: the default entry's hyperparameters and what it
    trains the agent as, on ID's preset (not the entry's trackers, targets and mixture, which
    overrode it: TPMAdaptPaper-v0 trained on the random family), the preset's features after the
    entry's; the evaluation runs on the preset's tracker."""
    default = _params()
    parser = train.build_parser()
    args = parser.parse_args(["--env", env_id, "--out", "/nonexistent/out"])
    params = train.hyperparams(args, train.check_args(parser, args))
    assert "env_mixture" not in params
    config = EnvConfig.build({**PRESETS[env_id], **params["env_kwargs"]})
    preset = EnvConfig.build(PRESETS[env_id])
    for field in set(PRESETS[env_id]) - {"obs_features"}:
        assert getattr(config, field) == getattr(preset, field), field
    features = default["env_kwargs"]["obs_features"]
    assert list(config.obs_features) == [
        *features, *(f for f in PRESETS[env_id].get("obs_features", ()) if f not in features)
    ]
    agent = {k: v for k, v in default["env_kwargs"].items() if k in AGENT_FIELDS}
    assert {k: params["env_kwargs"][k] for k in agent if k != "obs_features"} == {
        k: v for k, v in agent.items() if k != "obs_features"
    }
    assert args.env_overrides == json.loads(json.dumps(PRESETS[env_id]))

