"""Baselines at settings other than their defaults, worked by hand: a window longer than two,
a ``logit_scale`` other than 4, AMP-IMM's own likelihood clip, the refusals at the edges of the
parameters' ranges."""

from __future__ import annotations

import numpy as np
import pytest

from baselines import (
    AMPIMM,
    REGISTRY,
    TIPIMM,
    BuildContext,
    FixedTPM,
    Registry,
    SlidingWindowTPM,
    stay_grid,
)
from baselines.amp_imm import tpm_to_logits
from imm_gym import ConfigError, EnvConfig, TrackingCore
from imm_gym.evaluation.rollout import evaluation_config
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.tracking.tpm import apply_floor, stay_tpm


def _set_core(policy, seed: int = 0) -> TrackingCore:
    """A one-slot core of the paper scenario with the policy's settings."""
    core = TrackingCore(EnvConfig.build({"scenario": "paper", **policy.env_overrides}), 1)
    core.reset(np.array([0]), [seed])
    return core


def test_a_window_of_three_counts_the_last_three_transitions_at_its_logit_scale() -> None:
    """Window 3, kappa 2, prior stay 0.7, logit_scale 2 after five transitions: the TPM the
    environment applies is ``2 pi0 + sum of the last three outer(mu(t-1), mu(t))``, rows
    normalised (the oldest two transitions have left the window)."""
    w = SlidingWindowTPM(window=3, kappa=2.0, prior_stay=0.7, logit_scale=2.0)
    mu = np.array(
        [
            [0.6, 0.3, 0.1],
            [0.5, 0.4, 0.1],
            [0.2, 0.7, 0.1],
            [0.1, 0.1, 0.8],
            [0.3, 0.3, 0.4],
            [0.9, 0.05, 0.05],
        ]
    )
    _, state = w.predict(np.concatenate([mu[0], mu[0]])[None], None, np.array([True]))
    for k in range(5):
        actions, state = w.predict(
            np.concatenate([mu[k + 1], mu[k]])[None], state, np.array([False])
        )
    prior = np.array([[0.7, 0.15, 0.15], [0.15, 0.7, 0.15], [0.15, 0.15, 0.7]])
    expected = 2.0 * prior
    for k in (2, 3, 4):
        expected += np.outer(mu[k], mu[k + 1])
    expected /= expected.sum(axis=1, keepdims=True)
    assert w.env_overrides["logit_scale"] == 2.0
    got = _set_core(w).tpm_from_action(actions)
    np.testing.assert_allclose(got[0], expected, rtol=1e-12)


def test_amp_imm_with_its_own_clip_and_logit_scale_applies_its_update() -> None:
    """``AMPIMM(guard=0.5, loglik_clip=3, logit_scale=5)``: the environment runs the clip and
    the logit scale of the policy, and the TPM it applies is the guarded update computed from the
    tracker's log-likelihoods (relative to the best model's, clipped to ``[-3, 0]``)."""
    amp = AMPIMM(guard=0.5, loglik_clip=3.0, logit_scale=5.0)
    core = TrackingCore(EnvConfig.build({"scenario": "paper", **amp.env_overrides}), 2)
    assert (core.config.loglik_clip, core.config.logit_scale) == (3.0, 5.0)
    core.reset(np.arange(2), [3, 4])
    # keep the initial stay-0.995 TPM: row logits 1 + log(pi / max pi) / 5
    logits = 1.0 + np.log(np.where(np.eye(3, dtype=bool), 1.0, 0.005 / 2 / 0.995)) / 5.0
    result = core.step(np.tile(logits.ravel(), (2, 1)))
    adapted = clipped = 0
    for _ in range(40):
        before = core.tpm.copy()
        relative = result.info["loglik"] - result.info["loglik"].max(axis=-1, keepdims=True)
        clipped += int(np.sum(relative < -3.0))
        lam = np.exp(np.maximum(relative, -3.0))  # Lambda_j, up to a common factor
        expected = before.copy()
        for n in range(2):
            update = before[n] * (lam[n][None, :] / lam[n][:, None])
            np.fill_diagonal(update, 0.0)
            np.fill_diagonal(update, 1.0 - update.sum(axis=1))
            if np.all(np.diag(update) > 0.5):
                expected[n] = update
        expected = apply_floor(expected, core.config.p_min)
        action, _ = amp.predict(result.obs)
        result = core.step(action)
        np.testing.assert_allclose(core.tpm, expected, rtol=1e-6, atol=1e-9)
        adapted += int(np.abs(expected - before).max() > 1e-6)
    assert adapted >= 10 and clipped >= 1


