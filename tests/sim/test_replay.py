"""imm_gym.run_policy replays the environment: a simulated episode's measurements, detection
flags and initial velocity handed to run_policy() give the env's estimates, covariances, mode
probabilities and TPMs bit for bit (fixed TPM, TIP-IMM, the shipped agent; two sequences in one
batch), without any truth."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import imm_gym
from agents import PRETRAINED
from agents.ensemble import load_policy
from baselines import make_baseline
from imm_gym import ConfigError, EnvConfig, paper_scenario
from imm_gym.envs.tpm_adapt import TPMAdaptEnv
from imm_gym.sim.config_file import EVALUATED_FIELDS
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.sim.replay import UNKNOWN_VELOCITY_STD, ReplayCore, TrackResult, run_policy
from imm_gym.tracking.initiation import initiate
from imm_gym.tracking.sensors import Sonar

SEEDS = (3, 11)


def _policy(name: str) -> Any:
    return load_policy(PRETRAINED) if name == "pretrained" else make_baseline(name)


def _episodes(name: str, config: EnvConfig) -> dict[str, np.ndarray]:
    """Each seed's episode in the scalar env, stacked: its inputs and per-step outputs."""
    records: dict[str, list[np.ndarray]] = {}
    for seed in SEEDS:
        policy = _policy(name)
        overrides = policy.env_overrides
        if name == "pretrained":  # a trained agent tracks with the configured tracker
            overrides = {k: v for k, v in overrides.items() if k not in EVALUATED_FIELDS}
        env = TPMAdaptEnv(config.replace(**overrides))
        obs, _ = env.reset(seed=seed)
        core = env.core
        rows: dict[str, list[np.ndarray]] = {
            "estimate": [], "covariance": [], "mode_probs": [], "tpm": []
        }
        state, start, done = None, True, False
        while not done:
            action, state = policy.predict(
                obs, state=state, episode_start=np.array([start]), deterministic=True
            )
            start = False
            obs, _, terminated, truncated, info = env.step(action)
            assert not terminated
            done = truncated
            for key in rows:
                rows[key].append(info[key])
        episode = {key: np.stack(value) for key, value in rows.items()}
        episode["z"], episode["detected"] = core.z[0].copy(), core.detected[0].copy()
        episode["velocity"] = core.truth[0, 0, 2:4].copy()
        for key, value in episode.items():
            records.setdefault(key, []).append(value)
    return {key: np.stack(value) for key, value in records.items()}


def _assert_replayed(out: TrackResult, env: dict[str, np.ndarray], i: int, row: int) -> None:
    """Row ``row`` of ``out`` is episode ``i`` bit for bit."""
    for key in ("estimate", "covariance", "mode_probs", "tpm"):
        np.testing.assert_array_equal(getattr(out, key)[row], env[key][i], err_msg=key)
    assert not out.diverged[row]


@pytest.mark.parametrize("name", ["fixed", "tip-imm", "pretrained"])
def test_track_reproduces_the_env_bit_for_bit(name: str) -> None:
    config = EnvConfig(sensor=Sonar(detection_prob=0.8))
    env = _episodes(name, config)
    assert not env["detected"].all()  # missed detections are replayed too
    # the recorded z of a missed detection is never read
    z = np.where(env["detected"][..., None], env["z"], np.nan)
    # one sequence at a time, as the scalar env ran them (a network's actions may differ in the
    # last bit between batch sizes), and, for the rule policies, both in one batch
    for i in range(len(SEEDS)):
        out = imm_gym.run_policy(z[i], _policy(name), config, velocity=env["velocity"][i])
        _assert_replayed(out, env, i, 0)
    if name != "pretrained":
        out = imm_gym.run_policy(z, _policy(name), config, velocity=env["velocity"])
        for i in range(len(SEEDS)):
            _assert_replayed(out, env, i, i)


@pytest.mark.parametrize(("name", "bank"), [("window", "paper"), ("tip-imm", "hetero")])
def test_other_policies_and_banks(name: str, bank: str) -> None:
    """A rule with a memory (window) and the heterogeneous NCV/CT/CTRA bank (numpy engine,
    6-d states; tip-imm runs bank B and the fusion) replay bit for bit too."""
    config = EnvConfig().replace(**BANK_PRESETS[bank])
    env = _episodes(name, config)
    out = imm_gym.run_policy(
        env["z"], _policy(name), config, env["detected"], velocity=env["velocity"]
    )
    for i in range(len(SEEDS)):
        for key in ("mode_probs", "tpm"):
            np.testing.assert_array_equal(getattr(out, key)[i], env[key][i], err_msg=key)
        np.testing.assert_array_equal(out.estimate[i], env["estimate"][i][..., :4])
        np.testing.assert_array_equal(out.covariance[i], env["covariance"][i][..., :4, :4])


