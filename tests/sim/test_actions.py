"""Actions -> TPM: the ``set``, ``scale`` and stay modes, the floor, clipping, bad actions."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.special
import scipy.stats
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from imm_gym import ActionError, ConfigError, EnvConfig, TrackingCore
from imm_gym.envs import TPMAdaptEnv, TPMAdaptVectorEnv
from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv
from imm_gym.sim import kernels
from imm_gym.tracking.tpm import DIVERGENCE_FLOOR, apply_floor, row_divergence, stay_tpm

_CORES: dict[tuple, TrackingCore] = {}


def core_for(mode: str, p_min: float, n: int = 1, **extra) -> TrackingCore:
    key = (mode, p_min, n, tuple(sorted(extra.items())))
    if key not in _CORES:
        config = EnvConfig(scenario="paper", action_mode=mode, p_min=p_min, **extra)
        _CORES[key] = TrackingCore(config, n)
    return _CORES[key]


def test_set_mode_zero_action_is_the_uniform_tpm() -> None:
    for p_min in (0.0, 1e-3, 0.3):
        tpm = core_for("set", p_min).tpm_from_action(np.zeros((1, 9)))
        np.testing.assert_allclose(tpm, np.full((1, 3, 3), 1 / 3), rtol=1e-15)


def test_set_mode_is_a_row_softmax() -> None:
    a = np.array([[0.5, -0.25, 0.0, 1.0, 1.0, -1.0, 0.1, 0.2, 0.3]])
    tpm = core_for("set", 0.0, logit_scale=2.5).tpm_from_action(a)[0]
    logits = 2.5 * a.reshape(3, 3)
    expected = np.exp(logits) / np.exp(logits).sum(axis=1, keepdims=True)
    np.testing.assert_allclose(tpm, expected, rtol=1e-14)
    # the current TPM does not matter in set mode
    other = core_for("set", 0.0, logit_scale=2.5).tpm_from_action(a, np.array([stay_tpm(3, 0.4)]))
    np.testing.assert_array_equal(other[0], tpm)


@pytest.mark.parametrize("p_min", [1e-3, 0.01, 0.05, 0.2])
def test_set_mode_large_diagonal_saturates_at_the_floor(p_min: float) -> None:
    a = (2 * np.eye(3) - 1).reshape(1, 9) * 1.0  # +1 on the diagonal, -1 elsewhere
    core = core_for("set", p_min, logit_scale=8.0)  # softmax off-diagonal e^-16 << p_min
    tpm = core.tpm_from_action(a)[0]
    np.testing.assert_allclose(np.diag(tpm), 1 - 2 * p_min, rtol=1e-14)
    np.testing.assert_allclose(tpm[~np.eye(3, dtype=bool)], p_min, rtol=1e-14)
    np.testing.assert_allclose(tpm.sum(axis=1), 1.0, atol=1e-15)


def test_set_mode_at_a_large_logit_scale_saturates_without_overflow() -> None:
    """logit_scale 1000: exp(1000) overflows; the row's largest logit is taken out first, so the
    TPM is the floored identity (it was NaN without that), on both engines."""
    a = (2 * np.eye(3) - 1).reshape(1, 9)
    tpms = [core_for("set", 1e-3, logit_scale=1000.0).tpm_from_action(a)[0]]
    for engine in ("numpy", "compiled"):
        env = TPMAdaptEnv(scenario="paper", action_mode="set", p_min=1e-3, logit_scale=1000.0,
                          engine=engine)
        env.reset(seed=0)
        tpms.append(env.step(a[0])[4]["tpm"])
    for tpm in tpms:
        np.testing.assert_allclose(np.diag(tpm), 1 - 2e-3, rtol=1e-14)
        np.testing.assert_allclose(tpm[~np.eye(3, dtype=bool)], 1e-3, rtol=1e-14)


def test_compiled_set_mode_at_a_large_logit_scale_is_the_softmax() -> None:
    """The compiled set mode (kernels.tpm_from_action, two slots, no floor) at logit_scale 1000
    against scipy's softmax of the logits: rows whose logits exp overflows (1000, 999) or
    underflows to 0 (-1000, -999) are finite probability vectors, not NaN."""
    action = np.array([
        (2 * np.eye(3) - 1).ravel(),
        [1.0, 0.999, -1.0, 0.2, 1.0, 0.9995, -1.0, -1.0, -0.999],
    ])
    uniform = np.full((2, 3, 3), 1 / 3)
    got = kernels.tpm_from_action(action, uniform, kernels.SET, 1000.0, 0.0, uniform)
    expected = scipy.special.softmax(1000.0 * action.reshape(2, 3, 3), axis=2)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got.sum(axis=2), 1.0, rtol=1e-15)
    np.testing.assert_allclose(got, expected, rtol=1e-14, atol=1e-300)
    np.testing.assert_allclose(got[1, 2], np.array([1 / np.e, 1 / np.e, 1.0]) / (1 + 2 / np.e),
                               rtol=1e-14)  # logits -1000, -1000, -999 by hand


@pytest.mark.parametrize("mode", ["scale", "set", "stay", "stay_step"])
def test_actions_beyond_the_box_make_the_clipped_actions_tpm(mode: str) -> None:
    """tpm_from_action itself clips to [-1, 1] (the env test goes through the compiled step),
    in every action mode."""
    core = core_for(mode, 1e-3)
    size = 3 if mode in ("stay", "stay_step") else 9
    big = np.random.default_rng(3).uniform(-1, 1, (1, size)) * 7.0
    current = np.array([stay_tpm(3, 0.7)])
    np.testing.assert_array_equal(core.tpm_from_action(big, current),
                                  core.tpm_from_action(np.clip(big, -1, 1), current))
    assert not np.array_equal(core.tpm_from_action(big, current),
                              core.tpm_from_action(big / 7.0, current))


def test_scale_mode_multiplies_entries_by_powers_of_max_factor() -> None:
    core = core_for("scale", 0.0, max_factor=3.0)
    current = np.array([[[0.5, 0.25, 0.25], [0.1, 0.6, 0.3], [0.2, 0.2, 0.6]]])
    a = np.array([[1.0, -1.0, 0.0, 0.5, 0.0, -0.5, 0.0, 0.0, 1.0]])
    raw = current[0] * 3.0 ** a.reshape(3, 3)
    expected = raw / raw.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(core.tpm_from_action(a, current)[0], expected, rtol=1e-14)
    # the default current TPM is the core's own
    np.testing.assert_array_equal(
        core.tpm_from_action(np.zeros((1, 9))), core.tpm_from_action(np.zeros((1, 9)), core.tpm)
    )


def test_stay_mode_moves_each_rows_stay_on_the_logit_scale() -> None:
    # the tracker's own TPM, with an uneven switching structure on each row
    base = np.array([[0.9, 0.06, 0.04], [0.1, 0.8, 0.1], [0.02, 0.03, 0.95]])
    core = core_for("stay", 1e-3, n=1, logit_scale=2.0, sojourn=None)
    assert core.action_dim == 3
    core.fixed_tpms[:] = base
    a = np.array([[0.5, -1.0, 0.0]])
    tpm = core.tpm_from_action(a)[0]
    logit = np.log(np.diag(base) / (1 - np.diag(base))) + 2.0 * a[0]
    stay = 1 / (1 + np.exp(-logit))
    np.testing.assert_allclose(np.diag(tpm), stay, rtol=1e-14)
    for i in range(3):  # the rest of the row in the base row's proportions
        off = [j for j in range(3) if j != i]
        np.testing.assert_allclose(
            tpm[i, off], (1 - stay[i]) * base[i, off] / base[i, off].sum(), rtol=1e-13
        )
    # the zero action is the tracker's own TPM: a classical IMM
    np.testing.assert_allclose(core.tpm_from_action(np.zeros((1, 3)))[0], base, rtol=1e-14)
    # the current TPM does not matter
    np.testing.assert_array_equal(core.tpm_from_action(a, np.array([stay_tpm(3, 0.4)]))[0], tpm)


def test_stay_step_mode_moves_the_current_stays_in_the_trackers_structure() -> None:
    base = np.array([[0.9, 0.06, 0.04], [0.1, 0.8, 0.1], [0.02, 0.03, 0.95]])
    core = core_for("stay_step", 1e-3, n=1, logit_scale=0.5)
    assert core.action_dim == 3
    core.fixed_tpms[:] = base
    a = np.array([[1.0, -0.5, 0.0]])
    current = core.tpm_from_action(np.array([[-1.0, 0.4, 1.0]]), base[None])
    tpm = core.tpm_from_action(a, current)[0]
    stay0 = np.diag(current[0])
    stay = 1 / (1 + np.exp(-(np.log(stay0 / (1 - stay0)) + 0.5 * a[0])))
    np.testing.assert_allclose(np.diag(tpm)[:2], stay[:2], rtol=1e-13)
    np.testing.assert_array_equal(tpm[2], current[0, 2])  # a zero entry keeps its row
    for i in range(2):  # the tracker's switching structure, whatever the current rows
        off = [j for j in range(3) if j != i]
        np.testing.assert_allclose(
            tpm[i, off], (1 - stay[i]) * base[i, off] / base[i, off].sum(), rtol=1e-13
        )
    # steps add up on the logit scale
    twice = core.tpm_from_action(a, core.tpm_from_action(a, current))[0]
    once = core_for("stay_step", 1e-3, n=1, logit_scale=1.0)
    once.fixed_tpms[:] = base
    np.testing.assert_allclose(np.diag(twice), np.diag(once.tpm_from_action(a, current)[0]),
                               rtol=1e-12)


def test_stay_mode_keeps_the_stay_between_uniform_and_the_floor() -> None:
    core = core_for("stay", 0.01, n=2, logit_scale=50.0)
    core.fixed_tpms[:] = stay_tpm(3, 0.9)
    tpm = core.tpm_from_action(np.array([[1.0, 1.0, 1.0], [-1.0, -1.0, -1.0]]))
    np.testing.assert_allclose(np.diagonal(tpm[0]), 1 - 2 * 0.01, rtol=1e-14)
    np.testing.assert_allclose(tpm[1], np.full((3, 3), 1 / 3), rtol=1e-14)


def test_stay_mode_env_has_an_action_per_model() -> None:
    env = TPMAdaptEnv(scenario="paper", action_mode="stay")
    assert env.action_space.shape == (3,)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(3, dtype=np.float32))
    np.testing.assert_allclose(info["tpm"], stay_tpm(3, 0.995), rtol=1e-14)
    with pytest.raises(ActionError, match=r"shape \(3,\)"):
        env.step(np.zeros(9, dtype=np.float32))


def _check_bounds(tpm: np.ndarray, p_min: float) -> None:
    assert np.all(np.isfinite(tpm))
    np.testing.assert_allclose(tpm.sum(axis=-1), 1.0, rtol=0, atol=1e-12)
    assert tpm.min() >= p_min - 1e-12
    assert tpm.max() <= 1 - p_min + 1e-12


@settings(max_examples=150, deadline=None)
@given(
    mode=st.sampled_from(["scale", "set", "stay", "stay_step"]),
    p_min=st.floats(0.0, 0.3, exclude_max=True),
    actions=arrays(np.float64, (5, 4, 9), elements=st.floats(-3.0, 3.0)),
    start_stay=st.floats(0.0, 1.0),
)
def test_every_tpm_is_stochastic_and_inside_the_floor(mode, p_min, actions, start_stay) -> None:
    core = TrackingCore(EnvConfig(scenario="paper", action_mode=mode, p_min=p_min), 4)
    current = apply_floor(np.repeat(stay_tpm(3, start_stay)[None], 4, axis=0), p_min)
    core.fixed_tpms[:] = current  # stay mode's base: any valid TPM
    for a in actions:  # several steps: scale mode multiplies the current matrix
        current = core.tpm_from_action(a[:, : core.action_dim], current)
        _check_bounds(current, p_min)


@settings(max_examples=100, deadline=None)
@given(
    raw=arrays(
        np.float64,
        (6, 3, 3),
        elements=st.one_of(st.floats(1e-300, 1e300), st.sampled_from([1.0, 1e-12, 5e-324])),
    ),
    p_min=st.floats(0.0, 1 / 3, exclude_max=True),
)
def test_apply_floor_bounds_any_positive_matrix(raw, p_min) -> None:
    raw = raw / raw.max(axis=-1, keepdims=True)  # keep row sums finite
    _check_bounds(apply_floor(raw, p_min), p_min)


def test_apply_floor_leaves_a_valid_tpm_bitwise_unchanged() -> None:
    for tpm in (
        stay_tpm(3, 0.995),
        stay_tpm(3, 0.6),
        stay_tpm(4, 0.25),
        np.array([[0.5, 0.25, 0.25], [0.125, 0.75, 0.125], [0.0625, 0.0625, 0.875]]),
    ):
        assert np.all(tpm.sum(axis=1) == 1.0)  # rows that sum to 1 exactly in floating point
        for p_min in (0.0, 1e-3, min(tpm.min(), 0.05)):
            out = apply_floor(tpm[None], p_min)
            assert np.array_equal(out[0], tpm), (tpm, p_min)
    # a batch where one matrix needs the floor leaves the valid one alone
    batch = np.stack([stay_tpm(3, 0.995), stay_tpm(3, 0.6)])
    out = apply_floor(batch, 0.01)
    assert np.array_equal(out[1], batch[1])
    expected = 0.98 * np.eye(3) + 0.01 * (1 - np.eye(3))
    np.testing.assert_allclose(out[0], expected, rtol=1e-14)


def test_apply_floor_leaves_a_tpm_with_ulp_row_sums_unchanged() -> None:
    for tpm in (stay_tpm(4, 0.7), stay_tpm(3, 0.409)):
        assert np.all(np.abs(tpm.sum(axis=1) - 1.0) <= 2.3e-16)
        assert np.array_equal(apply_floor(tpm[None], 1e-3)[0], tpm)


def test_apply_floor_by_hand() -> None:
    tpm = np.array(
        [
            [0.9, 0.07, 0.03],  # one entry floored, the others pay proportionally
            [0.001, 0.98, 0.019],  # both small entries floored in one pass
            [0.005, 0.035, 0.96],  # 0.035 drops below the floor after the first pass
        ]
    )
    out = apply_floor(tpm[None], 0.05)[0]
    expected = np.array(
        [
            [0.9 * 0.95 / 0.97, 0.07 * 0.95 / 0.97, 0.05],
            [0.05, 0.9, 0.05],
            [0.05, 0.05, 0.9],
        ]
    )
    np.testing.assert_allclose(out, expected, rtol=1e-14)
    # rows are floored independently: the valid first row of another matrix is untouched
    mixed = np.array([[0.5, 0.3, 0.2], [0.001, 0.98, 0.019], [0.25, 0.5, 0.25]])
    out = apply_floor(mixed[None], 0.05)[0]
    assert np.array_equal(out[0], mixed[0]) and np.array_equal(out[2], mixed[2])
    np.testing.assert_allclose(out[1], [0.05, 0.9, 0.05], rtol=1e-14)


def test_apply_floor_rejects_a_floor_of_one_over_m() -> None:
    with pytest.raises(ConfigError, match="p_min"):
        apply_floor(stay_tpm(3, 0.9)[None], 1 / 3)
    with pytest.raises(ConfigError, match="p_min"):
        apply_floor(stay_tpm(3, 0.9)[None], -0.1)


def test_apply_floor_result_of_a_row_does_not_depend_on_the_batch() -> None:
    rng = np.random.default_rng(0)
    raw = rng.random((64, 3, 3)) ** 4
    batched = apply_floor(raw, 0.3)
    alone = np.stack([apply_floor(raw[i : i + 1], 0.3)[0] for i in range(raw.shape[0])])
    assert np.array_equal(batched, alone)


@pytest.mark.parametrize("mode", ["scale", "set"])
def test_out_of_range_actions_act_like_clipped_ones(mode: str) -> None:
    rng = np.random.default_rng(5)
    big = rng.uniform(-1, 1, 9) * 7.0
    runs = []
    for action in (np.clip(big, -1, 1), big, np.full(9, 5.0), np.ones(9)):
        env = TPMAdaptEnv(scenario="random", action_mode=mode, obs_features=("tpm",))
        env.reset(seed=2)
        out = [env.step(action) for _ in range(3)]
        runs.append(out)
    for first, second in ((runs[0], runs[1]), (runs[2], runs[3])):
        for a, b in zip(first, second, strict=True):
            np.testing.assert_array_equal(a[0], b[0])
            assert a[1] == b[1]
            np.testing.assert_array_equal(a[4]["tpm"], b[4]["tpm"])
    assert not np.array_equal(runs[0][0][0], runs[2][0][0])
    core = core_for(mode, 1e-3)
    np.testing.assert_array_equal(
        core.check_action(np.array([[5.0, -5.0, 0.5, 1e6, -1e6, 1.0, -1.0, 0.0, 1e-300]])),
        [[1.0, -1.0, 0.5, 1.0, -1.0, 1.0, -1.0, 0.0, 1e-300]],
    )


BAD_SCALAR = [
    np.full(9, np.nan),
    np.array([np.inf] + [0.0] * 8),
    np.array([0.0] * 8 + [-np.inf]),
    np.zeros(8),
    np.zeros(10),
    np.zeros((1, 9)),
    np.zeros((3, 3)),
    np.float64(0.0),
    np.full(9, 0.5 + 1j),  # not silently its real part
    np.array(["0.5"] * 9),  # not parsed as numbers
]


@pytest.mark.parametrize("bad", BAD_SCALAR, ids=lambda a: f"{np.shape(a)}")
def test_bad_actions_raise_in_the_scalar_env_and_leave_it_usable(bad) -> None:
    env, twin = TPMAdaptEnv(scenario="paper"), TPMAdaptEnv(scenario="paper")
    env.reset(seed=0)
    twin.reset(seed=0)
    with pytest.raises(ActionError):
        env.step(bad)
    # the rejected action did not advance or change the episode
    a = np.full(9, 0.5)
    oa, ra, *_ = env.step(a)
    ob, rb, *_ = twin.step(a)
    np.testing.assert_array_equal(oa, ob)
    assert ra == rb


@pytest.mark.parametrize(
    "bad",
    [
        np.full((3, 9), np.nan),
        np.where(np.eye(3, 9, dtype=bool), np.inf, 0.0),
        np.zeros((3, 8)),
        np.zeros((2, 9)),
        np.zeros(27),
        np.zeros((3, 3, 3)),
    ],
    ids=lambda a: f"{np.shape(a)}-{np.isfinite(a).all()}",
)
def test_bad_actions_raise_in_the_vector_env_core_and_sb3_adapter(bad) -> None:
    venv = TPMAdaptVectorEnv(3, config={"scenario": "paper"})
    venv.reset(seed=0)
    with pytest.raises(ActionError):
        venv.step(bad)
    core = TrackingCore(EnvConfig(scenario="paper"), 3)
    core.reset(np.arange(3), [0, 1, 2])
    with pytest.raises(ActionError):
        core.step(bad)
    with pytest.raises(ActionError):
        core.tpm_from_action(bad)
    if np.size(bad) == 27 and not np.isfinite(bad).all():
        sb3 = TPMAdaptSB3VecEnv(3, config={"scenario": "paper"})
        sb3.reset()
        with pytest.raises(ActionError):
            sb3.step(bad)


def test_action_error_is_a_value_error_naming_the_problem() -> None:
    assert issubclass(ActionError, ValueError)
    env = TPMAdaptEnv()
    env.reset(seed=0)
    with pytest.raises(ActionError, match=r"shape.*\(9,\)"):
        env.step(np.zeros(4))
    with pytest.raises(ActionError, match="finite"):
        env.step(np.full(9, np.nan))


def test_rejected_action_on_an_autoreset_step_does_not_skip_an_episode() -> None:
    config = {"scenario": "random", "divergence_error": 1.0}  # every episode ends at step 1

    def episode_two_truth(reject: bool) -> np.ndarray:
        venv = TPMAdaptVectorEnv(1, config=config)
        venv.reset(seed=0)
        venv.step(np.zeros((1, 9)))  # diverges: the next step autoresets
        if reject:
            with pytest.raises(ActionError):
                venv.step(np.full((1, 9), np.nan))
        venv.step(np.zeros((1, 9)))
        return venv.core.truth[0].copy()

    np.testing.assert_array_equal(episode_two_truth(True), episode_two_truth(False))


@settings(max_examples=50, deadline=None)
@given(
    raw=arrays(np.float64, (2, 3, 3), elements=st.floats(1e-3, 1.0)),
    stay=st.floats(0.05, 0.95),
)
def test_row_divergence_is_the_mean_kl_of_the_rows(raw, stay) -> None:
    tpm = raw / raw.sum(axis=-1, keepdims=True)
    reference = stay_tpm(3, stay)
    expected = [np.mean([scipy.stats.entropy(t[i], reference[i]) for i in range(3)]) for t in tpm]
    np.testing.assert_allclose(row_divergence(tpm, reference), expected, rtol=1e-10, atol=1e-14)
    assert np.all(row_divergence(tpm, reference) >= -1e-15)
    assert row_divergence(reference, reference) == 0.0


def test_row_divergence_by_hand() -> None:
    # a row (0.6, 0.2, 0.2) from the uniform one: 0.6 ln 1.8 + 2 * 0.2 ln 0.6
    expected = 0.6 * np.log(1.8) + 0.4 * np.log(0.6)
    np.testing.assert_allclose(row_divergence(stay_tpm(3, 0.6), stay_tpm(3, 1 / 3)), expected)
    zero_entry = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(row_divergence(zero_entry, stay_tpm(3, 1 / 3)), np.log(3.0))


def test_row_divergence_from_a_reference_with_zero_entries_is_finite() -> None:
    """A stay of 1 (or ``p_min = 0``) puts zeros in the reference: the probability moved onto
    them costs ``ln(p / DIVERGENCE_FLOOR)`` instead of an infinite divergence."""
    moved = stay_tpm(3, 0.99)
    expected = 0.99 * np.log(0.99) + 2 * 0.005 * np.log(0.005 / DIVERGENCE_FLOOR)  # every row
    np.testing.assert_allclose(row_divergence(moved, np.eye(3)), expected, rtol=1e-12)
    assert row_divergence(np.eye(3), np.eye(3)) == 0.0


@pytest.mark.parametrize(
    ("settings", "cost"),
    [({"initial_stay": 1.0}, "tpm_change_cost"), ({"shadow_stay": 1.0}, "tpm_cost")],
)
def test_a_cost_against_a_stay_of_one_gives_finite_rewards(settings: dict, cost: str) -> None:
    """The reset TPM (``initial_stay: 1``) and the shadow's (``shadow_stay: 1``) have zero
    entries that the floored TPM of every step moves probability onto."""
    env = TPMAdaptEnv(scenario="random", **settings, **{cost: 0.05})
    env.reset(seed=0)
    for _ in range(3):
        _, reward, *_ = env.step(np.zeros(9))
        assert np.isfinite(reward)


def test_tpm_cost_is_subtracted_from_the_reward() -> None:
    cost = 0.05
    env = TPMAdaptEnv(scenario="random", action_mode="set", shadow_stay=1 / 3, tpm_cost=cost)
    env.reset(seed=4)
    _, reward, *_, info = env.step(np.zeros(9))  # set mode: zero logits, the uniform TPM
    assert abs(info["tpm_divergence"]) < 1e-14
    np.testing.assert_allclose(reward, info["reward_advantage"], rtol=0.0, atol=1e-15)
    rng = np.random.default_rng(4)
    for _ in range(20):
        _, reward, *_, info = env.step(rng.uniform(-1, 1, 9))
        divergence = row_divergence(info["tpm"], stay_tpm(3, 1 / 3))
        np.testing.assert_allclose(info["tpm_divergence"], divergence, rtol=1e-12)
        assert divergence > 0.0
        np.testing.assert_allclose(reward, info["reward_advantage"] - cost * divergence)
