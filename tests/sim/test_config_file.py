"""Configuration files: file -> EnvConfig -> file round trips, bank presets, bad files named."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from imm_gym.scenarios.catalog import SUITE_CONFIGS, SUITES
from imm_gym.scenarios.segments import paper_scenario
from imm_gym.sim.config_file import (
    env_config_dict,
    read_env_config,
    tracker_of,
    write_env_config,
)
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.presets import BANK_PRESETS, CONTINUOUS_BANK
from imm_gym.validation import ConfigError

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

CONFIGS = {
    "default": {},
    "scenario object": {"scenario": paper_scenario(), "sensor": {"sigma_r": 20.0}},
    "continuous bank": {**BANK_PRESETS["cv-ct-continuous"], "initial_stay": 0.9},
    "hetero": BANK_PRESETS["hetero"],
    "agent settings": {"action_mode": "set", "obs_features": ("loglik", "speed"), "p_min": 1e-3},
    "varied conditions": {
        **BANK_PRESETS["cv-ct-continuous"],
        "vary": {"T": (0.5, 5.0), "sigma_r": (10.0, 100.0), "detection_prob": (0.8, 1.0)},
        "sojourn": (60.0, 20.0, 20.0),
    },
}


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
@pytest.mark.parametrize("name", list(CONFIGS))
def test_round_trip_file_config_file(tmp_path, name, suffix) -> None:
    config = EnvConfig.build(CONFIGS[name])
    first = tmp_path / f"a{suffix}"
    write_env_config(config, first)
    again = EnvConfig.build(read_env_config(first))
    assert again == config
    second = tmp_path / f"b{suffix}"
    write_env_config(again, second)
    assert second.read_text() == first.read_text()
    assert env_config_dict(again) == env_config_dict(config)


@pytest.mark.parametrize(
    "path",
    sorted(EXAMPLES.glob("*.yaml"))
    + sorted((EXAMPLES / "probes").glob("*.yaml"))
    + sorted(SUITE_CONFIGS.glob("*.yaml")),
    ids=lambda p: p.name,
)
def test_shipped_examples_are_valid(path) -> None:
    EnvConfig.build(read_env_config(path))


def test_every_suite_scenario_has_its_configuration_file() -> None:
    for names in SUITES.values():
        for name in names:
            assert read_env_config(SUITE_CONFIGS / f"{name}.yaml").get("scenario", "random") == name


def test_a_bank_preset_name_stands_for_its_overrides(tmp_path) -> None:
    file = tmp_path / "c.yaml"
    file.write_text("bank: cv-ct-continuous\ninitial_stay: 0.9\n")
    assert EnvConfig.build(read_env_config(file)).bank == CONTINUOUS_BANK
    file.write_text("bank: hetero\n")
    assert EnvConfig.build(read_env_config(file)) == EnvConfig.build(BANK_PRESETS["hetero"])
    file.write_text("bank: paper\n")
    assert EnvConfig.build(read_env_config(file)) == EnvConfig()
    # the overrides are plain data: a trained agent writes them to env.json
    json.dumps(read_env_config(file))


def test_yaml_floats_with_exponents_are_numbers(tmp_path) -> None:
    file = tmp_path / "c.yaml"
    file.write_text("p_min: 1e-3\ndivergence_cov: 1e8\n")
    config = EnvConfig.build(read_env_config(file))
    assert config.p_min == 0.001 and config.divergence_cov == 1e8


BAD = [
    # (file name, content, words the message must contain)
    ("k.yaml", "sensr: {sigma_r: 10.0}\n", ["k.yaml", "sensr"]),
    ("n.yaml", "sensor: {sigma_rr: 10.0}\n", ["n.yaml", "sigma_rr"]),
    ("s.yaml", 'p_min: "0.01"\n', ["s.yaml", "p_min", "'0.01'"]),
    ("t.json", '{"initial_stay": true}', ["t.json", "initial_stay"]),
    ("l.yaml", "bank: [{kind: cv}, {kind: ct, turn_rate_deg: 3.0, intensity: x}]\n", ["bank[1]"]),
    ("p.yaml", "bank: no-such-bank\n", ["p.yaml", "bank", "cv-ct-continuous"]),
    ("f.yaml", "family: {T: fast}\n", ["f.yaml", "family.T"]),
    ("v.yaml", "vary: {sigma_r: [100.0, 10.0]}\n", ["v.yaml", "vary.sigma_r[1]"]),
    ("o.yaml", "sojourn: [60.0, 20.0]\n", ["o.yaml", "sojourn"]),
    ("m.yaml", "- 1\n- 2\n", ["m.yaml", "mapping"]),
    ("y.yaml", "sensor: {sigma_r: [1\n", ["y.yaml", "YAML"]),
    ("j.json", "{", ["j.json", "JSON"]),
    ("d.json", "[" * 5000 + "]" * 5000, ["d.json", "not valid JSON (nested too deeply)"]),
    ("d.yaml", "a: " + "[" * 5000 + "]" * 5000, ["d.yaml", "not valid YAML (nested too deeply)"]),
    ("c.toml", "p_min = 0.01\n", ["c.toml", ".yaml"]),
]


@pytest.mark.parametrize(("name", "content", "words"), BAD, ids=[b[0] for b in BAD])
def test_bad_files_name_the_key_and_the_file(tmp_path, name, content, words) -> None:
    file = tmp_path / name
    file.write_text(content)
    with pytest.raises(ConfigError) as err:
        read_env_config(file)
    for word in words:
        assert word in str(err.value)


def test_a_missing_file_is_named(tmp_path) -> None:
    with pytest.raises(ConfigError, match=r"nothere\.yaml"):
        read_env_config(tmp_path / "nothere.yaml")


def test_tracker_of_fills_defaults() -> None:
    tracker = tracker_of({"action_mode": "set", "sensor": {"sigma_r": 10.0}})
    assert set(tracker) == {"sensor", "bank", "filter", "initial_stay", "sojourn"}
    assert tracker["sensor"]["sigma_r"] == 10.0 and tracker["filter"] == "ukf"
    assert tracker["initial_stay"] == 0.995 and tracker["sojourn"] is None
    assert tracker["bank"] == env_config_dict(EnvConfig())["bank"]
