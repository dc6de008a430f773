"""``agents.export``: the target is replaced as a whole only when it holds nothing but what an
export writes, and ``--from-pickle`` writes through the same replacement."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from helpers import shipped_agent

from agents import PRETRAINED
from agents.ensemble import EnsemblePolicy, load_policy
from agents.export import export
from agents.policy import LearnedPolicy
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
