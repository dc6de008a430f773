"""Tests of imm_gym.evaluation.rollout.rollout from several starting TPMs at once: the same
records, bit for bit, as one roll-out per TPM (the best fixed TPM's search relies on it)."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from baselines import TIPIMM, FixedTPM
from imm_gym.evaluation.rollout import Rollout, evaluation_config, rollout, score
from imm_gym.sim.core import INFINITY_STAND_IN, StepResult, TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.tracking.tpm import stay_tpm
from imm_gym.validation import ConfigError


@pytest.mark.parametrize("scenario", ["paper", "random"])
def test_rollout_from_several_tpms_equals_one_rollout_per_tpm(scenario: str) -> None:
    base = EnvConfig(scenario=scenario)
    stays = (1 / 3, 0.9, 0.999)  # 0.999's off-diagonal 5e-4 is below the default floor 1e-3
    tpms = np.stack([stay_tpm(3, p) for p in stays])
    policy = FixedTPM(3)
    batched = rollout(
        policy, evaluation_config(base, policy.env_overrides), 4, 21, initial_tpms=tpms
    )
    parts = batched.groups(len(stays))
    assert len(parts) == 3 and all(len(p.diverged) == 4 for p in parts)
    for stay, part in zip(stays, parts, strict=True):
        alone = FixedTPM(3, stay)
        ref = rollout(alone, evaluation_config(base, alone.env_overrides), 4, 21)
        for f in fields(ref):
            np.testing.assert_array_equal(getattr(part, f.name), getattr(ref, f.name), f.name)
        np.testing.assert_array_equal(part.tpm, np.broadcast_to(stay_tpm(3, stay), part.tpm.shape))


@pytest.mark.parametrize("config", [EnvConfig(), EnvConfig.build({"sojourn": [60.0, 20.0, 20.0]})])
def test_a_slot_started_from_other_tpms_returns_to_the_configured_one(config) -> None:
    """``initial_tpms`` start one episode; the slot's next reset without them starts from the
    configuration's TPM again (bank B and the stay action's base read it)."""
    core = TrackingCore(config, n_envs=2)
    configured = core.fixed_tpms.copy()
    core.reset(np.arange(2), [0, 1], np.repeat(stay_tpm(3, 0.6)[None], 2, axis=0))
    np.testing.assert_array_equal(core.fixed_tpms, np.repeat(stay_tpm(3, 0.6)[None], 2, axis=0))
    core.reset(np.array([1]), [2])
    np.testing.assert_array_equal(core.fixed_tpms[1], configured[1])
    np.testing.assert_array_equal(core.fixed_tpms[0], stay_tpm(3, 0.6))
    np.testing.assert_array_equal(core.tpm[1], configured[1])


def test_reset_checks_the_initial_tpms() -> None:
    core = TrackingCore(EnvConfig(), n_envs=2)
    with pytest.raises(ConfigError, match="initial_tpms rows must sum to 1"):
        core.reset(np.arange(2), [0, 1], np.full((2, 3, 3), 0.5))
    with pytest.raises(ConfigError, match=r"initial_tpms must have shape \(\.\.\., 3, 3\)"):
        core.reset(np.arange(2), [0, 1], np.eye(2)[None].repeat(2, axis=0))
    with pytest.raises(ConfigError, match=r"initial_tpms must have shape \(2, 3, 3\)"):
        core.reset(np.arange(2), [0, 1], stay_tpm(3, 0.9)[None])


@pytest.fixture(scope="module")
def diverging() -> Rollout:
    """20 paper runs with a divergence threshold of 40 m: most of them diverge."""
    policy = FixedTPM(3)
    config = evaluation_config(EnvConfig(scenario="paper", divergence_error=40.0),
                               policy.env_overrides)
    return rollout(policy, config, 20, 0)


def _divergence_steps(run: Rollout) -> dict[int, int]:
    """Each diverged run's first step recorded at the cap (40 m)."""
    error = np.sqrt(run.squared_position_error)
    capped = np.isclose(error, 40.0)
    return {int(r): int(np.argmax(capped[r])) for r in np.flatnonzero(run.diverged)}


def test_a_diverged_run_records_the_cap_from_the_step_it_diverges_at(diverging: Rollout) -> None:
    """With a divergence threshold of 40 m most runs diverge; no recorded error exceeds it (the
    step at which a run diverges held its raw estimate before, 42-111 m here)."""
    run = diverging
    assert run.diverged.sum() >= 5
    error = np.sqrt(run.squared_position_error)
    assert error.max() <= 40.0 + 1e-9
    for r in np.flatnonzero(run.diverged):
        capped = np.flatnonzero(np.isclose(error[r], 40.0))
        assert capped.size and (capped == np.arange(capped[0], error.shape[1])).all()
        np.testing.assert_array_equal(run.mode_probs[r, capped], 1.0 / 3)


