"""An ensemble of trained agents acts on the mean of their actions; its file is data, checked."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import shipped_agent
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from agents.ensemble import (
    ENSEMBLE_FILE,
    EnsemblePolicy,
    load_ensemble,
    load_policy,
    write_ensemble,
)
from agents.ensemble import main as ensemble_main
from agents.policy import LearnedPolicy, load_agent
from imm_gym.cli.evaluate import main as evaluate_main
from imm_gym.validation import ConfigError


@pytest.fixture
def members(tmp_path) -> tuple[Path, Path]:
    """An agent of the shipped policy and a copy whose action head's bias is shifted (another
    policy)."""
    agent = shipped_agent()
    other = Path(shutil.copytree(agent, tmp_path / "other"))
    tensors = load_file(str(other / "policy.safetensors"))
    tensors["action_net.bias"] = tensors["action_net.bias"] + 0.3
    save_file(tensors, str(other / "policy.safetensors"))
    return agent, other


def observations(policy: LearnedPolicy, steps: int = 6, n: int = 5) -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    return [rng.normal(size=(n, policy.obs_size)) for _ in range(steps)]


def roll(policy, frames: list[np.ndarray]) -> np.ndarray:
    """The actions over consecutive frames of one episode per row (the state carried)."""
    state, start, out = None, np.ones(len(frames[0]), bool), []
    for obs in frames:
        action, state = policy.predict(obs, state, start)
        start = np.zeros_like(start)
        out.append(action)
    return np.array(out)


def write(directory: Path, data: dict) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / ENSEMBLE_FILE).write_text(json.dumps(data))
    return directory


def test_an_ensemble_of_one_is_its_member(tmp_path) -> None:
    member = load_agent(shipped_agent())
    ensemble = load_policy(write(tmp_path / "e", {
        "format": "imm_gym-ensemble", "members": [str(shipped_agent())],
    }))
    assert isinstance(ensemble, EnsemblePolicy)
    frames = observations(member)
    np.testing.assert_array_equal(roll(ensemble, frames), roll(member, frames))


def test_the_ensemble_acts_on_the_members_mean_action(members, tmp_path) -> None:
    assert ensemble_main([str(tmp_path / "e"), *map(str, members)]) == 0
    data = json.loads((tmp_path / "e" / ENSEMBLE_FILE).read_text())
    assert not any(Path(m).is_absolute() for m in data["members"])  # relative to the ensemble
    ensemble = load_ensemble(tmp_path / "e")
    singles = [load_agent(m) for m in members]
    frames = observations(singles[0])
    each = [roll(p, frames) for p in singles]
    assert not np.allclose(each[0], each[1])  # two policies
    np.testing.assert_allclose(roll(ensemble, frames), (each[0] + each[1]) / 2, rtol=0, atol=1e-7)


def test_the_evaluation_takes_an_ensemble_as_a_policy(members, tmp_path) -> None:
    ensemble_main([str(tmp_path / "e"), *map(str, members)])
    out = tmp_path / "r.json"
    argv = ["--policy", str(tmp_path / "e"), "--policy", "fixed", "--scenario", "paper", "--runs",
            "2", "--quiet", "--no-clairvoyant", "--json", str(out)]
    assert evaluate_main(argv) == 0
    row = json.loads(out.read_text())["policies"][str(tmp_path / "e")]
    assert np.isfinite(row["armse_pos"]) and 0.0 <= row["mode_accuracy"] <= 1.0


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"format": "imm_gym-ensemble", "members": []}, "members must be a non-empty list"),
        ({"format": "other", "members": ["a"]}, "format must be 'imm_gym-ensemble'"),
        ({"format": "imm_gym-ensemble", "members": ["a"], "combine": "vote"},
         "combine must be one of ['mean_action']"),
        ({"format": "imm_gym-ensemble", "members": ["a"], "weights": [1]}, "unknown keys"),
        ({"format": "imm_gym-ensemble", "members": ["nowhere"]},
         "member 'nowhere': no trained agent there"),
        ({"format": "imm_gym-ensemble", "members": ["se\u0000ed"]},
         "member 'se\\x00ed' is not a path (embedded null byte)"),
        ({"format": "imm_gym-ensemble", "members": ["a"]}, "member 'a' is not a path"),
    ],
)
def test_a_malformed_ensemble_is_refused_naming_the_file(data, message, tmp_path) -> None:
    directory = write(tmp_path / "e", data)
    (directory / "a").symlink_to("b")  # a loop of symbolic links
    (directory / "b").symlink_to("a")
    with pytest.raises(ConfigError) as err:
        load_ensemble(directory)
    assert message in str(err.value) and ENSEMBLE_FILE in str(err.value)


def test_an_ensemble_file_nested_too_deeply_is_refused_naming_it(tmp_path) -> None:
    directory = tmp_path / "e"
    directory.mkdir()
    (directory / ENSEMBLE_FILE).write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ConfigError, match=r"ensemble\.json: not valid JSON \(nested too deep"):
        load_policy(directory)


def test_members_must_read_and_write_alike(members, tmp_path) -> None:
    other = members[1]
    env = json.loads((other / "env.json").read_text())
    env["logit_scale"] = 3.0
    (other / "env.json").write_text(json.dumps(env))
    with pytest.raises(ConfigError, match="logit_scale differ"):
        load_policy(write(tmp_path / "e", {
            "format": "imm_gym-ensemble", "members": [str(shipped_agent()), str(other)],
        }))
    twice = {"format": "imm_gym-ensemble", "members": [str(shipped_agent())] * 2}
    with pytest.raises(ConfigError, match="listed twice"):
        load_ensemble(write(tmp_path / "t", twice))


def detector_ensemble(tmp_path: Path, weights: list[str]) -> Path:
    """Two shipped agents acting with the learned detector of ``weights[k]`` (as env.json names
    it), in an ensemble beside the shipped detector's copy ``turn.safetensors``."""
    from agents import PRETRAINED
    from agents.ensemble import member_paths
    from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS

    directory = tmp_path / "e"
    directory.mkdir()
    shutil.copy2(DEFAULT_WEIGHTS, directory / "turn.safetensors")
    for k, source in enumerate(member_paths(PRETRAINED)[:2]):
        member = Path(shutil.copytree(source, directory / f"seed_{k}"))
        env = json.loads((member / "env.json").read_text())
        env.update(detector="learned", detector_share=0.5, detector_weights=weights[k])
        (member / "env.json").write_text(json.dumps(env))
    return write(directory, {"format": "imm_gym-ensemble", "members": ["seed_0", "seed_1"]})


