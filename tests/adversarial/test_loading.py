"""Loading an agent, a checkpoint or a hyperparameter file runs no code, and a bad file is one
line naming it.

Planted payloads are pickles whose ``__reduce__`` creates a marker file when unpickled (each is
first shown to fire when unpickled the unsafe way): planted as ``policy.pt``, ``model.zip``, the
weights file and the checkpoint's tensors, and as the issue's ``policy_kwargs`` escape, loading
fails with a clear message and the marker never appears. Corrupt or mismatched agents (truncated
weights, bad JSON, unknown keys, sizes the environment does not give, names outside the
allow-lists) are refused by ``agents.policy.load_agent`` and ``python -m imm_gym.evaluate``
alike."""

from __future__ import annotations

import base64
import io
import json
import os
import pickle
import shutil
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import NETWORK_SPECS, SMALL, shipped_agent
from safetensors.torch import load_file, save_file

import train
from agents.policy import load_agent
from imm_gym.cli.evaluate import main as evaluate_main
from imm_gym.validation import ConfigError


class Payload:
    """Unpickling it creates ``marker`` (``open(marker, "w")``): code run by loading."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Callable[..., object], tuple[str, str]]:
        return open, (str(self.marker), "w")


def planted_pickle(file: Path, marker: Path) -> None:
    """``file`` holds a pickled :class:`Payload`; unpickling it creates ``marker`` (checked)."""
    data = pickle.dumps(Payload(marker))
    pickle.loads(data).close()
    assert marker.exists()
    marker.unlink()
    file.write_bytes(data)


def planted_torch(file: Path, marker: Path) -> None:
    """``file`` is a ``torch.save`` of a :class:`Payload` (as SB3's ``policy.pt``); loading it
    with ``weights_only=False`` creates ``marker`` (checked)."""
    buffer = io.BytesIO()
    torch.save(Payload(marker), buffer)
    torch.load(io.BytesIO(buffer.getvalue()), weights_only=False).close()
    assert marker.exists()
    marker.unlink()
    file.write_bytes(buffer.getvalue())


def planted_sb3_zip(file: Path, marker: Path) -> None:
    """``file`` is an SB3 ``model.zip`` whose ``data`` entry holds a serialized
    :class:`Payload`, as SB3 stores its schedules (fires in SB3's loader, checked)."""
    from stable_baselines3.common.save_util import load_from_zip_file

    blob = base64.b64encode(pickle.dumps(Payload(marker))).decode()
    data = {"learning_rate": {":type:": "<class 'function'>", ":serialized:": blob}}
    with zipfile.ZipFile(file, "w") as archive:
        archive.writestr("data", json.dumps(data))
    load_from_zip_file(file, device="cpu")
    assert marker.exists()
    marker.unlink()


@pytest.fixture
def agent(tmp_path) -> Path:
    """A copy of an agent of the shipped policy, to damage."""
    return Path(shutil.copytree(shipped_agent(), tmp_path / "agent"))


def old_format(directory: Path) -> None:
    """``agent.json`` as earlier versions wrote it (no network description)."""
    meta = json.loads((directory / "agent.json").read_text())
    del meta["policy"]
    (directory / "agent.json").write_text(json.dumps(meta))
    (directory / "policy.safetensors").unlink()


def refused_by_evaluate(directory: Path, capsys) -> str:
    """``python -m imm_gym.evaluate --policy DIRECTORY``: a usage error; its message."""
    with pytest.raises(SystemExit) as exc:
        evaluate_main(["--policy", str(directory), "--runs", "2", "--quiet", "--no-clairvoyant"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err.strip().splitlines()[-1]


def test_a_planted_policy_pt_is_not_unpickled(agent, tmp_path, capsys) -> None:
    marker = tmp_path / "ran"
    old_format(agent)
    planted_torch(agent / "policy.pt", marker)
    with pytest.raises(
        ConfigError, match=r"pickled format.*python -m agents\.export --from-pickle"
    ):
        load_agent(agent)
    assert "can run code" in refused_by_evaluate(agent, capsys)
    assert not marker.exists()


def test_a_planted_model_zip_is_not_unpickled(agent, tmp_path, capsys) -> None:
    marker = tmp_path / "ran"
    old_format(agent)
    planted_sb3_zip(agent / "model.zip", marker)
    with pytest.raises(ConfigError, match="pickled format"):
        load_agent(agent / "model.zip")
    assert "pickled format" in refused_by_evaluate(agent / "model.zip", capsys)
    assert not marker.exists()


def test_a_pickle_planted_as_the_weights_file_is_not_unpickled(agent, tmp_path, capsys) -> None:
    marker = tmp_path / "ran"
    planted_pickle(agent / "policy.safetensors", marker)
    with pytest.raises(ConfigError, match=r"policy\.safetensors: not a readable safetensors file"):
        load_agent(agent)
    assert "policy.safetensors" in refused_by_evaluate(agent, capsys)
    planted_torch(agent / "policy.safetensors", marker)
    with pytest.raises(ConfigError, match=r"policy\.safetensors: not a readable safetensors file"):
        load_agent(agent)
    assert not marker.exists()


def test_an_ensemble_of_a_planted_member_runs_no_code(agent, tmp_path, capsys) -> None:
    # the ensemble's file names its members; each loads as an agent does, refusing pickles
    marker = tmp_path / "ran"
    old_format(agent)
    planted_torch(agent / "policy.pt", marker)
    ensemble = tmp_path / "ensemble"
    ensemble.mkdir()
    members = [str(shipped_agent()), str(agent)]
    (ensemble / "ensemble.json").write_text(
        json.dumps({"format": "imm_gym-ensemble", "members": members})
    )
    line = refused_by_evaluate(ensemble, capsys)
    assert "ensemble.json" in line and "pickled format" in line
    assert not marker.exists()


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """checkpoints/latest of a 256-step run."""
    out = tmp_path_factory.mktemp("run")
    (out / "small.yml").write_text(SMALL)
    argv = ["--config", str(out / "small.yml"), "--out", str(out), "--timesteps", "256"]
    assert train.main([*argv, "--no-eval", "--no-progress", "--validate-every", "0"]) == 0
    return out / "seed_0" / "checkpoints" / "latest"


def resume_error(directory: Path, tmp_path: Path, capsys) -> str:
    """``train.py --resume DIRECTORY``: a usage error before training; its message."""
    with pytest.raises(SystemExit) as exc:
        train.main(["--resume", str(directory), "--out", str(tmp_path / "out"), "--no-eval"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and not (tmp_path / "out").exists()
    return err.strip().splitlines()[-1]


@pytest.mark.parametrize("planted", ["resume.safetensors", "policy.safetensors"])
def test_a_pickle_planted_in_a_checkpoint_is_not_unpickled(
    checkpoint, tmp_path, capsys, planted
) -> None:
    marker = tmp_path / "ran"
    directory = Path(shutil.copytree(checkpoint, tmp_path / "latest"))
    planted_pickle(directory / planted, marker)
    assert f"{planted}: not a readable safetensors file" in resume_error(
        directory, tmp_path, capsys
    )
    assert not marker.exists()


def test_an_sb3_checkpoint_is_not_unpickled(checkpoint, tmp_path, capsys) -> None:
    marker = tmp_path / "ran"
    directory = tmp_path / "sb3"
    directory.mkdir()
    planted_sb3_zip(directory / "model.zip", marker)
    message = resume_error(directory, tmp_path, capsys)
    assert "checkpoint of an earlier version (SB3's model.zip" in message
    assert "can run code" in message
    assert not marker.exists()


@pytest.mark.parametrize(
    "policy_kwargs",
    [
        # the escape from the restricted eval namespace
        "\"dict(x=nn.modules.module.torch.os.system('touch {marker}'))\"",
        '\'__import__("os").system("touch {marker}")\'',
    ],
)
def test_policy_kwargs_are_never_evaluated(policy_kwargs, tmp_path, capsys) -> None:
    marker = tmp_path / "ran"
    config = tmp_path / "evil.yml"
    config.write_text(f"policy_kwargs: {policy_kwargs.format(marker=marker)}\n")
    with pytest.raises(SystemExit) as exc:
        train.main(["--config", str(config), "--out", str(tmp_path / "out"), "--no-eval"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"{config}: policy_kwargs must be a mapping" in err
    assert "Python expressions are not evaluated" in err
    assert not marker.exists() and not (tmp_path / "out").exists()


def test_yaml_tags_that_build_objects_are_refused(tmp_path, capsys) -> None:
    marker = tmp_path / "ran"
    config = tmp_path / "evil.yml"
    config.write_text(f'n_envs: !!python/object/apply:os.system ["touch {marker}"]\n')
    with pytest.raises(SystemExit) as exc:
        train.main(["--config", str(config), "--out", str(tmp_path / "out"), "--no-eval"])
    assert exc.value.code == 2
    assert f"{config}: not valid YAML" in capsys.readouterr().err
    assert not marker.exists()


def _json(file: str, **changes: object) -> Callable[[Path], None]:
    def damage(directory: Path) -> None:
        path = directory / file
        data = json.loads(path.read_text())
        for key, value in changes.items():
            if value is None:
                del data[key]
            else:
                data[key] = value
        path.write_text(json.dumps(data))

    return damage


def _policy(**changes: object) -> Callable[[Path], None]:
    def damage(directory: Path) -> None:
        path = directory / "agent.json"
        data = json.loads(path.read_text())
        data["policy"].update(changes)
        path.write_text(json.dumps(data))

    return damage


def _without_activation(directory: Path) -> None:
    """agent.json's network description without its activation (SB3's default is tanh)."""
    path = directory / "agent.json"
    data = json.loads(path.read_text())
    del data["policy"]["activation_fn"]
    path.write_text(json.dumps(data))


def _truncate(directory: Path) -> None:
    file = directory / "policy.safetensors"
    file.write_bytes(file.read_bytes()[: file.stat().st_size // 2])


def _nan_weights(directory: Path) -> None:
    file = directory / "policy.safetensors"
    tensors = load_file(file)
    tensors["action_net.bias"][0] = float("nan")
    save_file(tensors, file)


def _wide_weights(directory: Path) -> None:
    file = directory / "policy.safetensors"
    tensors = load_file(file)
    tensors["action_net.weight"] = torch.zeros(9, 64)
    save_file(tensors, file)


def _actor_index(shift: int) -> Callable[[Path], None]:
    """The asymmetric actor's input index (an integer buffer of the weights file) moved."""

    def damage(directory: Path) -> None:
        file = directory / "policy.safetensors"
        tensors = load_file(file)
        tensors["mlp_extractor.index"] = tensors["mlp_extractor.index"] + shift
        save_file(tensors, file)

    return damage


def _obs_features(directory: Path) -> None:
    _json("env.json", obs_features=["loglik", "innovation"])(directory)


def _float8_weights(directory: Path) -> None:
    file = directory / "policy.safetensors"
    tensors = load_file(file)
    tensors["log_std"] = tensors["log_std"].to(torch.float8_e4m3fn)
    save_file(tensors, file)


def _directory_for(name: str) -> Callable[[Path], None]:
    def damage(directory: Path) -> None:
        (directory / name).unlink()
        (directory / name).mkdir()

    return damage


def _link_to(name: str, target: str) -> Callable[[Path], None]:
    def damage(directory: Path) -> None:
        (directory / name).unlink()
        (directory / name).symlink_to(target)

    return damage


def _fifo_for(name: str) -> Callable[[Path], None]:
    def damage(directory: Path) -> None:
        (directory / name).unlink()
        os.mkfifo(directory / name)

    return damage


def _detector(dtype: torch.dtype) -> Callable[[Path], None]:
    """env.json names a detector file (beside it) whose tensors are of ``dtype``."""
    from safetensors import safe_open

    from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS

    def damage(directory: Path) -> None:
        with safe_open(str(DEFAULT_WEIGHTS), "pt") as f:
            tensors = {k: f.get_tensor(k).to(dtype) for k in f.keys()}
            save_file(tensors, directory / "det.safetensors", metadata=f.metadata())
        _json("env.json", detector="learned", detector_share=0.5,
              detector_weights="det.safetensors")(directory)

    return damage


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (_truncate, "policy.safetensors: not a readable safetensors file"),
        (_nan_weights, "policy.safetensors: tensor 'action_net.bias' holds NaN"),
        (
            _wide_weights,
            r"policy\.safetensors: tensor 'action_net\.weight' is torch\.float32 \(9, 64\)",
        ),
        (_actor_index(1), r"tensor 'mlp_extractor\.index' is not the one the network"),
        (_actor_index(10**6), r"tensor 'mlp_extractor\.index' is not the one the network"),
        (lambda d: (d / "agent.json").write_text("{'algo': "), "agent.json: not valid JSON"),
        (_json("agent.json", env_id=["imm_gym/TPMAdapt-v0"]), "agent.json: env_id must be a str"),
        (_json("agent.json", env_id="imm_gym/Nope-v0"), "agent.json: env_id must be one of"),
        (_json("agent.json", seed="zero"), "agent.json: seed must be an integer >= 0"),
        (_json("agent.json", num_timesteps=-5), "agent.json: num_timesteps must be an integer"),
        (_json("agent.json", swa={"start": "x"}), "agent.json: swa must map swa_start"),
        (_json("vecnormalize.json", count=-1.0), "vecnormalize.json: count must be a positive"),
        (_json("vecnormalize.json", count="many"), "vecnormalize.json: count must be a positive"),
        (lambda d: (d / "env.json").write_text("[1, 2"), "env.json: not valid JSON"),
        (lambda d: (d / "agent.json").write_text("[]"), "agent.json: must hold a JSON object"),
        (_json("agent.json", frame_stak=4), r"agent\.json: unknown keys \['frame_stak'\]"),
        (_json("agent.json", algo="dqn"), "agent.json: algo must be one of"),
        (_json("agent.json", trained_across={"bank": "cv"}), "trained_across must be a list"),
        (
            _json("agent.json", trained_across=[{"filter": "pf"}]),
            "agent.json: trained_across: .*filter",
        ),
        (
            _json("agent.json", trained_across=[{"filtr": "ekf"}]),
            r"agent\.json: trained_across\[0\]: unknown keys \['filtr'\]",
        ),
        (_json("agent.json", frame_stack=2), "critic_dims/frame_stack differ from the agent's"),
        (_json("agent.json", critic_dims=0), r"needs one of \['MlpPolicy', 'PerModelPolicy'\]"),
        (_json("env.json", sigma_r=50.0), r"env\.json: EnvConfig: unknown key\(s\) \['sigma_r'\]"),
        (_json("env.json", p_min="0.01"), "env.json: p_min must be a real number"),
        (
            _obs_features,
            "reads 220 entries and writes 3, but the environment of .*env.json gives 4 frames of",
        ),
        (_json("vecnormalize.json", mean=[0.0] * 54), "vecnormalize.json: mean must be 55"),
        (_json("vecnormalize.json", var=[-1.0] * 55), "vecnormalize.json: var must be >= 0"),
        (_json("vecnormalize.json", epsilon=None), "vecnormalize.json: keys must be"),
        (_policy(activation_fn="os.system"), r"policy.activation_fn must be one of \['tanh'"),
        (_without_activation, r"agent\.json: policy: missing \['activation_fn'\]"),
        (_policy(**{"class": "builtins.eval"}), "policy.class must be one of"),
        (_policy(net_arch={"pi": [64], "vf": [128, 128]}), r"missing \[.*policy_net\.2"),
        (_policy(lstm_hidden_size=64), "unknown keys \\['lstm_hidden_size'\\]"),
        (_policy(observation_size="168"), "policy.observation_size must be a positive integer"),
        (_policy(net_arch={"pi": [10**6], "vf": [128]}), r"net_arch\.pi\[0\] must be at most"),
        (_policy(net_arch={"pi": [8] * 9, "vf": [128]}), "must be a list of at most 8 layer"),
        (_policy(observation_size=10**7), "policy.observation_size must be at most 16384"),
        (_json("agent.json", frame_stack=10**6), r"frame_stack must be an integer in \[1, 64\]"),
        # refused by name, not with a traceback (OverflowError, NotImplementedError, TypeError,
        # RecursionError, IsADirectoryError)
        (_json("env.json", logit_scale=10**400), "env.json: logit_scale must be a real number"),
        (_json("vecnormalize.json", clip_obs=10**400), "clip_obs must be a positive number"),
        (_json("vecnormalize.json", count=10**400), "count must be a positive number"),
        (_json("vecnormalize.json", mean=[10**400] * 55), "vecnormalize.json: mean must be 55"),
        (_float8_weights, r"policy\.safetensors: tensor 'log_std' is torch\.float8_e4m3fn, not"),
        (_detector(torch.bfloat16), r"env\.json: .*det\.safetensors'.*is BF16, not one of"),
        (_detector(torch.float8_e5m2), r"env\.json: .*det\.safetensors'.*is F8_E5M2, not one"),
        (lambda d: (d / "agent.json").write_text("[" * 100_000 + "]" * 100_000),
         r"agent\.json: not valid JSON \(nested too deeply\)"),
        (_directory_for("env.json"), r"env\.json: not a regular file"),
        (_directory_for("vecnormalize.json"), r"vecnormalize\.json: not a regular file"),
        # read without end, or waiting for a writer
        (_link_to("vecnormalize.json", "/dev/zero"), r"vecnormalize\.json: not a regular file"),
        (_fifo_for("env.json"), r"env\.json: not a regular file"),
        (_json("env.json", logit_scale=3.0, padding=" " * (16 * 2**20)),
         r"env\.json: \d+ bytes, more than the 16777216"),
    ],
)
def test_a_corrupt_or_mismatched_agent_is_one_line_naming_the_file(
    agent, capsys, damage, message
) -> None:
    damage(agent)
    with pytest.raises(ConfigError, match=message):
        load_agent(agent)
    line = refused_by_evaluate(agent, capsys)
    assert str(agent) in line


HUGE_LSTM = {
    "class": "MlpLstmPolicy", "observation_size": 64 * 44, "action_size": 3,
    "net_arch": {"pi": [4096] * 8, "vf": [4096] * 8}, "activation_fn": "tanh",
    "lstm_hidden_size": 4096, "n_lstm_layers": 8, "shared_lstm": False,
    "enable_critic_lstm": True,
}


def test_a_description_larger_than_its_weights_file_is_refused_before_it_is_built(
    agent, monkeypatch, capsys
) -> None:
    """A description within every bound of agents.schema (width 4096, 8 layers, 64 frames) may
    describe 2.4 G numbers: with a weights file that holds a few, the loader refuses it without
    building the network (9 GB)."""
    import agents.network

    def build_policy(*args: object) -> None:
        pytest.fail("the network was built")

    monkeypatch.setattr(agents.network, "build_policy", build_policy)
    meta = json.loads((agent / "agent.json").read_text())
    meta.update(algo="recurrent-ppo", frame_stack=64, critic_dims=0, policy=HUGE_LSTM)
    (agent / "agent.json").write_text(json.dumps(meta))
    save_file({"junk": torch.zeros(4)}, agent / "policy.safetensors")
    (agent / "vecnormalize.json").unlink()  # of frames with the critic's entries
    message = r"policy\.safetensors: \d+ bytes, fewer than the 9498329116 of the 2374582279"
    with pytest.raises(ConfigError, match=message):
        load_agent(agent)
    assert str(agent) in refused_by_evaluate(agent, capsys)


@pytest.mark.parametrize("spec", NETWORK_SPECS)
def test_the_size_computed_from_a_description_is_the_built_network_s(spec) -> None:
    from agents.network import build_policy, parameter_count
    from agents.schema import check_spec

    spec = check_spec("test", {"activation_fn": "tanh", **spec})
    built = build_policy(spec, "test").state_dict().values()
    assert parameter_count(spec) == sum(t.numel() for t in built if t.is_floating_point())


def test_an_observation_of_the_wrong_size_is_named(agent) -> None:
    policy = load_agent(agent)
    with pytest.raises(ConfigError, match=f"agent '{agent}' reads observations of 44 entries"):
        policy.predict(np.zeros((2, 30)))


def test_converting_a_file_that_is_no_pickled_agent_is_one_line(agent, tmp_path, capsys) -> None:
    """``agents.export --from-pickle`` on a ``policy.pt`` of another kind: a usage error naming
    the file, not a traceback."""
    from agents.export import main as export_main

    (agent / "policy.pt").write_bytes(b"not a pickle at all")
    with pytest.raises(SystemExit) as exc:
        export_main(["--from-pickle", str(agent), "--to", str(tmp_path / "new")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert f"{agent / 'policy.pt'}: not an agent of the earlier pickled format" in err
