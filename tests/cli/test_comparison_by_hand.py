"""What :func:`imm_gym.cli.comparison.evaluate` records and runs on, checked by hand: the
results' ``meta`` against the roll-outs themselves, and the configuration every policy shares."""

from __future__ import annotations

import pytest

from imm_gym.cli.comparison import evaluate, evaluated_config, load_source
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.validation import ConfigError


def test_meta_records_the_steps_the_seeds_and_the_env_config_it_ran() -> None:
    """``meta.steps`` is the number of steps each run recorded (the roll-out's own, 150 on the
    paper scenario), ``meta.seeds`` runs 4 and 5 for ``seed 4``, 2 runs, and ``meta.env_config``
    the overrides given, as plain data (None without); ``clairvoyant=False`` leaves the row
    out."""
    env = {"sensor": {"sigma_r": 10.0}}
    results, rollouts = evaluate(["fixed"], "paper", 2, 4, clairvoyant=False, env_config=env)
    meta = results["meta"]
    assert meta["steps"] == rollouts["fixed"].truth.shape[1] == 150
    assert (meta["runs"], meta["seed"], meta["seeds"]) == (2, 4, "4..5")
    assert meta["env_config"] == {"sensor": {"sigma_r": 10.0}}
    assert "clairvoyant" not in results
    bare, _ = evaluate(["fixed"], "paper", 1, 0, clairvoyant=False)
    assert bare["meta"]["env_config"] is None and "clairvoyant" not in bare


def test_the_shared_configuration_drops_what_an_agent_is_trained_as_but_its_detector() -> None:
    """Action mode, features and reward are each policy's own and dropped from the shared
    configuration (EnvConfig's defaults there); a detector network it names is kept."""
    given = {
        "detector_weights": str(DEFAULT_WEIGHTS),
        "action_mode": "stay",
        "obs_features": ["mode_probs"],
        "reward": "nis",
    }
    config = evaluated_config("paper", given)
    default = EnvConfig()
    assert config.detector_weights == str(DEFAULT_WEIGHTS)
    assert (config.action_mode, config.obs_features, config.reward) == (
        default.action_mode,
        default.obs_features,
        default.reward,
    )


def test_the_bank_preset_replaces_the_env_config_bank() -> None:
    """``bank``'s preset is applied over ``env_config``: a file's own bank (discrete noise,
    ±3°/s) gives way to ``cv-ct-continuous``'s (continuous noise, ±4°/s)."""
    own = [
        {"kind": "cv"},
        {"kind": "ct", "turn_rate_deg": 3.0},
        {"kind": "ct", "turn_rate_deg": -3.0},
    ]
    config = evaluated_config("paper", {"bank": own}, "cv-ct-continuous")
    preset = EnvConfig.build(BANK_PRESETS["cv-ct-continuous"])
    assert config.bank == preset.bank
    assert [m.turn_rate_deg for m in config.bank] == [0.0, 4.0, -4.0]
    assert {m.noise for m in config.bank} == {"continuous"}


def test_meta_records_the_filter_the_policies_ran() -> None:
    """``meta.filter`` is the configuration's: ``ekf`` where ``env_config`` asks for it."""
    results, _ = evaluate(["fixed"], "paper", 1, 0, clairvoyant=False, env_config={"filter": "ekf"})
    assert results["meta"]["filter"] == "ekf"


def test_an_unknown_bank_preset_is_refused_naming_the_presets() -> None:
    """``bank`` outside the presets is a ConfigError naming them, not a KeyError."""
    with pytest.raises(ConfigError, match=r"--bank must be one of \['paper'.*got 'nope'"):
        evaluate(["fixed"], "paper", 1, 0, bank="nope")


def test_a_scenario_file_giving_a_key_twice_is_refused(tmp_path) -> None:
    """A scenario file that gives ``segments`` twice is refused (JSON would keep the last one
    silently), naming the file and the key."""
    path = tmp_path / "twice.json"
    path.write_text('{"segments": [{"duration": 5}], "segments": [{"duration": 9}]}')
    with pytest.raises(ConfigError, match=r"scenario file .*twice\.json: not valid JSON.*segments"):
        load_source(str(path))


def test_the_paired_differences_name_the_reference_they_are_against() -> None:
    """``--reference tip-imm``: ``paired.reference`` says ``tip-imm`` (not ``fixed``, evaluated
    too), and the differences are the others' minus its ARMSE."""
    results, _ = evaluate(
        ["fixed", "tip-imm"], "paper", 2, 0, reference="tip-imm", clairvoyant=False
    )
    paired = results["paired"]
    assert paired["reference"] == "tip-imm" and set(paired["differences"]) == {"fixed"}
    fixed, tip = (results["policies"][n]["armse_pos"] for n in ("fixed", "tip-imm"))
    assert abs(paired["differences"]["fixed"]["diff"] - (fixed - tip)) < 1e-9