def test_members_of_one_detector_named_relative_load_and_export(tmp_path) -> None:
    """Members that name one detector file (relative to their env.json, through ..) act alike,
    and so do their exported copies, each with the detector beside it."""
    from agents.export import DETECTOR_FILE, export

    source = detector_ensemble(tmp_path, ["../turn.safetensors", "../turn.safetensors"])
    ensemble = load_ensemble(source)
    assert {m.env_overrides["detector_weights"] for m in ensemble.members} == {
        str(source / "turn.safetensors")
    }
    export(source, tmp_path / "shipped")
    exported = load_ensemble(tmp_path / "shipped")
    assert [m.env_overrides["detector_weights"] for m in exported.members] == [
        str(tmp_path / "shipped" / name / DETECTOR_FILE) for name in ("seed_0", "seed_1")
    ]
    frames = observations(exported.members[0])
    np.testing.assert_array_equal(roll(exported, frames), roll(ensemble, frames))


def test_members_of_other_detectors_are_refused(tmp_path) -> None:
    source = detector_ensemble(tmp_path, ["../turn.safetensors", "../other.safetensors"])
    tensors = load_file(source / "turn.safetensors")
    with safe_open(source / "turn.safetensors", "pt") as f:
        metadata = f.metadata()
    tensors["layer0.bias"] = tensors["layer0.bias"] + 0.1
    save_file(tensors, source / "other.safetensors", metadata=metadata)
    with pytest.raises(ConfigError, match="detector_weights differ"):
        load_ensemble(source)


def test_a_failed_export_leaves_nothing_beside_its_target(members, tmp_path, monkeypatch):
    import agents.export

    def refuse(*args: object) -> None:
        raise ConfigError("refused")

    monkeypatch.setattr(agents.export, "write_ensemble", refuse)
    data = {"format": "imm_gym-ensemble", "members": [str(m) for m in members]}
    source = write(tmp_path / "e", data)
    with pytest.raises(ConfigError, match="refused"):
        agents.export.export(source, tmp_path / "shipped")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e", "other"]