def test_track_reads_no_truth() -> None:
    """The replay core keeps no truth, and a configuration whose scenario draws another truth
    (the paper scenario instead of the random family, same T) tracks the same."""
    core = ReplayCore(EnvConfig(), n_envs=2)
    for name in ("truth", "true_model", "z", "detected"):
        assert not hasattr(core, name)
    env = _episodes("pretrained", EnvConfig())
    other = EnvConfig(scenario=paper_scenario())
    assert other.source.T == EnvConfig().source.T
    for i in range(len(SEEDS)):
        out = run_policy(
            env["z"][i], _policy("pretrained"), other, env["detected"][i],
            velocity=env["velocity"][i],
        )
        np.testing.assert_array_equal(out.estimate[0], env["estimate"][i])
        np.testing.assert_array_equal(out.tpm[0], env["tpm"][i])


def test_single_sequence_initial_state_and_engines() -> None:
    """One sequence (K+1, m) comes back batched; the default start is a zero velocity with
    UNKNOWN_VELOCITY_STD; x0/P0 given are used as they are; the numpy engine agrees."""
    env = _episodes("tip-imm", EnvConfig())
    z = env["z"][0]
    out = run_policy(z, _policy("tip-imm"))
    x0, P0 = initiate(Sonar(), z[:1], np.zeros(2), UNKNOWN_VELOCITY_STD)
    np.testing.assert_array_equal(out.x0, x0)
    np.testing.assert_array_equal(out.P0, P0)
    assert out.estimate.shape == (1, z.shape[0] - 1, 4)
    start_x, start_P = initiate(Sonar(), z[:1], env["velocity"][0], 5.0)
    given = run_policy(z, _policy("tip-imm"), x0=start_x[0], P0=start_P[0])
    np.testing.assert_array_equal(given.estimate[0], env["estimate"][0])
    numpy_engine = run_policy(
        z, _policy("tip-imm"), EnvConfig(engine="numpy"), x0=start_x[0], P0=start_P[0]
    )
    np.testing.assert_allclose(numpy_engine.estimate, given.estimate, rtol=1e-9, atol=1e-6)
    # a wrong start moves the estimates: the start is really used
    assert not np.array_equal(out.estimate, given.estimate)