def test_the_nis_of_a_diverged_run_counts_up_to_the_step_before_it_diverges(
    diverging: Rollout,
) -> None:
    """The step a run diverges at is no detection of the NIS test (its NIS was counted as a 0
    there, inside the bound), nor any later one; every step before it still counts."""
    run = diverging
    steps = _divergence_steps(run)
    assert max(steps.values()) > 0
    for r, d in steps.items():
        assert run.detected[r, :d].all()  # the paper's sensor detects every step
        assert not run.detected[r, d:].any()
    assert not (run.detected & (run.nis == 0.0)).any()


def test_a_diverged_run_holds_the_velocity_error_it_diverged_with(diverging: Rollout) -> None:
    """From the step a run diverges at, its velocity error is its tracker's at that step (the
    position cap, 40/sqrt(2) m on each axis, was written into vx, vy: 28 m/s here, 3536 m/s at
    the default cap). With a fixed TPM the tracker runs the same until it diverges, so a cap it
    never reaches gives that error."""
    policy = FixedTPM(3)
    free = rollout(policy, evaluation_config(EnvConfig(scenario="paper"), policy.env_overrides),
                   20, 0)
    assert not free.diverged.any()
    velocity_error = diverging.estimate[..., 2:4] - diverging.truth[..., 2:4]
    free_error = free.estimate[..., 2:4] - free.truth[..., 2:4]
    for r, d in _divergence_steps(diverging).items():
        np.testing.assert_allclose(velocity_error[r, :d + 1], free_error[r, :d + 1], atol=1e-9)
        np.testing.assert_allclose(velocity_error[r, d:], np.broadcast_to(free_error[r, d], (
            velocity_error.shape[1] - d, 2)), atol=1e-9)


class _FailingCore:
    """Two slots, three steps of a target at (100, 0) m moving at (3, 4) m/s; slot 0's tracker
    fails at step 1: its estimate is NaN in vx and infinite in vy (the core's API gives 0 and
    ``INFINITY_STAND_IN`` for them), slot 1 tracks with a velocity error (0.5, -0.5) m/s."""

    horizon, M = 3, 2

    def __init__(self, config: EnvConfig, n: int) -> None:
        self.truth = np.tile(np.array([100.0, 0.0, 3.0, 4.0]), (n, self.horizon + 1, 1))
        self.true_model = np.zeros((n, self.horizon), dtype=np.int64)
        self.z = self.truth[..., :2].copy()
        self.detected = np.ones((n, self.horizon + 1), dtype=bool)
        self.k = 0

    def reset(self, indices, seeds, initial_tpms=None) -> None:
        self.k = 0

    def observe(self) -> np.ndarray:
        return np.zeros((2, 1), dtype=np.float32)

    def step(self, actions, active=None) -> StepResult:
        self.k += 1
        estimate = self.truth[:, self.k] + np.array([1.0, 1.0, 0.5, -0.5])
        failed = np.array([self.k >= 2, False])
        if self.k == 2:
            estimate[0] = [0.0, 0.0, 0.0, INFINITY_STAND_IN]
        info = {
            "estimate": estimate,
            "covariance": np.tile(np.eye(4), (2, 1, 1)),
            "mode_probs": np.full((2, 2), 0.5),
            "tpm": np.tile(np.eye(2), (2, 1, 1)),
            "nis": np.ones(2),
            "detected": np.ones(2, dtype=bool),
        }
        return StepResult(self.observe(), np.zeros(2), failed, np.zeros(2, dtype=bool), info)


class _Zero:
    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.zeros((len(obs), 1)), state


def test_a_failed_trackers_velocity_is_no_stand_in() -> None:
    """A velocity entry that is not finite at the step a run diverges at holds the error of a
    zero velocity (-3, -4 m/s here), not the API's stand-in for infinity."""
    run = rollout(_Zero(), EnvConfig(), 2, 0, make_core=_FailingCore)
    velocity_error = run.estimate[..., 2:4] - run.truth[..., 2:4]
    np.testing.assert_array_equal(velocity_error[0, 1:], [[-3.0, -4.0], [-3.0, -4.0]])
    np.testing.assert_array_equal(velocity_error[0, 0], [0.5, -0.5])
    np.testing.assert_array_equal(velocity_error[1], np.tile([0.5, -0.5], (3, 1)))
    assert run.diverged.tolist() == [True, False]
    assert run.live.tolist() == [[True, False, False], [True, True, True]]


def _replay(policy, config: EnvConfig, runs: int, seed: int) -> list[dict]:
    """What :func:`rollout` does by hand: a core of ``runs`` slots reset with seeds ``seed + r``,
    stepped with the policy's actions (only the runs not diverged), each step's info kept with
    which runs were still live after it."""
    core = TrackingCore(config, runs)
    core.reset(np.arange(runs), [seed + r for r in range(runs)])
    obs, state, alive = core.observe(), None, np.ones(runs, dtype=bool)
    steps = []
    for k in range(core.horizon):
        actions, state = policy.predict(
            obs, state=state, episode_start=np.full(runs, k == 0), deterministic=True
        )
        result = core.step(actions, active=alive.copy())
        alive = alive & ~result.terminated
        steps.append({**result.info, "live": alive.copy()})
        obs = result.obs
    return steps


