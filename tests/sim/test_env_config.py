"""EnvConfig: validation errors naming the field, equivalent ways to give a config, nested dicts."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import imm_gym
from imm_gym import ConfigError, EnvConfig, MotionModel, RandomFamily, Scenario, Segment, Sonar
from imm_gym.envs import TPMAdaptEnv, TPMAdaptVectorEnv
from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv
from imm_gym.sim.episodes import draw_batch

FOUR_MODELS = [
    {"kind": "cv"},
    {"kind": "ct", "turn_rate_deg": 2.0},
    {"kind": "ct", "turn_rate_deg": -2.0},
    {"kind": "ct", "turn_rate_deg": 5.0},
]

BAD = [
    # (overrides, a word the message must contain)
    ({"bogus": 1}, "bogus"),
    ({"sensor": {"sigma_rr": 1}}, "sigma_rr"),
    ({"family": {"horizont": 10}}, "horizont"),
    ({"bank": [{"kind": "cv", "omega": 1.0}, {"kind": "cv"}]}, "omega"),
    ({"scenario": {"segments": [{"duration": 5}], "speed": 3}}, "speed"),
    ({"p_min": 1.0 / 3.0}, "p_min"),
    ({"p_min": 0.5}, "p_min"),
    ({"p_min": -0.01}, "p_min"),
    ({"p_min": float("nan")}, "p_min"),
    ({"p_min": 0.25, "bank": FOUR_MODELS}, "p_min"),
    ({"reward_scale": -1.0}, "reward_scale"),
    ({"reward_scale": 0.0}, "reward_scale"),
    # its square would underflow to 0: NaN and infinite rewards
    ({"reward_scale": 1e-170}, r"reward_scale must be in \[1e-06, inf\)"),
    ({"reward_scale": 9e-7}, "reward_scale"),
    ({"max_factor": 1.0}, "max_factor"),
    ({"max_factor": 0.5}, "max_factor"),
    ({"max_factor": float("inf")}, "max_factor"),
    ({"logit_scale": 0.0}, "logit_scale"),
    ({"action_mode": "foo"}, "action_mode"),
    ({"obs_features": ("bank_b",)}, "bank_b"),
    ({"obs_features": ("bank_b",)}, "parallel"),
    ({"obs_features": ("tpm", "foo")}, "obs_features"),
    ({"obs_features": ("tpm", "tpm")}, "obs_features"),
    ({"obs_features": ("shadow_probs",), "shadow": "none", "reward": "error"}, "shadow"),
    ({"obs_features": ("turn_magnitude_ema",), "shadow": "none", "reward": "error"}, "shadow"),
    ({"reward": "advantage", "shadow": "none"}, "advantage"),
    ({"reward": "advantage", "shadow": "none"}, "shadow"),
    ({"reward": "squared_advantage", "shadow": "none"}, "squared_advantage"),
    ({"tpm_cost": -0.1}, "tpm_cost"),
    ({"tpm_cost": 0.1, "shadow": "none", "reward": "error"}, "tpm_cost"),
    ({"reward": "regret"}, "reward"),
    ({"shadow": "sometimes"}, "shadow"),
    ({"shadow_stay": 1.5}, "shadow_stay"),
    ({"initial_stay": -0.1}, "initial_stay"),
    ({"filter": "kf"}, "filter"),
    ({"filter": "pf"}, "filter"),
    ({"parallel": "yes"}, "parallel"),
    ({"scenario": "circle"}, "scenario"),
    ({"loglik_clip": 0.0}, "loglik_clip"),
    ({"velocity_std": -5.0}, "velocity_std"),
    ({"divergence_error": 0.0}, "divergence_error"),
    ({"divergence_cov": -1.0}, "divergence_cov"),
    ({"bank": [{"kind": "cv"}]}, "bank"),
    ({"sensor": {"sigma_r": -5.0}}, "sigma_r"),
    ({"sensor": {"detection_prob": 0.0}}, "detection_prob"),
    ({"sensor": {"outlier_prob": 1.5}}, "outlier_prob"),
    ({"family": {"n_segments": (3, 30)}}, "n_segments"),
    ({"family": {"horizon": 0}}, "horizon"),
    ({"scenario": {"segments": [{"duration": 0}]}}, "duration"),
    ({"scenario": {"segments": []}}, "segments"),
    ({"sensor": 50.0}, "sensor"),
]


def _ids(case: tuple[dict, str]) -> str:
    return f"{case[1]}:{sorted(case[0])}"


@pytest.mark.parametrize(("overrides", "word"), BAD, ids=[_ids(c) for c in BAD])
def test_bad_config_raises_config_error_naming_the_field(overrides: dict, word: str) -> None:
    with pytest.raises(ConfigError, match=word):
        EnvConfig.build(overrides)
    with pytest.raises(ConfigError, match=word):
        EnvConfig.build(None, **overrides)


@pytest.mark.parametrize(
    ("overrides", "word"),
    [
        ({"bogus": 1}, "bogus"),
        ({"p_min": 0.34}, "p_min"),
        ({"reward_scale": -2.0}, "reward_scale"),
        ({"max_factor": 1.0}, "max_factor"),
        ({"action_mode": "foo"}, "action_mode"),
        ({"obs_features": ("bank_b",)}, "bank_b"),
        ({"shadow": "none"}, "advantage"),
        ({"sensor": {"sigma_rr": 1}}, "sigma_rr"),
    ],
)
def test_bad_config_through_every_front(overrides: dict, word: str) -> None:
    with pytest.raises(ConfigError, match=word):
        gym.make("imm_gym/TPMAdapt-v0", **overrides)
    with pytest.raises(ConfigError, match=word):
        gym.make("imm_gym/TPMAdapt-v0", config=overrides)
    with pytest.raises(ConfigError, match=word):
        gym.make_vec(
            "imm_gym/TPMAdapt-v0", num_envs=2, vectorization_mode="vector_entry_point", **overrides
        )
    with pytest.raises(ConfigError, match=word):
        TPMAdaptVectorEnv(2, config=overrides)
    with pytest.raises(ConfigError, match=word):
        TPMAdaptSB3VecEnv(2, config=overrides)


def test_config_error_is_a_value_error_exported_at_top_level() -> None:
    assert imm_gym.ConfigError is ConfigError
    assert issubclass(ConfigError, ValueError)
    with pytest.raises(ConfigError, match="config must be an EnvConfig or a mapping"):
        EnvConfig.build(42)  # type: ignore[arg-type]


def test_valid_edges_are_accepted() -> None:
    assert EnvConfig(p_min=0.0).p_min == 0.0
    assert EnvConfig(p_min=0.333).p_min == 0.333  # just below 1/M
    assert EnvConfig(p_min=0.24, bank=tuple(MotionModel(**m) for m in FOUR_MODELS)).p_min == 0.24
    assert EnvConfig(max_factor=1.0 + 1e-9).max_factor > 1.0
    config = EnvConfig(reward="error", shadow="none")
    env = TPMAdaptEnv(config)
    env.reset(seed=0)
    _, reward, *_, info = env.step(np.zeros(9))
    assert "reward_advantage" not in info and reward == info["reward_error"]
    assert "reward_squared_advantage" not in info


KW = {
    "scenario": "paper",
    "parallel": True,
    "p_min": 0.05,
    "obs_features": ("tpm", "bank_b", "time"),
    "action_mode": "set",
    "logit_scale": 3.0,
    "sensor": {"sigma_r": 40.0, "outlier_prob": 0.1},
    "reward": "error",
    "shadow_stay": 0.6,
}


def test_object_dict_and_kwargs_give_equal_configs() -> None:
    obj = EnvConfig(
        scenario="paper",
        parallel=True,
        p_min=0.05,
        obs_features=("tpm", "bank_b", "time"),
        action_mode="set",
        logit_scale=3.0,
        sensor=Sonar(sigma_r=40.0, outlier_prob=0.1),
        reward="error",
        shadow_stay=0.6,
    )
    as_dict = {**KW, "obs_features": list(KW["obs_features"])}  # JSON-like: lists
    configs = [
        EnvConfig.build(obj),
        EnvConfig.build(as_dict),
        EnvConfig.build(None, **KW),
        EnvConfig.build({"scenario": "paper"}, **{k: v for k, v in KW.items() if k != "scenario"}),
        TPMAdaptEnv(config=obj).config,
        TPMAdaptEnv(config=as_dict).config,
        TPMAdaptEnv(**KW).config,
        gym.make(
            "imm_gym/TPMAdaptPaper-v0", **{k: v for k, v in KW.items() if k != "scenario"}
        ).unwrapped.config,
        gym.make("imm_gym/TPMAdapt-v0", config=obj).unwrapped.config,
        TPMAdaptVectorEnv(2, config=as_dict).config,
        TPMAdaptSB3VecEnv(2, config=obj).config,
    ]
    for c in configs:
        assert c == obj
        assert isinstance(c.sensor, Sonar) and isinstance(c.obs_features, tuple)
    assert hash(configs[0]) == hash(configs[1])


def test_build_overrides_fields_of_an_envconfig() -> None:
    base = EnvConfig(scenario="paper", p_min=0.01)
    changed = EnvConfig.build(base, p_min=0.02, parallel=True)
    assert changed.p_min == 0.02 and changed.parallel and changed.scenario == "paper"
    assert base.p_min == 0.01  # frozen original untouched
    with pytest.raises(ConfigError, match="p_min"):
        EnvConfig.build(base, p_min=0.9)
    with pytest.raises(ConfigError, match="max_factor"):
        base.replace(max_factor=1.0)


def test_nested_dicts_for_sensor_family_and_bank() -> None:
    config = EnvConfig.build(
        {
            "sensor": {"sigma_r": 30.0, "sigma_theta_deg": 0.1, "position": [100.0, -50.0]},
            "family": {"horizon": 40, "n_segments": [2, 3], "min_duration": 10, "speed": [5, 6]},
            "bank": [
                {"kind": "cv"},
                {"kind": "ct", "turn_rate_deg": 3.0, "q": [0.05, 0.05, 0.06, 0.06]},
                {"kind": "ct", "turn_rate_deg": -3.0},
            ],
        }
    )
    assert config.sensor == Sonar(sigma_r=30.0, sigma_theta_deg=0.1, position=(100.0, -50.0))
    assert config.family == RandomFamily(
        horizon=40, n_segments=(2, 3), min_duration=10, speed=(5, 6)
    )
    assert config.bank[1] == MotionModel("ct", 3.0, (0.05, 0.05, 0.06, 0.06))
    assert all(isinstance(m, MotionModel) for m in config.bank)
    env = TPMAdaptEnv(config)
    env.reset(seed=3)
    batch = draw_batch(config.family, config.sensor, 1, 3)
    np.testing.assert_array_equal(env.core.z[0], batch.measurements.z[0])
    steps = 0
    truncated = False
    while not truncated:
        _, _, terminated, truncated, info = env.step(np.zeros(9, np.float32))
        assert not terminated
        steps += 1
        np.testing.assert_array_equal(info["true_state"], batch.truth.states[0, steps])
    assert steps == 40


def test_user_scenario_dict_with_segments_list() -> None:
    scenario = {
        "segments": [
            {"duration": 12},
            {"duration": 8, "turn_rate_deg": 2.5},
            {"duration": 5, "accel": 0.5},
        ],
        "position": [2000.0, 3000.0],
        "velocity": [10.0, -5.0],
    }
    env = gym.make("imm_gym/TPMAdapt-v0", scenario=scenario)
    config = env.unwrapped.config
    expected = Scenario(
        segments=(Segment(12), Segment(8, 2.5), Segment(5, accel=0.5)),
        position=(2000.0, 3000.0),
        velocity=(10.0, -5.0),
    )
    assert config.scenario == expected and config.source == expected
    assert EnvConfig(scenario=scenario) == config  # a dict straight into the dataclass works too
    env.reset(seed=8)
    batch = draw_batch(expected, config.sensor, 1, 8)
    true_models = []
    for k in range(1, 26):
        _, _, terminated, truncated, info = env.step(np.zeros(9, np.float32))
        np.testing.assert_array_equal(info["true_state"], batch.truth.states[0, k])
        true_models.append(int(info["true_model"]))
        assert not terminated and truncated == (k == 25)
    # straight -> CV (0); +2.5 deg/s -> the left-turn model (1); acceleration -> no CA model (-1)
    assert true_models == [0] * 12 + [1] * 8 + [-1] * 5
