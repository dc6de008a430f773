"""The core's two engines compute the same step: the compiled :func:`imm_gym.sim.kernels.env_step`
(built-in banks) against the numpy orchestration that any bank runs (here the same bank on the
numpy IMM engine), over whole episodes with random actions, autoresets and divergences."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import ConfigError, EnvConfig, TrackingCore
from imm_gym.sim.kernels import ACTION_MODE_CODES, tpm_from_action
from imm_gym.tracking.tpm import apply_floor

FEATURES = ("tpm", "loglik", "nis", "innovation", "time", "turn_rate")
SHADOW_FEATURES = ("shadow_probs", "shadow_turn_rate", "shadow_evidence", "stay_evidence")
N = 3


def _engines(config: EnvConfig) -> tuple[TrackingCore, TrackingCore]:
    fused, general = TrackingCore(config, N), TrackingCore(config.replace(engine="numpy"), N)
    assert fused.imm.kernel_args is not None and general.imm.kernel_args is None
    return fused, general


def _assert_close(a: object, b: object, key: str) -> None:
    if isinstance(a, np.ndarray) and a.dtype.kind == "f":
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10, err_msg=key)
    else:
        np.testing.assert_array_equal(a, b, err_msg=key)


def _assert_the_engines_agree(config: EnvConfig) -> None:
    """200 steps of random actions on both engines, with resets of the ended episodes: equal
    observations, flags, rewards, infos and bank states (to 1e-10; observations to 1e-6)."""
    fused, general = _engines(config)
    rng = np.random.default_rng(3)
    for core in (fused, general):
        core.reset(np.arange(N), [10, 11, 12])
    ends = diverged = 0
    for _ in range(200):
        action = rng.uniform(-1.5, 1.5, (N, fused.action_dim))
        a, b = fused.step(action), general.step(action)
        np.testing.assert_allclose(a.obs, b.obs, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(a.terminated, b.terminated)
        np.testing.assert_array_equal(a.truncated, b.truncated)
        np.testing.assert_allclose(a.reward, b.reward, rtol=1e-10, atol=1e-10)
        assert a.info.keys() == b.info.keys()
        for key in a.info:
            _assert_close(a.info[key], b.info[key], key)
        for name in ("cbar", "loglik", "cbar_s", "loglik_s", "mu_s_prev"):
            _assert_close(getattr(fused, name), getattr(general, name), name)
        for bank in ("state_a", "state_b", "state_s"):
            for part in ("x", "P", "mu"):
                _assert_close(
                    getattr(getattr(fused, bank), part), getattr(getattr(general, bank), part), bank
                )
        done = np.flatnonzero(a.terminated | a.truncated)
        ends += done.size
        diverged += int(a.terminated.sum())
        for core in (fused, general):
            core.reset(done, [None] * done.size)
    assert ends >= N and diverged >= 1  # whole episodes, divergences, then new episodes


@pytest.mark.parametrize("mode", ["scale", "set", "stay", "stay_step"])
@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize("shadow", ["fixed", "none"])
def test_fused_step_equals_the_numpy_orchestration(mode: str, parallel: bool, shadow: str) -> None:
    features = (
        FEATURES
        + (SHADOW_FEATURES if shadow == "fixed" else ())
        + (("bank_b",) if parallel else ())
    )
    config = EnvConfig(
        action_mode=mode,
        parallel=parallel,
        shadow=shadow,
        reward="advantage" if shadow == "fixed" else "error",
        p_min=0.01,
        obs_features=features,
        sensor={"detection_prob": 0.8},
        family={"horizon": 60, "n_segments": (2, 4)},
        divergence_error=60.0,  # a few episodes end as diverged
    )
    _assert_the_engines_agree(config)


def test_the_shadow_runs_its_own_tpm_in_both_engines() -> None:
    """A shadow stay of 0.6 (the trackers' initial and fixed TPMs keep 0.995): the shadow's
    probabilities, evidence, error and the advantage reward of the compiled engine equal the
    numpy engine's, which steps the shadow IMM with ``config.shadow_tpm``."""
    config = EnvConfig(
        shadow="fixed",
        shadow_stay=0.6,
        reward="advantage",
        obs_features=FEATURES + SHADOW_FEATURES,
        sensor={"detection_prob": 0.8},
        family={"horizon": 60, "n_segments": (2, 4)},
        divergence_error=60.0,  # a few episodes end as diverged
    )
    T = config.source.T
    assert not np.allclose(config.shadow_tpm(T), config.initial_tpm(T))
    _assert_the_engines_agree(config)


@pytest.mark.parametrize("mode", ["scale", "set", "stay", "stay_step"])
@pytest.mark.parametrize("p_min", [0.0, 1e-3, 0.2, 0.3])
def test_compiled_tpm_from_action_equals_the_numpy_one(mode: str, p_min: float) -> None:
    core = TrackingCore(EnvConfig(action_mode=mode, p_min=p_min, max_factor=50.0), 64)
    rng = np.random.default_rng(1)
    tpm = apply_floor(rng.random((64, 3, 3)) ** 3, p_min)
    core.fixed_tpms[:] = apply_floor(rng.random((64, 3, 3)) ** 2, p_min)  # stay mode's base
    core.fixed_tpms[0] = np.eye(3)  # a row that never leaves: the rest shared evenly
    action = rng.uniform(-2, 2, (64, core.action_dim))
    gain = core.config.max_factor if mode == "scale" else core.config.logit_scale
    code = ACTION_MODE_CODES[mode]
    got = tpm_from_action(action, tpm, code, gain, p_min, core.fixed_tpms)
    np.testing.assert_allclose(got, core.tpm_from_action(action, tpm), rtol=1e-13, atol=1e-16)
    # the zero action keeps a valid TPM bit for bit: the current one (scale, stay_step) or the
    # trackers' own (stay; its identity row 0 is floored first)
    zero = np.zeros((64, core.action_dim))
    if mode == "scale":
        assert np.array_equal(tpm_from_action(zero, tpm, code, gain, p_min, tpm), tpm)
    elif mode in ("stay", "stay_step"):
        own = core.fixed_tpms if mode == "stay" else tpm
        source = apply_floor(own, p_min)
        assert np.array_equal(source[1:], own[1:])  # the floor keeps the valid TPMs
        got = tpm_from_action(zero, tpm, code, gain, p_min, core.fixed_tpms)
        assert np.array_equal(got, source)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_engines_agree_within_a_micrometre_under_outliers(seed: int) -> None:
    """With measurement outliers (innovations of NIS in the hundreds) the likelihoods of the mode
    probabilities amplify the engines' rounding differences: the positions of whole episodes part
    by up to 1e-6 m (9.5e-7 m measured over these runs), not the 1e-11 m of outlier-free ones;
    the test allows ten times that."""
    config = EnvConfig(sensor={"outlier_prob": 0.2})
    fused, general = TrackingCore(config, 4), TrackingCore(config.replace(engine="numpy"), 4)
    for core in (fused, general):
        core.reset(np.arange(4), list(range(10 * seed, 10 * seed + 4)))
    rng = np.random.default_rng(seed)
    ends = 0
    for _ in range(300):
        action = rng.uniform(-1.0, 1.0, (4, fused.action_dim))
        a, b = fused.step(action), general.step(action)
        np.testing.assert_array_equal(a.terminated, b.terminated)
        np.testing.assert_array_equal(a.truncated, b.truncated)
        np.testing.assert_allclose(a.info["estimate"], b.info["estimate"], rtol=0, atol=1e-5)
        np.testing.assert_allclose(a.info["mode_probs"], b.info["mode_probs"], rtol=0, atol=1e-7)
        np.testing.assert_allclose(a.reward, b.reward, rtol=0, atol=1e-6)
        done = np.flatnonzero(a.terminated | a.truncated)
        ends += done.size
        for core in (fused, general):
            core.reset(done, [None] * done.size)
    assert ends >= 4  # whole episodes, then new ones


def test_the_covariance_divergence_flag_is_the_trace_of_the_position_covariance() -> None:
    """A track diverges when the trace of its position covariance, P_xx + P_yy, passes
    ``divergence_cov``: with half the detections missed that trace passes 1500 m² in some steps
    and not in others; both engines flag exactly the steps where P_xx + P_yy of the returned
    ``info["covariance"]`` exceeds it (the position error can not end an episode here)."""
    cov = 1500.0
    config = EnvConfig(divergence_cov=cov, divergence_error=1e6, sensor={"detection_prob": 0.5})
    fused, general = _engines(config)
    for core in (fused, general):
        core.reset(np.arange(N), [1, 2, 3])
    rng = np.random.default_rng(0)
    diverged = kept = 0
    for _ in range(100):
        action = rng.uniform(-1.0, 1.0, (N, fused.action_dim))
        a, b = fused.step(action), general.step(action)
        P = b.info["covariance"]
        expected = P[:, 0, 0] + P[:, 1, 1] > cov
        for out in (a, b):
            np.testing.assert_array_equal(out.terminated, expected)
            np.testing.assert_array_equal(out.info["diverged"], expected)
        np.testing.assert_allclose(a.info["covariance"], P, rtol=1e-10, atol=1e-10)
        diverged += int(expected.sum())
        kept += int((~expected).sum())
        done = np.flatnonzero(a.terminated | a.truncated)
        for core in (fused, general):
            core.reset(done, [None] * done.size)
    assert diverged >= 5 and kept >= 100  # the threshold is crossed in some steps, not all


@pytest.mark.parametrize("engine", ["numpy", "compiled"])
def test_a_failed_filter_s_position_error_is_the_cap(engine: str) -> None:
    """A NaN measurement fails slot 1's filters (bank A and the shadow): its position errors
    are then ``divergence_error`` (60 m), not NaN, its episode ends as diverged and the
    advantage reward stays finite; slot 0 runs on."""
    config = EnvConfig(engine=engine, shadow="fixed", reward="advantage", divergence_error=60.0)
    core = TrackingCore(config, 2)
    core.reset(np.arange(2), [1, 2])
    for _ in range(3):
        core.step(np.zeros((2, core.action_dim)))
    core.z[1, core.k + 1] = np.nan
    core.detected[1, core.k + 1] = True
    out = core.step(np.zeros((2, core.action_dim)))
    assert out.info["position_error"][1] == 60.0
    assert out.info["shadow_position_error"][1] == 60.0
    assert out.terminated.tolist() == [False, True]
    assert np.isfinite(out.reward).all() and out.info["position_error"][0] < 60.0


def test_auto_is_the_compiled_engine_where_the_tracker_has_one() -> None:
    """``engine="auto"`` (the default) runs the compiled engine for a built-in bank, bit for bit
    (the numpy engine's numbers part from it by rounding, about 1e-11 m), and the numpy engine
    for the heterogeneous bank, which has no kernel; asking for ``"compiled"`` there is
    refused by name."""
    from imm_gym.sim.presets import BANK_PRESETS

    estimates = {}
    for engine in ("auto", "compiled", "numpy"):
        core = TrackingCore(EnvConfig(engine=engine, sensor={"detection_prob": 0.8}), N)
        core.reset(np.arange(N), [4, 5, 6])
        rng = np.random.default_rng(0)
        estimates[engine] = np.array([
            core.step(rng.uniform(-1, 1, (N, core.action_dim))).info["estimate"]
            for _ in range(40)
        ])
    np.testing.assert_array_equal(estimates["auto"], estimates["compiled"])
    np.testing.assert_allclose(estimates["auto"], estimates["numpy"], rtol=0, atol=1e-6)
    hetero = EnvConfig(**BANK_PRESETS["hetero"])
    assert TrackingCore(hetero, 1).imm.kernel_args is None  # auto: the numpy engine
    with pytest.raises(ConfigError, match="engine 'compiled' needs a tracker with a compiled"):
        TrackingCore(hetero.replace(engine="compiled"), 1)
