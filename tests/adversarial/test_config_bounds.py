"""Configuration bounds at their edges: a closed end accepts its own value, the next value past
it is refused naming the field and the interval."""

from __future__ import annotations

import pytest

from imm_gym import ConfigError, EnvConfig, MotionModel
from imm_gym.tracking.hetero import SONAR_HETERO_BANK, LinearModel
from imm_gym.validation import SHOWN_CHARS, check_int, shown


def test_an_integer_interval_includes_its_upper_end() -> None:
    # [4, 6] holds 4, 5 and 6 (written out: the documented closed interval)
    assert [check_int("n", n, 4, 6) for n in (4, 5, 6)] == [4, 5, 6]
    with pytest.raises(ConfigError, match=r"n must be an integer in \[4, 6\], got 7"):
        check_int("n", 7, 4, 6)
    # a six-dimensional linear model of the heterogeneous bank sits on that upper end
    assert LinearModel(MotionModel("cv"), dim=6).dim == 6
    with pytest.raises(ConfigError, match=r"model\.dim .* must be an integer in \[4, 6\], got 7"):
        LinearModel(MotionModel("cv"), dim=7)


def test_a_long_refused_value_is_shown_in_at_most_shown_chars_characters() -> None:
    value = ["x" * 100] * 10  # six shortened entries of about 60 characters: far past 200
    text = shown(value)
    assert len(text) == SHOWN_CHARS == 200
    assert text.endswith("...") and text.startswith("['xxx")
    with pytest.raises(ConfigError) as err:
        EnvConfig(filter=value)  # type: ignore[arg-type]
    got = str(err.value).split(", got ", 1)[1]
    assert len(got) == 200


def test_a_refused_value_is_shown_three_levels_deep() -> None:
    # written out: the fourth level of nesting is '...', past the sixth entry too
    assert shown([[[["a"]]]]) == "[[[[...]]]]"
    assert shown(list(range(10))) == "[0, 1, 2, 3, 4, 5, ...]"
    with pytest.raises(ConfigError, match=r"filter must be one of .*, got \[\[\[\[\.\.\.\]\]\]\]$"):
        EnvConfig(filter=[[[["ukf"]]]])  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"initial_stay": 1.5}, r"initial_stay must be in \[0\.0, 1\.0\], got 1\.5"),
        ({"initial_stay": 1.0 + 1e-12}, r"initial_stay must be in \[0\.0, 1\.0\]"),
        ({"initial_stay": (-0.5, 0.9, 0.9)}, r"initial_stay\[0\] must be in \[0\.0, 1\.0\]"),
        ({"initial_stay": (0.9, 0.9, -1e-12)}, r"initial_stay\[2\] must be in \[0\.0, 1\.0\]"),
        ({"sojourn": (0.0, 20.0, 20.0)}, r"sojourn\[0\] must be in \(0\.0, inf\), got 0\.0"),
        ({"sojourn": (60.0, -0.5, 20.0)}, r"sojourn\[1\] must be in \(0\.0, inf\), got -0\.5"),
        ({"stay_base": "evidence"}, r"stay_base 'evidence' needs action_mode 'stay'"),
        ({"stay_base": "uniform", "action_mode": "set"}, r"needs action_mode 'stay', got 'set'"),
        ({"detector_share": 0.5}, r"detector_share > 0 needs action_mode 'stay'.*got 'scale'"),
    ],
)
def test_a_stay_sojourn_or_stay_setting_out_of_its_range_is_refused(
    overrides: dict, message: str
) -> None:
    with pytest.raises(ConfigError, match=message):
        EnvConfig.build(overrides)


def test_stays_and_sojourns_at_their_edges_are_accepted() -> None:
    assert EnvConfig(initial_stay=1.0).initial_stay == 1.0
    assert EnvConfig(initial_stay=(0.0, 1.0, 0.5)).initial_stay == (0.0, 1.0, 0.5)
    assert EnvConfig(action_mode="stay", stay_base="evidence").stay_base == "evidence"


NO_CT = [{"kind": "cv"}, {"kind": "cv", "noise": "continuous", "intensity": 1.0}]


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (
            {"mode_reward": 0.5, "shadow": "none", "reward": "error"},
            r"mode_reward > 0 needs shadow 'fixed'",
        ),
        (
            {"obs_features": ("turn_band",), "bank": NO_CT},
            r"obs_features 'turn_band' needs a linear bank with a CT model",
        ),
        (
            {"family": {"designed_share": 0.5}, "bank": NO_CT},
            r"family\.designed_share needs a linear bank with a CT model",
        ),
        (
            {"bank": dict(SONAR_HETERO_BANK), "filter": "ukf"},
            r"heterogeneous bank \(NCV/CT/CTRA\) needs filter 'ekf'",
        ),
        (
            {"stay_grid": "pairs", "action_mode": "stay"},
            r"stay_grid 'pairs' needs stay_base 'evidence' or 'evidence_best'.*got 'tracker'",
        ),
        (
            {"detector": "turn_rate"},
            r"detector 'turn_rate' places .*detector_share must be in \(0, 1\], got 0",
        ),
    ],
)
def test_a_setting_without_what_it_needs_is_refused_naming_both(
    overrides: dict, message: str
) -> None:
    with pytest.raises(ConfigError, match=message):
        EnvConfig.build(overrides)


def test_the_settings_with_what_they_need_are_accepted() -> None:
    EnvConfig.build({"obs_features": ("turn_band",)})
    EnvConfig.build({"family": {"designed_share": 0.5}})
    EnvConfig.build({"bank": dict(SONAR_HETERO_BANK), "filter": "ekf"})
    EnvConfig.build({"stay_grid": "pairs", "action_mode": "stay", "stay_base": "evidence"})
    EnvConfig.build({"detector": "turn_rate", "detector_share": 0.5, "action_mode": "stay"})


def test_a_config_mapping_updates_the_preset_it_is_built_on() -> None:
    preset = {"scenario": "random", "p_min": 0.05, "parallel": True}
    config = EnvConfig.build({"p_min": 0.01}, preset=preset)
    assert config.p_min == 0.01 and config.parallel is True
    assert EnvConfig.build(None, preset=preset).p_min == 0.05
