"""``agents.export``: the target is replaced as a whole only when it holds nothing but what an
export writes, and ``--from-pickle`` writes through the same replacement."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import shipped_agent

from agents import PRETRAINED
from agents.ensemble import EnsemblePolicy, load_policy, member_paths
from agents.export import convert_pickled, export
from agents.export import main as export_main
from agents.policy import AGENT_FILE, NORMALIZER_FILE, LearnedPolicy, load_agent
from imm_gym.validation import ConfigError


@pytest.mark.parametrize("extra", [["resume.json", "resume.safetensors"], ["validation.json"],
                                   ["notes/todo.txt"]])
def test_a_policy_directory_holding_other_files_is_not_replaced(
    tmp_path: Path, extra: list[str]
) -> None:
    """A training checkpoint (an agent's files and its resume files), an agent's validation
    record or a user's files beside a policy: refused naming them, nothing deleted."""
    target = Path(shutil.copytree(shipped_agent(), tmp_path / "run"))
    for name in extra:
        (target / name).parent.mkdir(exist_ok=True)
        (target / name).write_text("mine")
    before = sorted(p for p in target.rglob("*"))
    with pytest.raises(ConfigError) as err:
        export(PRETRAINED, target)
    message = str(err.value)
    assert message.startswith(f"{target}: the export replaces its target")
    assert all(name in message for name in extra) and "\n" not in message
    assert sorted(p for p in target.rglob("*")) == before


def test_an_exported_policy_is_replaced_by_another(tmp_path: Path) -> None:
    target = tmp_path / "shipped"
    export(shipped_agent(), target)
    export(PRETRAINED, target)  # an ensemble over an agent
    assert isinstance(load_policy(target), EnsemblePolicy)
    export(shipped_agent(), target)  # an agent over an ensemble
    assert isinstance(load_policy(target), LearnedPolicy)
    assert not (target / "ensemble.json").exists()


@pytest.fixture
def pickled(tmp_path: Path) -> Path:
    """An agent of the earlier pickled format (``policy.pt``) trained without a normalizer."""
    agent = load_agent(shipped_agent())
    old = tmp_path / "old"
    old.mkdir()
    agent.model.save(str(old / "policy.pt"))
    meta = json.loads((shipped_agent() / AGENT_FILE).read_text())
    meta.pop("policy")
    meta.pop("normalize")
    (old / AGENT_FILE).write_text(json.dumps(meta))
    shutil.copy(shipped_agent() / "env.json", old / "env.json")
    return old


def test_a_pickled_agent_replaces_its_target_whole(pickled: Path, tmp_path: Path) -> None:
    """Converted into an agent with a normalizer, or into an ensemble: nothing of the target
    stays (its vecnormalize.json was used, its ensemble.json loaded in place of the agent)."""
    obs = np.random.default_rng(0).normal(size=(4, load_agent(shipped_agent()).obs_size))
    convert_pickled(pickled, tmp_path / "fresh")
    expected = load_policy(tmp_path / "fresh").predict(obs)[0]
    assert json.loads((tmp_path / "fresh" / AGENT_FILE).read_text())["normalize"] is False
    other = [m for m in member_paths(PRETRAINED) if (m / NORMALIZER_FILE).is_file()][-1]
    for target in (shutil.copytree(other, tmp_path / "stale"),
                   shutil.copytree(PRETRAINED, tmp_path / "ensemble")):
        written = convert_pickled(pickled, Path(target))
        assert sorted(p.name for p in written) == [AGENT_FILE, "env.json", "policy.safetensors"]
        assert sorted(p.name for p in Path(target).iterdir()) == sorted(p.name for p in written)
        converted = load_policy(target)
        assert isinstance(converted, LearnedPolicy)
        np.testing.assert_array_equal(converted.predict(obs)[0], expected)


def test_a_pickled_agent_is_not_converted_into_its_own_directory(pickled: Path) -> None:
    before = (pickled / "policy.pt").read_bytes()
    with pytest.raises(ConfigError, match=r"it holds \['policy\.pt'\]"):
        convert_pickled(pickled, pickled)
    assert (pickled / "policy.pt").read_bytes() == before


def test_from_pickle_needs_a_target(
    pickled: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """No default: the default target of the export is the shipped ensemble (a copy here)."""
    import agents.export

    shipped = Path(shutil.copytree(PRETRAINED, tmp_path / "pretrained"))
    monkeypatch.setattr(agents.export, "PRETRAINED", shipped)
    with pytest.raises(SystemExit) as exc:
        export_main(["--from-pickle", str(pickled)])
    assert exc.value.code == 2
    assert "--from-pickle needs --to NEW_DIR" in capsys.readouterr().err
    assert not (shipped / AGENT_FILE).exists()


def test_a_file_as_the_target_is_refused_and_kept(tmp_path: Path) -> None:
    target = tmp_path / "shipped"
    target.write_text("mine")
    with pytest.raises(ConfigError, match=r"shipped: the export replaces its target, .*not a file"):
        export(shipped_agent(), target)
    assert target.read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shipped"]


def test_a_policy_exported_with_its_detector_is_replaced_by_another(tmp_path: Path) -> None:
    """An agent of the learned detector is exported with the detector's network beside it
    (detector.safetensors); exporting again over it replaces that file too."""
    from agents.export import DETECTOR_FILE
    from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS

    agent = Path(shutil.copytree(shipped_agent(), tmp_path / "agent"))
    env = json.loads((agent / "env.json").read_text())
    env.update(detector="learned", detector_share=0.5, detector_weights=str(DEFAULT_WEIGHTS))
    (agent / "env.json").write_text(json.dumps(env))
    target = tmp_path / "shipped"
    export(agent, target)
    assert (target / DETECTOR_FILE).read_bytes() == DEFAULT_WEIGHTS.read_bytes()
    export(agent, target)
    export(shipped_agent(), target)
    assert not (target / DETECTOR_FILE).exists()


def test_a_directory_of_a_users_files_named_like_an_agents_is_not_replaced(
    tmp_path: Path,
) -> None:
    """Without agent.json a directory is no exported agent: its env.json (a user's
    configuration, say) is not the export's to delete."""
    target = tmp_path / "configs"
    target.mkdir()
    (target / "env.json").write_text("{}")
    with pytest.raises(ConfigError, match=r"it holds \['env\.json'\]"):
        export(shipped_agent(), target)
    assert (target / "env.json").read_text() == "{}"


def test_a_converted_agent_that_does_not_load_replaces_nothing(
    pickled: Path, tmp_path: Path
) -> None:
    """The converted files are loaded before they replace the target: an old agent without
    its env.json converts into no agent, and the target stays."""
    (pickled / "env.json").unlink()
    target = Path(shutil.copytree(shipped_agent(), tmp_path / "target"))
    before = sorted((p.name, p.read_bytes()) for p in target.iterdir())
    with pytest.raises(ConfigError, match=r"env\.json: missing"):
        convert_pickled(pickled, target)
    assert sorted((p.name, p.read_bytes()) for p in target.iterdir()) == before


def test_an_ensembles_members_are_exported_under_their_seeds(tmp_path: Path) -> None:
    """Members of seeds 7 and 3 are copied to seed_7/ and seed_3/, in the order listed."""
    from agents.ensemble import write_ensemble

    members = []
    for seed in (7, 3):
        member = Path(shutil.copytree(shipped_agent(), tmp_path / f"run_{seed}"))
        meta = json.loads((member / AGENT_FILE).read_text())
        (member / AGENT_FILE).write_text(json.dumps({**meta, "seed": seed}))
        members.append(member)
    write_ensemble(tmp_path / "ensemble", members)
    export(tmp_path / "ensemble", tmp_path / "shipped")
    listed = json.loads((tmp_path / "shipped" / "ensemble.json").read_text())["members"]
    assert listed == ["seed_7", "seed_3"]
    assert [m.name for m in member_paths(tmp_path / "shipped")] == ["seed_7", "seed_3"]


def test_the_command_line_reports_the_files_written_and_their_size_in_kib(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``python -m agents.export`` prints how many files it wrote and their total size in KiB
    (units of 1024 bytes), as the directory it wrote holds them."""
    import os

    target = tmp_path / "shipped"
    assert export_main([str(shipped_agent()), "--to", str(target)]) == 0
    sizes = [os.path.getsize(os.path.join(root, name))
             for root, _, names in os.walk(target) for name in names]
    assert len(sizes) >= 3 and sum(sizes) > 20 * 1024  # 1000 and 1024 round apart
    out = capsys.readouterr().out
    assert out == f"exported {len(sizes)} files ({round(sum(sizes) / 1024)} KiB) to {target}\n"


def test_a_pickled_agent_without_its_policy_file_is_named_missing(
    pickled: Path, tmp_path: Path
) -> None:
    (pickled / "policy.pt").unlink()
    with pytest.raises(ConfigError, match=r"policy\.pt: missing"):
        convert_pickled(pickled, tmp_path / "new")
    assert not (tmp_path / "new").exists()


def test_members_without_a_seed_each_are_exported_by_their_position(tmp_path: Path) -> None:
    """A member whose agent.json gives no seed beside one of seed 3: member_0/ and member_1/,
    no seed_None/."""
    from agents.ensemble import write_ensemble

    members = []
    for k, seed in enumerate((None, 3)):
        member = Path(shutil.copytree(shipped_agent(), tmp_path / f"run_{k}"))
        meta = json.loads((member / AGENT_FILE).read_text())
        meta.pop("seed", None)
        if seed is not None:
            meta["seed"] = seed
        (member / AGENT_FILE).write_text(json.dumps(meta))
        members.append(member)
    write_ensemble(tmp_path / "ensemble", members)
    export(tmp_path / "ensemble", tmp_path / "shipped")
    listed = json.loads((tmp_path / "shipped" / "ensemble.json").read_text())["members"]
    assert listed == ["member_0", "member_1"]