def test_a_registered_class_is_checked_by_its_settings_on_the_banks_size() -> None:
    """A class's check builds it for the configuration's bank (``cls(M)``) and applies its
    settings: one stay per model fits a two-model bank; a floor above ``1/M`` is refused."""
    registry = Registry()

    @registry.register("per-model", help="one stay per model")
    class PerModel(FixedTPM):
        def __init__(self, n_models: int = 3) -> None:
            super().__init__(n_models, (0.9,) * n_models)

    @registry.register("high-floor", help="a floor no TPM of three models can keep")
    class HighFloor(FixedTPM):
        def __init__(self, n_models: int = 3) -> None:
            super().__init__(n_models)
            self.env_overrides["p_min"] = 0.4

    two = EnvConfig.build({"bank": [{"kind": "cv"}, {"kind": "ct", "turn_rate_deg": 3.0}]})
    registry["per-model"].check(two)
    registry["per-model"].check(EnvConfig())
    with pytest.raises(ConfigError, match="p_min"):
        registry["high-floor"].check(EnvConfig())


def test_the_tuned_baselines_refuse_what_they_cannot_run_before_any_tuning() -> None:
    """``bbsca`` refuses varied conditions, the detector priors a heterogeneous bank: their
    registered checks, which the command line runs before any policy is tuned."""
    varied = EnvConfig.build({**BANK_PRESETS["cv-ct-continuous"], "vary": {"T": (0.5, 2.0)}})
    with pytest.raises(ConfigError, match="does not take varied conditions"):
        REGISTRY["bbsca"].check(varied)
    hetero = EnvConfig.build(dict(BANK_PRESETS["hetero"]))
    for name in ("turn-rate-prior", "learned-prior"):
        with pytest.raises(ConfigError, match="needs a linear bank"):
            REGISTRY[name].check(hetero)
    REGISTRY["best-fixed"].check(varied)  # a tuned baseline without a check admits both
    REGISTRY["best-fixed"].check(hetero)


def test_the_seeds_of_the_first_training_runs() -> None:
    context = BuildContext(EnvConfig(), 100, 40, train_armse=lambda policy: 0.0)
    assert context.train_seeds() == "100..139"
    assert context.train_seeds(8) == "100..107"
    assert context.train_seeds(1) == "100..100"


def test_a_class_is_built_for_the_contexts_bank() -> None:
    """``REGISTRY[name].build(context)`` of a class on a five-model bank: a policy of five
    models, acting with 25 entries."""
    five = EnvConfig.build(
        {"bank": [{"kind": "cv"}, *[{"kind": "ct", "turn_rate_deg": w} for w in (2, -2, 5, -5)]]}
    )
    context = BuildContext(five, 0, 1, train_armse=lambda policy: 0.0)
    for name in ("fixed", "window"):
        policy, notes = REGISTRY[name].build(context)
        assert (policy.n_models, notes) == (5, {})
        actions, _ = policy.predict(np.full((2, 10), 0.2), None, np.ones(2, bool))
        assert actions.shape == (2, 25)


def test_the_fixed_policy_keeps_a_configured_tpm_below_the_default_floor() -> None:
    """Stay 0.9995: entries 0.00025, below the default ``p_min`` 1e-3; ``FixedTPM()`` (no stay
    of its own) runs that TPM at every step, not one floored at 1e-3."""
    policy = FixedTPM()
    base = EnvConfig.build({"scenario": "paper", "initial_stay": 0.9995})
    core = TrackingCore(evaluation_config(base, policy.env_overrides), 1)
    core.reset(np.array([0]), [1])
    expected = np.full((3, 3), 0.00025) + np.eye(3) * (0.9995 - 0.00025)
    for _ in range(5):
        result = core.step(policy.predict(core.observe())[0])
        np.testing.assert_allclose(result.info["tpm"][0], expected, rtol=1e-12)


