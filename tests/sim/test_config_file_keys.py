"""Configuration files: what a bank preset name stands for, which keys win, which keys an
evaluated agent leaves to the evaluated configuration."""

from __future__ import annotations

import json

import pytest

from imm_gym.cli.policies import agent_overrides
from imm_gym.sim.config_file import env_config_dict, read_env_config, write_env_config
from imm_gym.sim.env_config import EnvConfig
from imm_gym.validation import ConfigError


def test_a_filter_given_in_the_file_wins_over_the_presets(tmp_path) -> None:
    file = tmp_path / "h.yaml"
    file.write_text("bank: hetero\n")
    assert read_env_config(file)["filter"] == "ekf"  # the preset's filter
    # the file's filter wins: the heterogeneous bank with the UKF is refused, naming the file
    file.write_text("bank: hetero\nfilter: ukf\n")
    with pytest.raises(ConfigError, match=r"h\.yaml: .*heterogeneous bank .* needs filter 'ekf'"):
        read_env_config(file)


def test_the_paper_preset_stands_for_the_paper_bank_written_out(tmp_path) -> None:
    # 'bank: paper' gives the bank a file listing the paper bank's models gives (an evaluation
    # records either as a bank from the configuration file)
    listed = tmp_path / "listed.json"
    listed.write_text(json.dumps({"bank": env_config_dict(EnvConfig())["bank"]}))
    named = tmp_path / "named.yaml"
    named.write_text("bank: paper\n")
    assert read_env_config(named) == read_env_config(listed)
    assert "bank" in read_env_config(named)


def test_a_yml_file_is_read_as_yaml(tmp_path) -> None:
    file = tmp_path / "c.yml"
    file.write_text("p_min: 1e-2\nsensor: {sigma_r: 20.0}\n")
    config = EnvConfig.build(read_env_config(file))
    assert config.p_min == 0.01 and config.sensor.sigma_r == 20.0


def test_an_evaluated_agent_keeps_only_its_own_settings() -> None:
    # written out: the tracker, the targets (with the first velocity's prior) and how the
    # evaluation runs (divergence cap, engine) are the evaluated configuration's
    recorded = {
        "sensor": {"sigma_r": 20.0},
        "filter": "ekf",
        "initial_stay": 0.9,
        "sojourn": None,
        "scenario": "paper",
        "family": {"min_duration": 5},
        "vary": {},
        "velocity_std": 20.0,
        "divergence_error": 100.0,
        "divergence_cov": 1e6,
        "engine": "numpy",
        "action_mode": "set",
        "p_min": 0.01,
        "obs_features": ("speed",),
    }
    kept, notes = agent_overrides(object(), recorded, EnvConfig())
    assert kept == {"action_mode": "set", "p_min": 0.01, "obs_features": ("speed",)}
    assert notes["trained_on"]["filter"] == "ekf" and notes["evaluated_on"]["filter"] == "ukf"


def test_writing_a_file_of_another_kind_is_refused_naming_it(tmp_path) -> None:
    file = tmp_path / "c.toml"
    with pytest.raises(ConfigError, match=r"c\.toml: a configuration file ends in \.yaml"):
        write_env_config(EnvConfig(), file)
    assert not file.exists()