def test_the_nis_counts_the_steps_the_sensor_detected_on() -> None:
    """With a detection probability of 0.8 a live run misses detections: ``detected`` is the
    sensor's detection flag of each step (``info["detected"]``) on a live run, not ``live``
    (a missed detection's NIS of 0 would count in the NIS test)."""
    policy = FixedTPM(3)
    base = EnvConfig.build({"scenario": "random", "sensor": {"detection_prob": 0.8}})
    config = evaluation_config(base, policy.env_overrides)
    run = rollout(policy, config, 4, 7)
    steps = _replay(policy, config, 4, 7)
    assert len(steps) == run.detected.shape[1]
    for k, info in enumerate(steps):
        np.testing.assert_array_equal(run.live[:, k], info["live"], f"step {k}")
        np.testing.assert_array_equal(run.detected[:, k], info["live"] & info["detected"],
                                      f"step {k}")
    missed = run.live & ~run.detected
    assert 0.1 < missed.sum() / run.live.sum() < 0.3  # about 1 - 0.8 of the live steps
    assert (run.nis[missed] == 0.0).all() and (run.nis[run.detected] > 0.0).all()


def test_an_adapting_policy_records_the_tpm_each_step_used() -> None:
    """TIP-IMM changes the TPM at every step: ``tpm[:, k]`` is the TPM step k ran with (the core's
    ``info["tpm"]`` at that step, replayed with the same actions), not the one of the step
    before."""
    policy = TIPIMM(3)
    config = evaluation_config(EnvConfig(scenario="paper"), policy.env_overrides)
    run = rollout(policy, config, 3, 11)
    steps = _replay(policy, config, 3, 11)
    assert not run.diverged.any() and len(steps) == run.tpm.shape[1]
    for k, info in enumerate(steps):
        np.testing.assert_array_equal(run.tpm[:, k], info["tpm"], f"step {k}")
    changed = np.any(run.tpm[:, 1:] != run.tpm[:, :-1], axis=(2, 3))
    assert changed.mean() > 0.5  # a TPM one step late would differ on these steps


def test_diverged_at_counts_the_steps_from_1(diverging: Rollout) -> None:
    """``diverged_at`` (the step the figures and the animation mark) is the first step recorded
    at the cap, counted 1..K as the roll-out counts them: step index ``d`` (0-based, found from
    the errors) is step ``d + 1``; a run that never diverged has none."""
    steps = _divergence_steps(diverging)
    assert steps and min(steps.values()) >= 0
    for r, d in steps.items():
        assert diverging.diverged_at(r) == d + 1
    kept = np.flatnonzero(~diverging.diverged)
    assert all(diverging.diverged_at(int(r)) is None for r in kept)


def test_the_policy_is_told_an_episode_starts_at_its_first_step_only() -> None:
    """SB3's contract: ``episode_start`` True at an episode's first step, False after (a
    windowed rule or a recurrent agent clears its memory where it is True): over K steps of R
    runs the policy sees one all-True start, then K - 1 all-False ones."""
    inner = FixedTPM(3)
    seen = []

    class Recording:
        env_overrides = inner.env_overrides

        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            seen.append(np.array(episode_start, dtype=bool))
            return inner.predict(obs, state=state, episode_start=episode_start,
                                 deterministic=deterministic)

    run = rollout(Recording(), evaluation_config(EnvConfig(), inner.env_overrides), 3, 0)
    K = run.truth.shape[1]
    assert len(seen) == K and all(s.shape == (3,) for s in seen)
    assert seen[0].all() and not np.any(seen[1:])


def test_a_starting_tpm_below_the_policys_floor_is_used_as_given() -> None:
    """``initial_tpms`` start as given even below the policy's floor: ``FixedTPM(3, 0.9)`` runs
    with ``p_min = 1e-3`` and a scale action of 1, so a starting stay of 0.999 (off-diagonal
    5e-4) would be floored to 1e-3 at its first step were ``p_min`` not lowered to 5e-4; the
    records hold the starting TPM, unchanged, at every step."""
    policy = FixedTPM(3, 0.9)
    config = evaluation_config(EnvConfig(scenario="paper"), policy.env_overrides)
    assert config.p_min == 1e-3
    start = np.array([[0.999, 5e-4, 5e-4], [5e-4, 0.999, 5e-4], [5e-4, 5e-4, 0.999]])
    run = rollout(policy, config, 2, 0, initial_tpms=start[None])
    np.testing.assert_array_equal(run.tpm, np.broadcast_to(start, run.tpm.shape))


def test_the_score_counts_every_diverged_run(diverging: Rollout) -> None:
    """``score``'s ``diverged`` is the number of runs recorded at the cap (40 m) from some step
    on, found from the errors (several here), not whether any run diverged."""
    capped = np.isclose(np.sqrt(diverging.squared_position_error), 40.0).any(axis=1)
    assert capped.sum() >= 5
    assert score(diverging)["diverged"] == int(capped.sum())