def test_a_fixed_stay_replaces_a_configured_sojourn() -> None:
    """On a base whose initial TPM comes from mean sojourns, ``FixedTPM(3, 0.8)`` runs the
    stay-0.8 TPM (0.1 off the diagonal), not the sojourns' TPM."""
    policy = FixedTPM(3, 0.8)
    base = EnvConfig.build({"scenario": "paper", "sojourn": [60.0, 20.0, 20.0]})
    core = TrackingCore(evaluation_config(base, policy.env_overrides), 1)
    core.reset(np.array([0]), [1])
    expected = np.full((3, 3), 0.1) + np.eye(3) * 0.7
    for _ in range(3):
        result = core.step(policy.predict(core.observe())[0])
        np.testing.assert_allclose(result.info["tpm"][0], expected, rtol=1e-12)


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: TIPIMM(beta=0.4), r"max_factor must be at least alpha and 1/beta \(2\.5\)"),
        (lambda: TIPIMM(alpha=1.5, beta=0.5, max_factor=1.8), r"1/beta \(2\.0\)"),
        (lambda: TIPIMM(floor=1 / 3), r"floor must be in \[0\.0, 0\.333\d*\)"),
        (lambda: TIPIMM(alpha=1.0), r"alpha must be in \(1\.0, inf\)"),
        (lambda: SlidingWindowTPM(window=0), r"window must be an integer in \[1, inf\)"),
        (lambda: AMPIMM(logit_scale=0.0), r"logit_scale must be in \(0\.0, inf\)"),
        (lambda: SlidingWindowTPM(logit_scale=-1.0), r"logit_scale must be in \(0\.0, inf\)"),
    ],
)
def test_the_edges_of_the_parameters_ranges_are_refused(build, message: str) -> None:
    """At the open ends of the ranges: a shrink factor ``1/beta`` the scale range cannot express,
    a floor of ``1/M`` (the uniform TPM, no rule left), ``alpha = 1`` (no growth), an empty
    window, a logit scale of zero or below."""
    with pytest.raises(ConfigError, match=message):
        build()


def test_the_amp_guard_takes_a_diagonal_above_it_only() -> None:
    """A diagonal equal to the guard is refused (seed 003: every diagonal entry *exceeds* it);
    a guard just below the diagonal takes the update."""
    tpm = np.array([[[0.8, 0.1, 0.1], [0.1, 0.8, 0.1], [0.1, 0.1, 0.8]]])
    loglik = np.log(np.array([[1.0, 2.0, 2.0]]))
    update = AMPIMM(guard=0.0).adapt(tpm, loglik)[0]
    lowest = float(np.diag(update).min())
    assert lowest == pytest.approx(0.6, rel=1e-12)  # row 0: 1 - 2 (2 * 0.1)
    np.testing.assert_array_equal(AMPIMM(guard=lowest).adapt(tpm, loglik), tpm)
    below = float(np.nextafter(lowest, 0.0))
    np.testing.assert_array_equal(AMPIMM(guard=below).adapt(tpm, loglik)[0], update)


def test_predict_leaves_the_state_it_was_given_unchanged() -> None:
    """The window's state passed to ``predict`` is not overwritten: predicting twice from the
    same state, once as an episode start, gives the continued episode the window's counts."""
    w = SlidingWindowTPM(window=4, kappa=1.0, prior_stay=0.8)
    mu0, mu1 = np.array([0.6, 0.3, 0.1]), np.array([0.1, 0.8, 0.1])
    _, state = w.predict(np.concatenate([mu0, mu0])[None], None, np.array([True]))
    _, state = w.predict(np.concatenate([mu1, mu0])[None], state, np.array([False]))
    kept = state.copy()
    obs = np.concatenate([mu1, mu1])[None]
    w.predict(obs, state, np.array([True]))
    np.testing.assert_array_equal(state, kept)
    continued, _ = w.predict(obs, state, np.array([False]))
    expected = stay_tpm(3, 0.8) + np.outer(mu0, mu1) + np.outer(mu1, mu1)
    expected /= expected.sum(axis=1, keepdims=True)
    got = 1.0 + (np.log(expected) - np.log(expected).max(axis=1, keepdims=True)) / 4.0
    np.testing.assert_allclose(continued[0], got.ravel(), rtol=1e-12)