def test_members_detectors_are_compared_as_networks_never_read_otherwise(
    tmp_path, monkeypatch
) -> None:
    """Members' detector files were compared by reading them whole, with no check (a member
    naming ``/dev/zero`` read without end): two learned detectors are compared as the networks
    their files load as (one network saved with other notes acts alike), and the file of
    another detector, which it does not read, is not compared."""
    from imm_gym.sim.learned_detector import DetectorNetwork

    def unread(self: Path) -> bytes:
        raise AssertionError(f"{self} read whole")

    source = detector_ensemble(tmp_path, ["../turn.safetensors", "../other.safetensors"])
    network = DetectorNetwork.load(source / "turn.safetensors")
    network.save(source / "other.safetensors", notes={"saved": "again"})
    assert (source / "other.safetensors").read_bytes() != (
        source / "turn.safetensors").read_bytes()
    monkeypatch.setattr(Path, "read_bytes", unread)
    assert len(load_ensemble(source).members) == 2
    members = []
    for weights in ("/dev/zero", "/dev/null"):  # with the shadow detector, unread
        member = load_agent(shipped_agent())
        member.env_overrides = {**member.env_overrides, "detector_weights": weights}
        members.append(member)
    assert len(EnsemblePolicy(members).members) == 2


def test_members_trained_on_other_banks_are_refused(tmp_path) -> None:
    """Members trained on banks of one size but other models (CT ±12 °/s against ±4 °/s)
    combined silently, the ensemble recording member 0's bank as the one it was trained on;
    the shipped ensembles' members share theirs."""
    from agents import PRETRAINED, PRETRAINED_PER_MODEL

    other = Path(shutil.copytree(shipped_agent(), tmp_path / "other"))
    env = json.loads((other / "env.json").read_text())
    for model in env["bank"][1:]:
        model["turn_rate_deg"] = 12.0 if model["turn_rate_deg"] > 0 else -12.0
    (other / "env.json").write_text(json.dumps(env))
    data = {"format": "imm_gym-ensemble", "members": [str(shipped_agent()), str(other)]}
    with pytest.raises(ConfigError, match=r"member 1 \(.*other'\) was trained on another bank "
                                          r"than member 0 .*'turn_rate_deg': 12\.0.* and "
                                          r".*'turn_rate_deg': 4\.0"):
        load_policy(write(tmp_path / "e", data))
    for shipped in (PRETRAINED, PRETRAINED_PER_MODEL):
        assert len(load_ensemble(shipped).members) == 5


def test_a_member_listed_by_its_directory_and_a_file_in_it_is_listed_twice(
    members, tmp_path, capsys
) -> None:
    """``seed_0/agent.json`` is loaded as ``seed_0``: listed beside it, the member got two
    votes."""
    agent, other = members
    data = {"format": "imm_gym-ensemble",
            "members": [str(agent), str(agent / "agent.json"), str(other)]}
    with pytest.raises(ConfigError, match=r"ensemble\.json: a member is listed twice"):
        load_ensemble(write(tmp_path / "e", data))
    with pytest.raises(SystemExit) as exit_:
        ensemble_main([str(tmp_path / "cli"), str(agent), str(agent / "agent.json")])
    assert exit_.value.code == 2
    assert "a member is given twice" in capsys.readouterr().err


def test_write_ensemble_refuses_a_member_given_twice_before_writing(members, tmp_path) -> None:
    """The Python API wrote the file load_ensemble refuses: the CLI alone checked."""
    agent, other = members
    with pytest.raises(ConfigError, match="a member is given twice"):
        write_ensemble(tmp_path / "e", [agent, agent / "agent.json", other])
    assert not (tmp_path / "e").exists()


