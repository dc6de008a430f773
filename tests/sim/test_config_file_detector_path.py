"""A configuration file's relative ``detector_weights`` names one file for every process: it is
read relative to the file's directory and made absolute, so a process in another working
directory (a Ray worker, whose directory is its node's) opens the same network."""

from __future__ import annotations

import shutil

import pytest

from imm_gym import EnvConfig, TrackingCore
from imm_gym.sim.config_file import read_env_config
from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS
from imm_gym.validation import ConfigError

LEARNED = "action_mode: stay\ndetector: learned\ndetector_share: 0.5\n"


@pytest.mark.parametrize("weights", ["mine.safetensors", "../cfg/./mine.safetensors"])
def test_a_relative_network_is_made_absolute_from_the_files_directory(
    tmp_path, monkeypatch, weights
) -> None:
    (tmp_path / "cfg").mkdir()
    (tmp_path / "elsewhere").mkdir()
    shutil.copy(DEFAULT_WEIGHTS, tmp_path / "cfg" / "mine.safetensors")
    (tmp_path / "cfg" / "tracker.yaml").write_text(f"{LEARNED}detector_weights: {weights}\n")
    monkeypatch.chdir(tmp_path)
    overrides = read_env_config("cfg/tracker.yaml")  # a file named relative to this directory
    assert overrides["detector_weights"] == str((tmp_path / "cfg" / "mine.safetensors").resolve())
    monkeypatch.chdir(tmp_path / "elsewhere")  # as a worker started in another directory
    TrackingCore(EnvConfig.build(overrides), n_envs=1)


def test_an_absolute_network_is_kept(tmp_path) -> None:
    file = tmp_path / "tracker.json"
    file.write_text(f'{{"action_mode": "stay", "detector": "learned", "detector_share": 0.5, '
                    f'"detector_weights": "{DEFAULT_WEIGHTS}"}}')
    assert read_env_config(file)["detector_weights"] == str(DEFAULT_WEIGHTS)


def test_a_network_path_with_a_nul_byte_is_refused_naming_the_file_and_key(tmp_path) -> None:
    file = tmp_path / "tracker.yaml"
    file.write_text(f'{LEARNED}detector_weights: "a\\0b"\n')
    with pytest.raises(ConfigError, match=r"tracker\.yaml: detector_weights 'a\\x00b' is not a"):
        read_env_config(file)
