"""Bad inputs to the library get a clear error before any work: one test per kind of input.

Each test feeds one kind of bad input (or, for the kinds the library accepts by design, the
accepted one) and asserts the error type and a message naming the offending field. The command
line's kinds are in ``test_cli_inputs.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from imm_gym import (
    IMM,
    ActionError,
    ConfigError,
    EnvConfig,
    MotionModel,
    PositionSensor,
    RandomFamily,
    Scenario,
    Segment,
    Sonar,
    draw_batch,
    paper_bank,
    paper_scenario,
    stay_tpm,
)
from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv
from imm_gym.envs.tpm_adapt import TPMAdaptEnv
from imm_gym.papers.tuning import TunerConfig
from imm_gym.sim.config_file import read_env_config
from imm_gym.tracking.hetero import HeteroBank, HeteroIMM
from imm_gym.tracking.imm import run
from imm_gym.validation import check_int, check_sequence, load_yaml

#: Every real-valued field of EnvConfig and of its nested configurations, as the path a
#: configuration mapping gives it and the name the error message must carry.
REAL_FIELDS = [
    ("initial_stay",),
    ("p_min",),
    ("max_factor",),
    ("logit_scale",),
    ("shadow_stay",),
    ("reward_scale",),
    ("tpm_cost",),
    ("loglik_clip",),
    ("velocity_std",),
    ("divergence_error",),
    ("divergence_cov",),
    ("sensor", "sigma_r"),
    ("sensor", "sigma_theta_deg"),
    ("sensor", "outlier_prob"),
    ("sensor", "outlier_scale"),
    ("sensor", "detection_prob"),
    ("family", "T"),
]
#: Integer fields of the same kind.
INT_FIELDS = [("family", "horizon"), ("family", "min_duration")]

NOT_A_NUMBER = st.one_of(
    st.booleans(),
    st.text(max_size=12),
    st.floats(allow_nan=False, allow_infinity=False).map(str),  # "0.01", "1e-3"...
    st.none(),
    st.lists(st.floats(0.1, 1.0), min_size=1, max_size=2),
)


def _config(path: tuple[str, ...], value: object) -> dict[str, object]:
    return {path[0]: value} if len(path) == 1 else {path[0]: {path[1]: value}}


def _stored(config: EnvConfig, path: tuple[str, ...]) -> object:
    obj: object = config
    for key in path:
        obj = getattr(obj, key)
    return obj


# --- numbers: types -----------------------------------------------------------------------------


def test_a_number_given_as_a_string_is_rejected_with_the_field_and_range() -> None:
    with pytest.raises(ConfigError, match=r"p_min must be a real number in \[0\.0, 0\.333.*\)"):
        EnvConfig(p_min="0.01")  # type: ignore[arg-type]


def test_a_boolean_is_not_a_number() -> None:
    with pytest.raises(ConfigError, match=r"sensor\.sigma_r must be a real number.*True \(bool\)"):
        Sonar(sigma_r=True)  # type: ignore[arg-type]


@settings(max_examples=150, deadline=None)
@given(path=st.sampled_from(REAL_FIELDS + INT_FIELDS), value=NOT_A_NUMBER)
def test_any_non_number_for_a_numeric_field_is_rejected_naming_it(
    path: tuple[str, ...], value: object
) -> None:
    if value is None and path == ("shadow_stay",):
        return  # shadow_stay=None means "initial_stay": a documented value
    with pytest.raises(ConfigError, match=path[-1]):
        EnvConfig.build(_config(path, value))


@settings(max_examples=100, deadline=None)
@given(path=st.sampled_from(REAL_FIELDS), value=st.sampled_from([1, 0, 2, 7]))
def test_an_accepted_number_is_stored_as_a_float(path: tuple[str, ...], value: int) -> None:
    try:
        config = EnvConfig.build(_config(path, value))
    except ConfigError as err:  # out of this field's range: the message names it
        assert path[-1] in str(err)
        return
    stored = _stored(config, path)
    assert type(stored) is float and stored == value


def test_integral_floats_are_stored_as_ints_and_other_numbers_rejected() -> None:
    s = Segment(duration=50.0)  # type: ignore[arg-type]
    assert type(s.duration) is int and s.duration == 50
    family = RandomFamily(horizon=np.int64(120), n_segments=(2.0, 4))  # type: ignore[arg-type]
    assert type(family.horizon) is int and family.n_segments == (2, 4)
    assert all(type(n) is int for n in family.n_segments)
    for bad in (50.5, "50", True, math.nan, math.inf):
        with pytest.raises(
            ConfigError, match=r"segment\.duration must be an integer in \[1, inf\)"
        ):
            Segment(duration=bad)  # type: ignore[arg-type]


@settings(max_examples=60, deadline=None)
@given(duration=st.integers(1, 10**6), as_float=st.booleans())
def test_a_scenario_with_integral_durations_runs(duration: int, as_float: bool) -> None:
    scenario = Scenario(
        segments=({"duration": float(duration) if as_float else duration},),  # type: ignore[arg-type]
        position=(1, 2),  # type: ignore[arg-type]
    )
    assert scenario.horizon == duration and type(scenario.horizon) is int
    assert all(type(v) is float for v in (*scenario.position, *scenario.velocity, scenario.T))


def test_every_configuration_dataclass_stores_converted_numbers() -> None:
    model = MotionModel("ct", turn_rate_deg=4, q=(1, 1, 1, 1), q_acc=1)  # type: ignore[arg-type]
    assert all(type(v) is float for v in (model.turn_rate_deg, *model.q, model.q_acc))
    sensor = PositionSensor(sigma_pos=np.float32(2), sigma_vel=1, detection_prob=1)
    assert all(
        type(v) is float for v in (sensor.sigma_pos, sensor.sigma_vel, sensor.detection_prob)
    )
    bank = HeteroBank(sigma_ncv=1, sigma_ct=[2, 1], q_scale=[1, 2, 3], initial_probs=[1, 0, 0])
    assert all(
        type(v) is float
        for v in (bank.sigma_ncv, *bank.sigma_ct, *bank.q_scale, *bank.initial_probs)
    )
    tuner = TunerConfig(particles=4.0, generations=np.int32(3), bounds=[-1, 1], a=1)  # type: ignore[arg-type]
    assert type(tuner.particles) is int and type(tuner.generations) is int
    assert tuner.bounds == (-1.0, 1.0) and type(tuner.bounds[0]) is float


def test_yaml_floats_written_without_a_dot_are_floats() -> None:
    """PyYAML's YAML 1.1 reads ``1e-3`` as a string; :func:`load_yaml` reads it as YAML 1.2 does,
    and a number quoted in the file stays a string, which the configuration rejects."""
    data = load_yaml("p_min: 1e-3\nreward_scale: 10\nfamily: {T: 1.}\n")
    assert data == {"p_min": 0.001, "reward_scale": 10, "family": {"T": 1.0}}
    assert EnvConfig.build(data).p_min == 0.001
    with pytest.raises(ConfigError, match=r"p_min must be a real number.*'1e-3' \(str\)"):
        EnvConfig.build(load_yaml("p_min: '1e-3'"))


def test_yaml_integers_and_booleans_are_yaml_12s() -> None:
    """YAML 1.1's octal ``010``, base-60 ``2:30`` and ``on``/``yes`` booleans are not read as
    numbers or booleans: ``010`` is ten, the others strings a typed field refuses by name."""
    data = load_yaml("a: 010\nb: 0150\nc: 2:30\nd: on\ne: yes\nf: true\ng: 0x1f\nh: -4\n")
    assert data == {"a": 10, "b": 150, "c": "2:30", "d": "on", "e": "yes", "f": True, "g": 31,
                    "h": -4}
    with pytest.raises(ConfigError, match="velocity_std must be a real number"):
        EnvConfig.build(load_yaml("velocity_std: 2:30"))
    with pytest.raises(ConfigError, match="parallel"):
        EnvConfig.build(load_yaml("parallel: on"))


@pytest.mark.parametrize(
    ("suffix", "text"),
    [(".yaml", "p_min: 0.01\ninitial_stay: 0.9\np_min: 0.2\n"),
     (".json", '{"p_min": 0.01, "initial_stay": 0.9, "p_min": 0.2}'),
     (".yaml", "sensor:\n  sigma_r: 20.0\n  sigma_r: 30.0\n")],
)
def test_a_key_given_twice_is_refused_naming_the_file(tmp_path, suffix: str, text: str) -> None:
    path = tmp_path / f"tracker{suffix}"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"tracker\.(yaml|json): not valid .*given twice"):
        read_env_config(path)


def test_yaml_merge_keys_may_be_overridden() -> None:
    assert load_yaml("x: &a {p: 1, q: 2}\ny:\n  <<: *a\n  q: 3\n")["y"] == {"p": 1, "q": 3}


def test_a_value_of_nested_yaml_aliases_is_shown_shortened(tmp_path) -> None:
    # a few hundred bytes whose value, printed whole, is 8 million characters (6 levels of 10)
    nested = ["&a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    nested += [f"&a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 6)]
    path = tmp_path / "tracker.yaml"
    path.write_text(f"p_min: [{', '.join(nested)}]\n")
    with pytest.raises(ConfigError) as err:
        read_env_config(path)
    message = str(err.value)
    assert message.startswith(f"{path}: p_min must be a real number in [0.0, 0.333")
    assert "got (['lol', 'lol'" in message and len(message) < 400


def test_an_integer_too_long_to_print_is_refused_naming_the_field() -> None:
    expected = r"horizon must be an integer in \[1, 10\], got an integer of 16610 bits"
    with pytest.raises(ConfigError, match=expected):
        check_int("horizon", 10**5000, 1, 10)
    with pytest.raises(ConfigError, match=r"p_min must be .*beyond the floats \(16610 bits\)"):
        EnvConfig(p_min=10**5000)
    # nested in a refused list too (repr raised ValueError, then the list had no bit_length)
    nested = r"x must have 3 entries, got 2: \[1, an integer of 16610 bits\]$"
    with pytest.raises(ConfigError, match=nested):
        check_sequence("x", [1, 10**5000], 3)


# --- configuration structure --------------------------------------------------------------------


def test_an_unknown_key_is_rejected_with_the_allowed_keys() -> None:
    with pytest.raises(ConfigError, match=r"EnvConfig: unknown key\(s\) \['p_mni'\]"):
        EnvConfig.build({"p_mni": 0.01})
    # the same keyword on an EnvConfig (not a TypeError)
    with pytest.raises(ConfigError, match=r"EnvConfig: unknown key\(s\) \['p_mni'\]"):
        EnvConfig.build(EnvConfig(), p_mni=0.01)
    with pytest.raises(ConfigError, match=r"EnvConfig: unknown key\(s\) \['p_mni'\]"):
        EnvConfig().replace(p_mni=0.01)


def test_an_unknown_nested_key_names_its_parent() -> None:
    with pytest.raises(ConfigError, match=r"sensor: unknown key\(s\) \['sigma'\]"):
        EnvConfig.build({"sensor": {"sigma": 3.0}})


def test_a_missing_required_key_is_named() -> None:
    with pytest.raises(ConfigError, match=r"scenario: missing key\(s\) \['segments'\]"):
        EnvConfig.build({"scenario": {"position": [0, 0]}})


def test_a_string_where_a_list_is_expected_is_rejected() -> None:
    with pytest.raises(ConfigError, match=r"obs_features must be a list, got 'tpm'"):
        EnvConfig(obs_features="tpm")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"scenario\.position must be a list"):
        Scenario(segments=(Segment(5),), position=5)  # type: ignore[arg-type]


def test_a_list_of_the_wrong_length_is_rejected() -> None:
    with pytest.raises(ConfigError, match=r"sensor\.position must have 2 entries, got 3"):
        Sonar(position=(1.0, 2.0, 3.0))  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"model\.q \(a 'cv' model\) must have 4 entries"):
        MotionModel("cv", q=(1.0, 1.0))


def test_an_out_of_range_value_names_the_interval() -> None:
    with pytest.raises(ConfigError, match=r"p_min must be in \[0\.0, 0\.333.*\), got 0\.5"):
        EnvConfig(p_min=0.5)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_a_non_finite_configuration_value_is_rejected(value: float) -> None:
    with pytest.raises(ConfigError, match=r"sensor\.sigma_r must be in \(0\.0, 1000000000\.0\]"):
        Sonar(sigma_r=value)


def test_an_unknown_choice_lists_the_choices() -> None:
    choices = r"\['ukf', 'ukf-cholesky', 'ekf'\]"
    with pytest.raises(ConfigError, match=rf"filter must be one of {choices}, got 'pf'"):
        EnvConfig(filter="pf")


def test_a_bad_segment_in_a_scenario_mapping_names_its_index() -> None:
    segments = [{"duration": 10}, {"duration": "x"}]
    with pytest.raises(ConfigError, match=r"scenario\.segments\[1\]: segment\.duration"):
        EnvConfig.build({"scenario": {"segments": segments}})
    with pytest.raises(ConfigError, match=r"scenario\.segments\[0\]: unknown key\(s\) \['turn'\]"):
        Scenario(segments=({"duration": 10, "turn": 1.0},))  # type: ignore[arg-type]


# --- the tracker ---------------------------------------------------------------------------------


@pytest.mark.parametrize("T", [0.0, -1.0, math.nan, math.inf, "1", True])
def test_a_bad_sampling_period_is_rejected_by_both_trackers(T: object) -> None:
    with pytest.raises(ConfigError, match=r"^T must be"):
        IMM(paper_bank(), Sonar(), T=T)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"^T must be"):
        HeteroIMM(HeteroBank(), Sonar(), T=T)  # type: ignore[arg-type]


def _recorded(sensor: object, runs: int = 3) -> tuple[np.ndarray, np.ndarray, object]:
    """Measurements at steps 1..K with about one missed detection in three."""
    family = RandomFamily(horizon=40, n_segments=(2, 3))
    batch = draw_batch(family, sensor, runs, seed=5)
    det = np.random.default_rng(0).random((runs, 40)) < 0.7
    return batch.measurements.z[:, 1:], det, batch


@pytest.mark.parametrize(
    "sensor", [Sonar(), PositionSensor(sigma_pos=20.0, sigma_vel=2.0)], ids=["sonar", "position"]
)
def test_a_nan_measurement_of_a_missed_detection_is_accepted(sensor, make_imm) -> None:
    """The filters ignore a missed detection's measurement, so NaN there gives the outputs of
    any finite value there: through ``run``, ``IMM.run`` and ``IMM.step``, on both engines."""
    z, det, batch = _recorded(sensor)
    z_nan = np.where(det[..., None], z, np.nan)
    imm = make_imm(paper_bank(), sensor)
    tpm = stay_tpm(3, 0.95)
    want = run(imm, z, tpm, batch.x0, batch.P0, detected=det)
    for got in (
        run(imm, z_nan, tpm, batch.x0, batch.P0, detected=det),
        imm.run(z_nan, tpm, batch.x0, batch.P0, detected=det),
    ):
        np.testing.assert_array_equal(got.x, want.x)
        np.testing.assert_array_equal(got.nis, want.nis)
        np.testing.assert_array_equal(got.mode_probs, want.mode_probs)
    state = imm.init(batch.x0, batch.P0)
    missed = ~det[:, 0]
    assert missed.any()
    _, out = imm.step(state, tpm, z_nan[:, 0], det[:, 0])
    _, ref = imm.step(state, tpm, z[:, 0], det[:, 0])
    np.testing.assert_array_equal(out.x, ref.x)
    assert np.all(np.isfinite(out.x))


def test_a_nan_measurement_of_a_missed_detection_is_accepted_by_the_hetero_bank() -> None:
    sensor = PositionSensor(sigma_pos=1.0, sigma_vel=0.5)
    z, det, batch = _recorded(sensor)
    imm = HeteroIMM(HeteroBank(), sensor, T=1.0)
    tpm = stay_tpm(3, 0.95)
    want = imm.run(z, tpm, batch.x0, batch.P0, detected=det)
    got = imm.run(np.where(det[..., None], z, np.nan), tpm, batch.x0, batch.P0, detected=det)
    np.testing.assert_array_equal(got.x, want.x)
    np.testing.assert_array_equal(got.nis, want.nis)


def test_a_nan_measurement_marked_detected_is_rejected(make_imm) -> None:
    z, det, batch = _recorded(Sonar())
    imm = make_imm(paper_bank(), Sonar())
    k = int(np.flatnonzero(det[0])[0])
    z[0, k, 1] = np.nan
    with pytest.raises(ConfigError, match=r"z must be finite where detected"):
        imm.run(z, stay_tpm(3, 0.95), batch.x0, batch.P0, detected=det)
    with pytest.raises(ConfigError, match=r"z must be finite where detected"):
        imm.run(z, stay_tpm(3, 0.95), batch.x0, batch.P0)  # no flags: every one is used


def test_measurements_of_the_wrong_shape_are_rejected(make_imm) -> None:
    imm = make_imm(paper_bank(), Sonar())
    with pytest.raises(ConfigError, match=r"z must have shape \(K, m\) or \(N, K, m\) with m = 2"):
        imm.run(np.zeros((10, 3)), stay_tpm(3, 0.9), np.zeros(4), np.eye(4))


def test_a_tpm_whose_rows_do_not_sum_to_one_is_rejected(make_imm) -> None:
    imm = make_imm(paper_bank(), Sonar())
    with pytest.raises(ConfigError, match=r"tpm rows must sum to 1"):
        imm.run(np.ones((5, 2)), np.full((3, 3), 0.3), np.zeros(4), np.eye(4))


def test_a_covariance_that_is_not_positive_definite_is_rejected(make_imm) -> None:
    imm = make_imm(paper_bank(), Sonar())
    with pytest.raises(ConfigError, match=r"P0 must be positive definite"):
        imm.init(np.zeros(4), -np.eye(4))


def test_bad_tpm_constructor_arguments_are_rejected() -> None:
    with pytest.raises(ConfigError, match=r"n_models must be an integer"):
        stay_tpm("3", 0.9)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"stay must be a real number in \[0\.0, 1\.0\]"):
        stay_tpm(3, "0.9")  # type: ignore[arg-type]


# --- actions ------------------------------------------------------------------------------------


def test_the_sb3_adapter_rejects_a_transposed_action_batch() -> None:
    """(9, 3) actions for 3 envs of 9 entries used to be reshaped into (3, 9) silently."""
    venv = TPMAdaptSB3VecEnv(num_envs=3, config=EnvConfig(scenario="paper"))
    venv.reset()
    good = np.zeros((3, 9), dtype=np.float32)
    for bad in (good.T, good.ravel(), good[:2]):
        with pytest.raises(ActionError, match=r"actions must have shape \(3, 9\), got"):
            venv.step(bad)
    with pytest.raises(ActionError, match=r"action must be finite"):
        venv.step(np.full((3, 9), np.nan, dtype=np.float32))
    obs, *_ = venv.step(good)  # the rejected actions consumed nothing
    assert obs.shape[0] == 3


def test_the_gymnasium_env_rejects_a_wrong_shaped_or_nan_action() -> None:
    env = TPMAdaptEnv(EnvConfig(scenario="paper"))
    env.reset(seed=0)
    with pytest.raises(ActionError, match=r"action must have shape \(9,\), got \(3, 3\)"):
        env.step(np.zeros((3, 3), dtype=np.float32))
    with pytest.raises(ActionError, match=r"action must be finite"):
        env.step(np.full(9, np.inf, dtype=np.float32))


def test_a_paper_scenario_given_with_integers_reproduces_the_float_one() -> None:
    """Validated numbers are the numbers: integer entries give the float scenario's truth."""
    ints = Scenario(
        segments=tuple(
            {"duration": s.duration, "turn_rate_deg": s.turn_rate_deg}
            for s in paper_scenario().segments
        ),  # type: ignore[arg-type]
        position=(3000, 4500),  # type: ignore[arg-type]
        velocity=(20, 15),  # type: ignore[arg-type]
        T=1,
    )
    assert ints == paper_scenario()
    a = draw_batch(ints, Sonar(), 2, 0)
    b = draw_batch(paper_scenario(), Sonar(), 2, 0)
    np.testing.assert_array_equal(a.truth.states, b.truth.states)