@pytest.mark.parametrize("policy_file", ["agent.json", "selector.json"])
def test_an_ensemble_is_not_written_into_a_policys_directory(
    members, tmp_path, capsys, policy_file
) -> None:
    """ensemble.json beside agent.json took precedence in load_policy: ``--policy OUT`` then
    evaluated the ensemble in place of the agent."""
    agent, other = members
    out = Path(shutil.copytree(other, tmp_path / "out"))
    if policy_file == "selector.json":
        (out / "agent.json").rename(out / policy_file)
    before = sorted(p.name for p in out.iterdir())
    with pytest.raises(SystemExit) as exit_:
        ensemble_main([str(out), str(agent), str(other)])
    assert exit_.value.code == 2
    assert f"{out}: holds {policy_file}, a policy of its own" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == before


def test_a_failed_ensemble_creates_no_directory(members, tmp_path, capsys) -> None:
    """The members are loaded before the directory is made: a member that is no agent leaves
    nothing behind."""
    agent, _ = members
    with pytest.raises(SystemExit) as exit_:
        ensemble_main([str(tmp_path / "e"), str(agent), str(tmp_path / "missing")])
    assert exit_.value.code == 2
    assert "no trained agent" in capsys.readouterr().err
    assert not (tmp_path / "e").exists()


def test_the_trackers_trained_across_are_listed_once(members, tmp_path) -> None:
    """Two members trained across one tracker: the ensemble lists it once (the evaluation's
    notes name each tracker any member was trained on, not one per member)."""
    member = load_agent(members[0])
    assert len(member.trained_across) == 1
    ensemble = load_policy(write(tmp_path / "e", {
        "format": "imm_gym-ensemble", "members": [str(m) for m in members],
    }))
    assert ensemble.trained_across == member.trained_across


def test_an_ensemble_shares_the_models_only_when_every_member_does() -> None:
    """One member reading the models by position (a network not shared by them) makes the
    ensemble read them by position: the evaluation then notes models that differ."""
    import copy

    from agents import PRETRAINED_PER_MODEL

    shipped = load_policy(PRETRAINED_PER_MODEL)
    member = shipped.members[0] if isinstance(shipped, EnsemblePolicy) else shipped
    assert member.shares_models
    positional = copy.copy(member)
    positional.spec = {**member.spec, "class": "MlpPolicy"}
    assert not positional.shares_models
    assert EnsemblePolicy([member, member]).shares_models
    assert not EnsemblePolicy([member, positional]).shares_models
    assert not EnsemblePolicy([positional, member]).shares_models


def test_an_ensemble_is_loaded_by_its_file_as_by_its_directory(members, tmp_path) -> None:
    """``--policy E/ensemble.json`` names the ensemble of ``E``, as ``E/agent.json`` names an
    agent: the same members, acting alike."""
    directory = write(tmp_path / "e", {
        "format": "imm_gym-ensemble", "members": [str(m) for m in members],
    })
    by_file = load_policy(directory / ENSEMBLE_FILE)
    assert isinstance(by_file, EnsemblePolicy) and len(by_file.members) == 2
    frames = observations(by_file.members[0])
    np.testing.assert_array_equal(roll(by_file, frames), roll(load_policy(directory), frames))


def test_an_ensemble_of_no_member_is_refused() -> None:
    with pytest.raises(ConfigError, match="an ensemble needs at least one member"):
        EnsemblePolicy([], source="mine")


@pytest.mark.parametrize("second", [ENSEMBLE_FILE, "selector.json"])
def test_a_directory_of_two_policies_is_refused_until_one_is_named(
    members, tmp_path, second
) -> None:
    """A directory holding agent.json beside ensemble.json (or selector.json) loaded whichever
    file load_policy tried first, silently; it is refused naming both, and each file named
    loads its own policy."""
    agent, other = members
    out = Path(shutil.copytree(agent, tmp_path / "both"))
    if second == ENSEMBLE_FILE:
        (out / ENSEMBLE_FILE).write_text(json.dumps({
            "format": "imm_gym-ensemble", "members": [str(agent), str(other)],
        }))
    else:
        shutil.copy(out / "agent.json", out / second)
    with pytest.raises(ConfigError, match=rf"both: holds agent.json and {second}, a policy each"):
        load_policy(out)
    assert isinstance(load_policy(out / "agent.json"), LearnedPolicy)
    if second == ENSEMBLE_FILE:
        assert len(load_policy(out / ENSEMBLE_FILE).members) == 2
