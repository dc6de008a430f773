"""A refused value is shown shortened in the message, whichever file or field gave it.

A YAML file of nested aliases is a few hundred bytes whose value, printed whole, is millions of
characters: each message that shows a refused configuration field, hyperparameter or mixture
part must stay short and still name what was refused.
"""

from __future__ import annotations

import re

import pytest

from agents.training import check_hyperparams, read_yaml
from imm_gym.sim.config_file import read_env_config
from imm_gym.validation import ConfigError

#: 6 levels of 10 aliases: 8 million characters printed whole.
BOMB = "[" + ", ".join(
    ["&a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    + [f"&a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 6)]
) + "]"
#: The longest a message may be: the field's name, what it allows and the value shortened.
SHORT = 500


@pytest.mark.parametrize(
    ("field", "message"),
    [("parallel", "parallel must be a bool, got (['lol'"),
     ("detector_weights", "detector_weights must be a file path or None, got (['lol'")],
)
def test_an_env_config_field_of_nested_aliases_is_shown_shortened(field, message, tmp_path):
    path = tmp_path / "tracker.yaml"
    path.write_text(f"{field}: {BOMB}\n")
    with pytest.raises(ConfigError) as err:
        read_env_config(path)
    assert str(err.value).startswith(f"{path}: {message}")
    assert len(str(err.value)) < SHORT


@pytest.mark.parametrize(
    ("yaml", "message"),
    [("env_kwargs: BOMB", "env_kwargs must be a mapping, got [['lol'"),
     ("policy: BOMB", "policy must be one of ['MlpPolicy', 'PerModelPolicy'] for ppo, got [['lol'"),
     ("swa_start: BOMB", "swa_start must be a fraction of the budget in [0, 1), got [['lol'"),
     ("sde_sample_freq: BOMB", "sde_sample_freq must be an integer >= -1, got [['lol'"),
     ("normalize: BOMB", "normalize must be true or false, got [['lol'"),
     ("n_steps: BOMB", "n_steps must be a positive integer, got [['lol'"),
     ("gamma: BOMB", "gamma must be a finite number, got [['lol'"),
     ("policy_kwargs: BOMB", "policy_kwargs must be a mapping"),
     ("policy_kwargs: {log_std_init: BOMB}", "policy_kwargs.log_std_init must be"),
     ("policy_kwargs: {activation_fn: BOMB}", "policy_kwargs.activation_fn must be one of"),
     ("env_mixture: {x: BOMB}", "env_mixture must be a non-empty list of {env_kwargs, share}, "
                                "got {'x': [['lol'"),
     ("env_mixture: [BOMB]", "env_mixture[0] must be a mapping with the keys env_kwargs and "
                             "share, got [['lol'"),
     ("env_mixture: [{env_kwargs: {}, share: BOMB}]",
      "env_mixture[0].share must be a number in (0, 1), got [['lol'")],
)
def test_a_hyperparameter_of_nested_aliases_is_shown_shortened(yaml, message, tmp_path):
    """As ``train.py --config`` reads and checks its file."""
    config = tmp_path / "config.yml"
    config.write_text(yaml.replace("BOMB", BOMB) + "\n")
    with pytest.raises(ConfigError) as err:
        check_hyperparams(str(config), read_yaml(config), "ppo", complete=False)
    assert str(err.value).startswith(f"{config}: {message}")
    assert len(str(err.value)) < SHORT


@pytest.mark.parametrize(
    ("yaml", "message"),
    [("bank: LONG", "bank must be a list of models or one of"),
     ('detector_weights: "\\0LONG"', "detector_weights '\\x00xxx")],
)
def test_a_long_string_in_a_configuration_file_is_shown_shortened(yaml, message, tmp_path):
    path = tmp_path / "tracker.yaml"
    path.write_text(yaml.replace("LONG", "x" * 100_000) + "\n")
    with pytest.raises(ConfigError) as err:
        read_env_config(path)
    assert str(err.value).startswith(f"{path}: {message}")
    assert len(str(err.value)) < SHORT


def test_an_integer_of_more_digits_than_python_reads_is_refused_naming_the_file(tmp_path):
    """Python reads at most ``sys.get_int_max_str_digits()`` (4300) decimal digits: more is a
    ValueError while parsing, which must be the file's error with the integer's line."""
    digits = "1" * 5000
    path = tmp_path / "tracker.yaml"
    path.write_text(f"p_min: 0.01\nsojourn: [1.0, {digits}]\n")
    with pytest.raises(ConfigError) as err:
        read_env_config(path)
    assert str(err.value).startswith(
        f"{path}: not valid YAML (an integer of 5000 digits, more than the 4300 Python reads"
    )
    assert "line 2, column 16" in str(err.value) and len(str(err.value)) < SHORT
    config = tmp_path / "config.yml"
    config.write_text(f"n_timesteps: -{digits}\n")
    message = (f"{config}: not valid YAML (an integer of 5000 digits, more than the 4300 Python "
               "reads at line 1, column 14)")
    with pytest.raises(ConfigError, match=f"^{re.escape(message)}$"):
        read_yaml(config)