def test_the_searched_baselines_refuse_a_context_without_the_grid_scorer() -> None:
    """``best-fixed``, ``best-fixed-rows`` and the detector priors score their grid in one
    roll-out: a context without ``train_armse_from`` is refused by name, before any run."""
    context = BuildContext(EnvConfig(), 0, 2, train_armse=lambda policy: pytest.fail("a run"))
    for name in ("best-fixed", "best-fixed-rows", "turn-rate-prior", "learned-prior"):
        with pytest.raises(ConfigError, match="offers train_armse_from"):
            REGISTRY[name].build(context)


def test_the_stays_searched_for_three_models_are_the_documented_twelve() -> None:
    """The README's grid: 1/M (the uniform TPM) to 0.999, twelve stays for three models."""
    expected = (1 / 3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 0.999)
    assert stay_grid(3) == pytest.approx(expected, rel=1e-15)
    assert stay_grid(2) == pytest.approx(expected[2:], rel=1e-15)  # 0.5 first, no stay below


def test_the_learned_prior_searches_and_runs_with_the_learned_detector() -> None:
    """``learned-prior`` is ``turn-rate-prior`` led by the network: every candidate scored and
    the policy found read the ``learned`` detector, under their own name."""
    detectors: set[tuple[str, str]] = set()

    def train_armse_from(policy, tpms: np.ndarray) -> np.ndarray:
        detectors.add((policy.name, policy.env_overrides["detector"]))
        return np.abs(np.diagonal(tpms, axis1=1, axis2=2)[:, 0] - 0.9) + policy.share

    context = BuildContext(EnvConfig(), 0, 3, lambda policy: pytest.fail("a run"), train_armse_from)
    policy, notes = REGISTRY["learned-prior"].build(context)
    assert detectors == {("learned-prior", "learned")}
    assert (policy.name, policy.env_overrides["detector"]) == ("learned-prior", "learned")
    assert (policy.stay, policy.share) == (0.9, 0.25) == (notes["stay"], notes["share"])


def test_the_learned_prior_refuses_a_bank_its_network_does_not_read() -> None:
    """The shipped network places beliefs on three models: a two-model bank is refused for
    ``learned-prior`` and taken by ``turn-rate-prior``."""
    two = EnvConfig.build({"bank": [{"kind": "cv"}, {"kind": "ct", "turn_rate_deg": 3.0}]})
    REGISTRY["turn-rate-prior"].check(two)
    with pytest.raises(ConfigError, match="the network places beliefs on 3 models, the bank has 2"):
        REGISTRY["learned-prior"].check(two)


def test_set_actions_carry_entries_down_to_a_lower_floor() -> None:
    """With ``p_min = 1e-4`` the environment applies rows with entries 5e-4, 6e-4, 8e-4 as
    given (above exp(-8) times their row's largest, what the actions can express):
    ``tpm_to_logits`` raises no entry to a floor of its own."""
    cfg = EnvConfig(scenario="paper", action_mode="set", p_min=1e-4)
    core = TrackingCore(cfg, 1)
    core.reset(np.array([0]), [0])
    target = np.array([[[0.9987, 5e-4, 8e-4], [0.05, 0.9, 0.05], [6e-4, 0.2, 0.7994]]])
    got = core.tpm_from_action(tpm_to_logits(target, cfg.logit_scale).reshape(1, -1))
    np.testing.assert_allclose(got, target, rtol=1e-12)


@pytest.mark.parametrize("max_factor", [1.0, 0.5, "2"])
def test_a_scale_range_of_one_or_less_is_refused_naming_its_range(max_factor) -> None:
    """TIP-IMM's ``max_factor`` of 1 or less (no factor to express) or not a number is refused
    as such, before it is compared with ``alpha`` and ``1/beta``."""
    with pytest.raises(ConfigError, match=r"max_factor must be (a real number )?in \(1\.0, inf\)"):
        TIPIMM(max_factor=max_factor)