def test_bad_inputs_are_config_errors() -> None:
    z = np.ones((5, 2)) * [1000.0, 0.1]
    policy = _policy("fixed")
    with pytest.raises(ConfigError, match="z must be"):
        run_policy(np.ones((5, 3)), policy)
    with pytest.raises(ConfigError, match="detected must have shape"):
        run_policy(z, policy, detected=np.ones(4, dtype=bool))
    with pytest.raises(ConfigError, match="not finite"):
        run_policy(np.where(np.arange(5)[:, None] == 2, np.nan, z), policy, detected=np.ones(5,
        bool))
    with pytest.raises(ConfigError, match="initiates the track"):
        run_policy(np.where(np.arange(5)[:, None] == 0, np.nan, z), policy)
    with pytest.raises(ConfigError, match="x0 needs P0"):
        run_policy(z, policy, x0=np.zeros(4))
    with pytest.raises(ConfigError, match="P0 needs x0"):
        run_policy(z, policy, P0=np.eye(4))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        # each was taken: inf and a half-NaN row as missed detections, 0.5/2/NaN flags as True,
        # a 3-vector velocity a numpy broadcast error
        ({"z": (2, 0, np.inf)}, r"z\[0, 2\] is infinite \(NaN is a missed detection\)"),
        ({"z": (2, 1, np.nan)}, r"z\[0, 2\] is partly NaN: a missed detection is a row of NaN"),
        ({"detected": 0.5}, "detected must be booleans or the numbers 0 and 1"),
        ({"detected": 2.0}, "detected must be booleans or the numbers 0 and 1"),
        ({"detected": np.nan}, "detected must be booleans or the numbers 0 and 1"),
        ({"velocity": [1.0, 2.0, 3.0]}, r"velocity must be finite, of shape \(2,\) or \(1, 2\)"),
        ({"velocity": [1.0, np.nan]}, r"velocity must be finite"),
        ({"P0": np.diag([1.0, 1.0, 1.0, -1.0])}, "sequence 0: P0 must be positive definite"),
        ({"P0": np.eye(4) + np.triu(np.ones((4, 4)), 1)}, "sequence 0: P0 must be symmetric"),
        ({"x0": [np.nan, 0.0, 0.0, 0.0]}, "sequence 0: x0 and P0 must be finite"),
    ],
    ids=["inf", "half-nan", "flag-half", "flag-2", "flag-nan", "velocity-3", "velocity-nan",
         "P0-indefinite", "P0-asymmetric", "x0-nan"],
)
def test_inputs_the_track_cannot_mean_are_refused(change, message) -> None:
    z = np.ones((5, 2)) * [1000.0, 0.1]
    kwargs: dict = {}
    if "z" in change:
        k, i, value = change["z"]
        z[k, i] = value
    if "detected" in change:
        kwargs["detected"] = np.array([1.0, 1.0, change["detected"], 1.0, 1.0])
    if "velocity" in change:
        kwargs["velocity"] = change["velocity"]
    if "P0" in change or "x0" in change:
        kwargs["x0"] = change.get("x0", np.zeros(4))
        kwargs["P0"] = change.get("P0", np.eye(4))
    with pytest.raises(ConfigError, match=message):
        run_policy(z, _policy("fixed"), **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        # numpy's ValueError, not ConfigError; a velocity beside x0 was silently ignored
        ({"z": [[1000.0, 0.1], [1.0]]}, "z must be an array of numbers"),
        ({"z": [["a", "b"], ["c", "d"]]}, "z must be an array of numbers"),
        ({"velocity": ["a", "b"]}, "velocity must be an array of numbers"),
        ({"x0": [[0.0, 0.0], [0.0]], "P0": np.eye(4)}, "x0 must be an array of numbers"),
        ({"x0": np.zeros(4), "P0": np.eye(4) * 100.0, "velocity": [1.0, 2.0, 3.0]},
         "velocity and x0 both given"),
        ({"x0": np.zeros(4), "P0": np.eye(4) * 100.0, "velocity": [1.0, 2.0]},
         "velocity and x0 both given"),
    ],
    ids=["z-ragged", "z-text", "velocity-text", "x0-ragged", "velocity-bad-with-x0",
         "velocity-with-x0"],
)
def test_inputs_that_are_no_array_of_numbers_or_two_starts_are_refused(kwargs, message) -> None:
    kwargs = {"z": np.ones((5, 2)) * [1000.0, 0.1], **kwargs}
    with pytest.raises(ConfigError, match=message):
        run_policy(policy=_policy("fixed"), **kwargs)


def test_flags_of_zeros_and_ones_and_what_the_env_can_draw_are_taken() -> None:
    """0/1 flags act as booleans; a negative range, which the env draws under heavy outliers
    (its noise is not clipped), is tracked as given."""
    z = np.ones((5, 2)) * [1000.0, 0.1]
    odd = z.copy()
    odd[3] = [-9761.5, -1.07]
    assert np.all(np.isfinite(run_policy(odd, _policy("fixed")).estimate))
    flags = np.array([1, 1, 0, 1, 1])
    as_numbers = run_policy(z, _policy("fixed"), detected=flags)
    as_bools = run_policy(z, _policy("fixed"), detected=flags.astype(bool))
    np.testing.assert_array_equal(as_numbers.estimate, as_bools.estimate)


class _EvidencePolicy:
    """Moves the stays by the stay bank's evidence for the sticky stays: its actions and the
    centre of its TPM come from the stay bank, which the replay has to run too."""

    env_overrides = {
        "action_mode": "stay",
        "stay_base": "evidence",
        "obs_features": ("stay_bank_evidence",),
    }

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.repeat(obs[:, -1:] - obs[:, -4:-3], 3, axis=1), state


def test_the_stay_bank_is_replayed() -> None:
    config = EnvConfig(sensor=Sonar(detection_prob=0.8))
    policy = _EvidencePolicy()
    for seed in SEEDS:
        env = TPMAdaptEnv(config.replace(**policy.env_overrides))
        obs, _ = env.reset(seed=seed)
        tpms, done = [], False
        while not done:
            obs, _, _, done, info = env.step(policy.predict(obs[None])[0][0])
            tpms.append(info["tpm"])
        core = env.core
        out = imm_gym.run_policy(
            core.z[0], policy, config, core.detected[0], velocity=core.truth[0, 0, 2:4]
        )
        np.testing.assert_array_equal(out.tpm[0], np.stack(tpms))
        assert np.ptp(np.stack(tpms)[:, 0, 0]) > 0.05  # the evidence moved the TPM
