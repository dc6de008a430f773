"""Baseline policies: the predict protocol, SB3's evaluate_policy, the rules by hand, and the
paper-scenario results of SPEC §6 (TIP-IMM beats classical IMM only with its TPM floor)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

import imm_gym  # noqa: F401  (registers the ids)
from baselines import (
    AMPIMM,
    REGISTRY,
    STAY_GRID,
    TIPIMM,
    BuildContext,
    FixedTPM,
    Registry,
    SlidingWindowTPM,
    make_baseline,
    stay_grid,
)
from baselines.amp_imm import tpm_to_logits
from imm_gym import ConfigError, EnvConfig, TrackingCore
from imm_gym.evaluation.rollout import evaluation_config, paired_bootstrap, rollout, score
from imm_gym.tracking.tip import tip_factors
from imm_gym.tracking.tpm import apply_floor, stay_tpm

PAPER = EnvConfig(scenario="paper")
#: The baselines built from the number of models alone.
UNTUNED = [name for name, entry in REGISTRY.items() if entry.cls is not None]


def _env_for(policy, env_id: str = "imm_gym/TPMAdaptPaper-v0") -> gym.Env:
    return gym.make(env_id, **policy.env_overrides)


@pytest.mark.parametrize("name", UNTUNED)
def test_predict_protocol_batched_and_single(name: str) -> None:
    policy = make_baseline(name)
    env = _env_for(policy)
    obs, _ = env.reset(seed=0)
    batch = np.stack([obs, obs, obs])
    actions, _ = policy.predict(batch, state=None, episode_start=np.ones(3, bool))
    assert actions.shape == (3, 9)
    assert np.all(np.isfinite(actions)) and np.all(np.abs(actions) <= 1.0 + 1e-12)
    single, _ = policy.predict(obs)
    assert single.shape == (9,)
    np.testing.assert_allclose(single, actions[0])
    env.step(single)


@pytest.mark.parametrize("name", UNTUNED)
def test_runs_through_sb3_evaluate_policy(name: str) -> None:
    policy = make_baseline(name)
    env = Monitor(_env_for(policy))
    mean, std = evaluate_policy(policy, env, n_eval_episodes=2, deterministic=True)
    assert np.isfinite(mean) and np.isfinite(std)


def test_registry_lists_every_shipped_baseline_in_order() -> None:
    assert list(REGISTRY) == [
        "fixed", "tip-imm", "best-fixed", "best-fixed-rows", "turn-rate-prior", "learned-prior",
        "amp-imm",
        "window", "bbsca",
    ]
    assert UNTUNED == ["fixed", "tip-imm", "amp-imm", "window"]
    assert all(REGISTRY[name].cls.name == name for name in UNTUNED)
    assert all(entry.help for entry in REGISTRY.values())
    with pytest.raises(ValueError, match="tuned on training runs"):
        make_baseline("best-fixed")
    with pytest.raises(ValueError, match="unknown baseline 'nope'"):
        make_baseline("nope")


def test_register_builds_classes_from_m_and_functions_from_the_context() -> None:
    registry = Registry()

    @registry.register("half", help="stay 1/2")
    def build_half(context: BuildContext) -> tuple[FixedTPM, dict[str, float]]:
        policy = FixedTPM(context.n_models, 0.5)
        return policy, {"train": context.train_armse(policy)}

    @registry.register("plain", help="a subclass built from M")
    class Plain(FixedTPM):
        pass

    with pytest.raises(ValueError, match="already registered"):
        registry.register("plain", help="again")(FixedTPM)
    context = BuildContext(PAPER, 7, 2, train_armse=lambda policy: policy.stay)
    assert list(registry) == ["half", "plain"] and registry["half"].cls is None
    policy, notes = registry["half"].build(context)
    assert (policy.stay, notes) == (0.5, {"train": 0.5})
    plain, notes = registry["plain"].build(context)
    assert type(plain) is Plain and plain.n_models == 3 and notes == {}
    assert Plain.name == "plain" and FixedTPM.name == "fixed"
    registry.unregister("plain")
    assert "plain" not in registry and len(registry) == 1
    assert "half" not in REGISTRY  # a registry of its own


def test_best_fixed_picks_the_lowest_training_armse_on_the_grid() -> None:
    scored: list[float] = []

    def train_armse_from(policy: FixedTPM, tpms: np.ndarray) -> np.ndarray:
        assert policy.stay is None  # the zero action from every starting TPM
        scored.extend(tpms[:, 0, 0])
        return np.abs(tpms[:, 0, 0] - 0.72)

    def no_single_runs(policy: FixedTPM) -> float:
        raise AssertionError("the search scores the grid in one roll-out")

    context = BuildContext(PAPER, 1_000_000, 40, no_single_runs, train_armse_from)
    policy, notes = REGISTRY["best-fixed"].build(context)
    assert scored == list(STAY_GRID)
    assert isinstance(policy, FixedTPM) and policy.stay == 0.7
    assert policy.env_overrides["initial_stay"] == 0.7
    assert notes["stay"] == 0.7 and notes["search"]["0.7000"] == pytest.approx(0.02)
    assert len(notes["search"]) == len(STAY_GRID)
    assert (notes["train_runs"], notes["train_seeds"]) == (40, "1000000..1000039")


@pytest.mark.parametrize("M", [2, 3, 4, 5])
def test_the_stays_searched_run_from_the_uniform_tpm_up(M) -> None:
    """``1/M`` first (the uniform TPM), then the grid's stays above it: none below ``1/M`` for two
    models, the uniform TPM for four and five; three models keep :data:`STAY_GRID`."""
    grid = stay_grid(M)
    assert grid[0] == pytest.approx(1.0 / M) and min(grid) == grid[0]
    assert list(grid[1:]) == [s for s in STAY_GRID if s > 1.0 / M + 1e-9]
    assert list(grid) == sorted(set(grid))
    if M == 3:
        assert grid == STAY_GRID


def test_best_fixed_searches_a_five_model_bank_from_its_uniform_tpm() -> None:
    scored: list[float] = []

    def train_armse_from(policy: FixedTPM, tpms: np.ndarray) -> np.ndarray:
        assert tpms.shape[1:] == (5, 5)
        scored.extend(tpms[:, 0, 0])
        return tpms[:, 0, 0]  # the lowest stay scores best

    def no_single_runs(policy: FixedTPM) -> float:
        raise AssertionError("the search scores the grid in one roll-out")

    five = EnvConfig.build({"bank": [{"kind": "cv"}, *[{"kind": "ct", "turn_rate_deg": w}
                                                       for w in (2.0, -2.0, 5.0, -5.0)]]})
    context = BuildContext(five, 1_000_000, 10, no_single_runs, train_armse_from)
    policy, notes = REGISTRY["best-fixed"].build(context)
    assert scored == pytest.approx(list(stay_grid(5)))
    assert policy.stay == pytest.approx(0.2) and "0.2000" in notes["search"]


def test_best_fixed_rows_searches_the_first_models_stay_and_the_others() -> None:
    """Every pair (a, b) of the grid scored in one roll-out; the policy holds (a, b, b)."""
    scored: list[tuple[float, float, float]] = []

    def train_armse_from(policy: FixedTPM, tpms: np.ndarray) -> np.ndarray:
        assert policy.stay is None
        stays = np.diagonal(tpms, axis1=1, axis2=2)
        scored.extend(map(tuple, stays))
        np.testing.assert_allclose(tpms.sum(axis=2), 1.0)
        return np.abs(stays[:, 0] - 0.98) + np.abs(stays[:, 1] - 0.52)

    def no_single_runs(policy: FixedTPM) -> float:
        raise AssertionError("the search scores the grid in one roll-out")

    context = BuildContext(PAPER, 1_000_000, 40, no_single_runs, train_armse_from)
    policy, notes = REGISTRY["best-fixed-rows"].build(context)
    assert scored == [(a, b, b) for a in STAY_GRID for b in STAY_GRID]
    assert isinstance(policy, FixedTPM) and policy.stay == (0.98, 0.5, 0.5)
    assert policy.env_overrides["initial_stay"] == (0.98, 0.5, 0.5)
    assert policy.env_overrides["p_min"] == pytest.approx(1e-3)
    assert notes["stays"] == [0.98, 0.5, 0.5]
    assert notes["search"]["0.9800/0.5000"] == pytest.approx(0.02)
    assert len(notes["search"]) == len(STAY_GRID) ** 2


@pytest.mark.parametrize(("sign", "stay"), [(-1.0, 0.999), (1.0, 1 / 3)], ids=["last", "first"])
def test_best_fixed_rows_finds_the_last_and_the_first_pair_of_its_grid(sign, stay) -> None:
    """The search's ends: the stickiest pair (0.999, 0.999), scored last, and the uniform TPM's
    (1/3, 1/3), scored first, each found when it scores lowest."""

    def train_armse_from(policy: FixedTPM, tpms: np.ndarray) -> np.ndarray:
        stays = np.diagonal(tpms, axis1=1, axis2=2)
        return sign * (stays[:, 0] + stays[:, 1])

    def no_single_runs(policy: FixedTPM) -> float:
        raise AssertionError("the search scores the grid in one roll-out")

    context = BuildContext(PAPER, 1_000_000, 4, no_single_runs, train_armse_from)
    policy, notes = REGISTRY["best-fixed-rows"].build(context)
    assert policy.stay == pytest.approx((stay, stay, stay), rel=1e-15)
    assert notes["stays"] == pytest.approx([stay] * 3, rel=1e-15)


def test_best_fixed_rows_holds_its_tpm_on_the_environment() -> None:
    """The found stays are the TPM of every step (the zero ``scale`` action keeps it)."""
    policy = FixedTPM(3, (0.999, 1 / 3, 1 / 3))
    env = _env_for(policy)
    obs, _ = env.reset(seed=4)
    for _ in range(5):
        action, _ = policy.predict(obs)
        obs, _, _, _, info = env.step(action)
        np.testing.assert_allclose(info["tpm"], stay_tpm(3, (0.999, 1 / 3, 1 / 3)), rtol=1e-12)


def test_fixed_policy_is_classical_imm_with_zero_reward() -> None:
    policy = FixedTPM()
    env = _env_for(policy)
    obs, _ = env.reset(seed=3)
    total, done = 0.0, False
    while not done:
        action, _ = policy.predict(obs)
        obs, reward, term, trunc, info = env.step(action)
        np.testing.assert_array_equal(info["tpm"], stay_tpm(3, 0.995))
        total += reward
        done = term or trunc
    assert total == 0.0  # the shadow tracker is the same classical IMM


def test_the_fixed_policy_keeps_the_configured_tpm_over_a_higher_floor() -> None:
    """On a base whose ``p_min`` (0.05) lies above the configured TPM's 0.0025, the classical
    IMM still runs the configured TPM at every step."""
    policy = FixedTPM()
    base = EnvConfig.build({"scenario": "paper", "parallel": True, "p_min": 0.05})
    core = TrackingCore(evaluation_config(base, policy.env_overrides), 1)
    core.reset(np.array([0]), [2])
    for _ in range(10):
        result = core.step(policy.predict(core.observe())[0])
        np.testing.assert_array_equal(result.info["tpm"][0], stay_tpm(3, 0.995))


@pytest.mark.parametrize(
    "settings",
    [
        {},
        {"reading": "intent", "alpha": 1.2, "beta": 0.8, "max_factor": 3.0, "parallel": False,
         "floor": 0.02},
    ],
)
def test_tip_policy_applies_the_rule_through_the_env(settings: dict) -> None:
    """The rule with the policy's own settings (the defaults: SPEC §6's 1.1 / 0.9, the literal
    reading, factors up to 2, the parallel bank, floor 0.05) reaches the environment's TPM."""
    rule = {"alpha": 1.1, "beta": 0.9, "reading": "literal", **settings}
    floor = settings.get("floor", 0.05)
    policy = TIPIMM(**settings)
    assert policy.env_overrides["parallel"] == settings.get("parallel", True)
    assert policy.env_overrides["max_factor"] == settings.get("max_factor", 2.0)
    cfg = EnvConfig.build({"scenario": "paper", **policy.env_overrides})
    core = TrackingCore(cfg, 1)
    core.reset(np.array([0]), [7])
    obs = core.observe()
    moved = 0
    for _ in range(60):
        before = core.tpm.copy()
        action, _ = policy.predict(obs)
        mu_now, mu_prev = obs[:, :3].astype(np.float64), obs[:, 3:6].astype(np.float64)
        factors = tip_factors(mu_now, mu_prev, rule["alpha"], rule["beta"], rule["reading"])
        expected = before * factors
        expected /= expected.sum(axis=-1, keepdims=True)
        result = core.step(action)
        obs = result.obs
        np.testing.assert_allclose(core.tpm, apply_floor(expected, floor), rtol=1e-12)
        moved += int(np.abs(core.tpm - before).max() > 1e-6)
        assert core.tpm.min() >= floor - 1e-12
        np.testing.assert_allclose(core.tpm.sum(axis=-1), 1.0, atol=1e-12)
    assert moved >= 10  # the rule moved the TPM, not only the floor held it


def test_amp_update_and_guard_by_hand() -> None:
    amp = AMPIMM()
    tpm = np.array([[[0.9, 0.05, 0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]]])
    loglik = np.log(np.array([[1.0, 2.0, 0.5]]))  # Lambda_j
    new = amp.adapt(tpm, loglik)
    d = np.array([[1, 2, 0.5], [0.5, 1, 0.25], [2, 4, 1]])  # Lambda_j / Lambda_i
    off = tpm[0] * d
    expected = off.copy()
    for i in range(3):
        expected[i, i] = 1.0 - (off[i].sum() - off[i, i])
    # row 2's diagonal 1 - 0.1 - 0.2 = 0.7 > 0.6 and row 0's 0.85: all accepted
    np.testing.assert_allclose(new[0], expected, rtol=1e-12)
    # a strong likelihood ratio pushes a diagonal below 0.6: the TPM is kept
    big = np.log(np.array([[1.0, 10.0, 1.0]]))
    np.testing.assert_array_equal(amp.adapt(tpm, big), tpm)


def test_amp_default_guard_is_seed_003s_0_6() -> None:
    """Lambda = (1, 8, 1) gives rows 0 and 2 the diagonal 1 - 8·0.05 - 0.05 = 0.55, above 0.5 but
    not above seed 003's 0.6: ``AMPIMM()`` keeps the TPM, a guard of 0.5 takes the update."""
    tpm = np.array([[[0.9, 0.05, 0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]]])
    loglik = np.log(np.array([[1.0, 8.0, 1.0]]))
    update = np.array([[0.55, 0.4, 0.05], [0.05 / 8, 1 - 0.1 / 8, 0.05 / 8], [0.05, 0.4, 0.55]])
    np.testing.assert_array_equal(AMPIMM().adapt(tpm, loglik), tpm)
    np.testing.assert_allclose(AMPIMM(guard=0.5).adapt(tpm, loglik)[0], update, rtol=1e-12)


def test_amp_policy_applies_its_update_through_the_env() -> None:
    """What the policy sets is the guarded update of the TPM the environment ran, from the
    log-likelihoods (relative to the best model's, clipped) the tracker gave: read off the
    step's info, not the observation the policy reads."""
    amp = AMPIMM()
    cfg = EnvConfig.build({"scenario": "paper", **amp.env_overrides})
    core = TrackingCore(cfg, 2)
    core.reset(np.arange(2), [3, 4])
    result = core.step(np.zeros((2, 9)) + tpm_to_logits(core.tpm, cfg.logit_scale).reshape(2, 9))
    adapted = 0
    for _ in range(60):
        before = core.tpm.copy()
        loglik = result.info["loglik"] - result.info["loglik"].max(axis=-1, keepdims=True)
        loglik = np.maximum(loglik, -cfg.loglik_clip)
        expected = apply_floor(amp.adapt(before, loglik), cfg.p_min)
        action, _ = amp.predict(result.obs)
        result = core.step(action)
        # the policy reads the TPM and the likelihoods in float32 (the observation's precision)
        np.testing.assert_allclose(core.tpm, expected, rtol=1e-6, atol=1e-9)
        adapted += int(np.abs(expected - before).max() > 1e-6)
    assert adapted >= 10  # the update moved the TPM, not only the guard kept it


def test_tpm_to_logits_round_trips_through_set_mode() -> None:
    cfg = EnvConfig(scenario="paper", action_mode="set", p_min=1e-3)
    core = TrackingCore(cfg, 1)
    core.reset(np.array([0]), [0])
    target = np.array([[[0.7, 0.2, 0.1], [0.05, 0.9, 0.05], [0.3, 0.3, 0.4]]])
    got = core.tpm_from_action(tpm_to_logits(target, cfg.logit_scale).reshape(1, -1))
    np.testing.assert_allclose(got, target, rtol=1e-12)
    # a row whose largest/smallest ratio passes exp(2 logit_scale) (an AMP update after a
    # strong likelihood ratio): the environment applies the row floored, its large entries
    # as given (the actions stay in [-1, 1])
    wide = np.array([[[0.997466, 2.5e-3, 3.39e-5], [0.05, 0.9, 0.05], [1e-6, 0.1, 0.899999]]])
    actions = tpm_to_logits(wide, cfg.logit_scale)
    np.testing.assert_array_equal(actions.max(axis=-1), 1.0)  # each row's largest entry
    got = core.tpm_from_action(np.clip(actions, -1.0, 1.0).reshape(1, -1))
    np.testing.assert_allclose(got, apply_floor(wide, cfg.p_min), rtol=1e-12)


def test_window_estimate_by_hand_and_episode_reset() -> None:
    w = SlidingWindowTPM(window=2, kappa=1.0, prior_stay=0.8)
    mu = [np.array([0.6, 0.3, 0.1]), np.array([0.5, 0.4, 0.1]), np.array([0.2, 0.7, 0.1]),
          np.array([0.1, 0.1, 0.8])]
    # an episode's first observation (mu(t) = mu(t-1) = mu0) follows no transition
    start = np.concatenate([mu[0], mu[0]])[None]
    obs = [np.concatenate([mu[k + 1], mu[k]])[None] for k in range(3)]
    prior = stay_tpm(3, 0.8)
    first, state = w.predict(start, None, np.array([True]))
    np.testing.assert_allclose(first[0], tpm_to_logits(prior[None], 4.0)[0].ravel())
    for k in range(3):
        actions, state = w.predict(obs[k], state, np.array([False]))
    # a window of 2: the transitions 1 -> 2 and 2 -> 3 (0 -> 1 has left it)
    expected = prior + np.outer(mu[1], mu[2]) + np.outer(mu[2], mu[3])
    expected /= expected.sum(axis=-1, keepdims=True)
    np.testing.assert_allclose(actions[0], tpm_to_logits(expected[None], 4.0)[0].ravel())
    # a new episode forgets the window
    fresh, _ = w.predict(start, state, np.array([True]))
    np.testing.assert_allclose(fresh[0], tpm_to_logits(prior[None], 4.0)[0].ravel())


def test_window_defaults_by_hand() -> None:
    """``SlidingWindowTPM()``: after one transition mu0 -> mu1, the TPM is
    ``5 pi0 + outer(mu0, mu1)`` row-normalised, ``pi0`` the stay-0.9 TPM (kappa 5, prior stay
    0.9), set as the row logits ``1 + (log pi - max_j log pi) / 4``."""
    mu0, mu1 = np.array([0.6, 0.3, 0.1]), np.array([0.1, 0.8, 0.1])
    w = SlidingWindowTPM()
    _, state = w.predict(np.concatenate([mu0, mu0])[None], None, np.array([True]))
    actions, _ = w.predict(np.concatenate([mu1, mu0])[None], state, np.array([False]))
    pi0 = np.array([[0.9, 0.05, 0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]])
    expected = 5.0 * pi0 + mu0[:, None] * mu1[None, :]
    expected /= expected.sum(axis=1, keepdims=True)
    logits = 1.0 + (np.log(expected) - np.log(expected).max(axis=1, keepdims=True)) / 4.0
    np.testing.assert_allclose(actions[0], logits.ravel(), rtol=1e-12)


def test_episode_start_none_continues_the_episode_as_in_sb3_contrib() -> None:
    """``episode_start=None`` is no episode start (sb3-contrib's recurrent ``predict``), except on
    the first call (``state=None``), where every slot starts."""
    w = SlidingWindowTPM(window=5, kappa=1.0, prior_stay=0.8)
    mu0 = np.full((2, 3), 1 / 3)
    seq = [
        np.array([[0.8, 0.1, 0.1], [0.1, 0.8, 0.1]]),
        np.array([[0.1, 0.8, 0.1], [0.1, 0.1, 0.8]]),
    ]
    first_none, s_none = w.predict(np.hstack([mu0, mu0]))
    first, s_explicit = w.predict(np.hstack([mu0, mu0]), None, np.ones(2, bool))
    np.testing.assert_array_equal(first_none, first)
    prev = mu0
    for mu in seq:
        obs = np.hstack([mu, prev])
        a_none, s_none = w.predict(obs, s_none)
        a_false, s_explicit = w.predict(obs, s_explicit, np.zeros(2, bool))
        np.testing.assert_array_equal(a_none, a_false)
        prev = mu
    prior = tpm_to_logits(stay_tpm(3, 0.8)[None], 4.0)[0].ravel()
    assert not np.allclose(a_none[0], prior)  # the window counted the transitions


def test_a_numpy_scalar_stay_is_one_stay() -> None:
    for stay in (np.float32(0.6), np.float64(0.6), np.int64(1)):
        policy = FixedTPM(3, stay)
        assert policy.stay == float(stay) and isinstance(policy.stay, float)
        assert policy.env_overrides["initial_stay"] == float(stay)
    assert FixedTPM(3, np.array([0.9, 0.8, 0.7])).stay == (0.9, 0.8, 0.7)


@pytest.mark.parametrize(
    ("name", "kwargs", "message"),
    [
        ("tip-imm", {"beta": 0.0}, r"beta must be in \(0.0, 1.0\), got 0.0"),
        ("tip-imm", {"beta": -0.5}, r"beta must be in \(0.0, 1.0\)"),
        ("tip-imm", {"alpha": 0.5}, r"alpha must be in \(1.0, inf\)"),
        ("tip-imm", {"reading": "intnet"}, r"reading must be one of \['literal', 'intent'\]"),
        ("tip-imm", {"floor": 0.5}, r"floor must be in \[0.0, 0.333"),
        ("tip-imm", {"max_factor": 1.05}, r"max_factor must be at least alpha and 1/beta"),
        ("window", {"window": 2.5}, r"window must be an integer in \[1, inf\), got 2.5"),
        ("window", {"kappa": 0.0}, r"kappa must be in \(0.0, inf\)"),
        ("window", {"prior_stay": 1.5}, r"prior_stay must be in \[0.0, 1.0\], got 1.5"),
        ("amp-imm", {"guard": 1.5}, r"guard must be in \[0.0, 1.0\), got 1.5"),
        ("amp-imm", {"guard": 1.0}, r"guard must be in \[0.0, 1.0\)"),
        ("amp-imm", {"loglik_clip": 0.0}, r"loglik_clip must be in \(0.0, inf\)"),
        ("fixed", {"stay": 1.5}, r"stay must be in \[0.0, 1.0\], got 1.5"),
        ("fixed", {"stay": (0.9, 0.8)}, r"stay must have 3 entries"),
    ],
)
def test_bad_parameters_are_refused_at_construction_naming_them(
    name: str, kwargs: dict, message: str
) -> None:
    """A baseline's parameter outside its range is refused when the baseline is built, as a
    ConfigError naming the parameter and its range (the command line's usage error), not at the
    first ``predict`` or never (a guard above 1 silently stopped AMP-IMM's adaptation)."""
    with pytest.raises(ConfigError, match=message):
        make_baseline(name, **kwargs)


def test_paired_bootstrap_against_explicit_resampling() -> None:
    rng = np.random.default_rng(1)
    a = rng.gamma(2.0, 100.0, (40, 30))
    b = a * 1.1 + rng.gamma(2.0, 5.0, (40, 30))
    out = paired_bootstrap(a, b, n_boot=400, seed=3)
    armse = lambda e: np.sqrt(e.mean(axis=0)).mean()  # noqa: E731
    assert out["diff"] == pytest.approx(armse(a) - armse(b))
    # relative to B, the reference the command line passes second (a is about 10 % below b)
    assert out["relative"] == pytest.approx((armse(a) - armse(b)) / armse(b), rel=1e-12)
    w = np.random.default_rng(3).multinomial(40, np.full(40, 1 / 40), size=400)
    boots = [armse(np.repeat(a, c, axis=0)) - armse(np.repeat(b, c, axis=0)) for c in w]
    assert out["low"] == pytest.approx(np.quantile(boots, 0.025), rel=1e-9)
    assert out["high"] == pytest.approx(np.quantile(boots, 0.975), rel=1e-9)
    same = paired_bootstrap(a, a, n_boot=50)
    assert same["diff"] == same["low"] == same["high"] == 0.0


@pytest.fixture(scope="module")
def paper_fixed():
    policy = FixedTPM()
    return rollout(policy, evaluation_config(PAPER, policy.env_overrides), 100, 0)


def test_paper_tip_imm_beats_classical_by_5_to_9_percent(paper_fixed) -> None:
    policy = TIPIMM()
    tip = rollout(policy, evaluation_config(PAPER, policy.env_overrides), 100, 0)
    classical = score(paper_fixed)["armse_pos"]
    assert classical == pytest.approx(18.4, rel=0.03)
    d = paired_bootstrap(tip.squared_position_error, paper_fixed.squared_position_error)
    assert -0.09 <= d["relative"] <= -0.05
    assert d["high"] < 0.0  # the CI excludes zero


@pytest.mark.parametrize("reading", ["literal", "intent"])
def test_paper_tip_imm_without_floor_loses_to_classical(paper_fixed, reading: str) -> None:
    policy = TIPIMM(floor=0.0, reading=reading)
    tip = rollout(policy, evaluation_config(PAPER, policy.env_overrides), 100, 0)
    d = paired_bootstrap(tip.squared_position_error, paper_fixed.squared_position_error)
    assert d["diff"] > 0.0 and d["low"] > 0.0


def test_uniform_tpm_is_the_best_fixed_choice_on_the_paper_scenario(paper_fixed) -> None:
    uniform = FixedTPM(stay=1 / 3)
    r = rollout(uniform, evaluation_config(PAPER, uniform.env_overrides), 100, 0)
    assert score(r)["armse_pos"] == pytest.approx(16.7, rel=0.03)
    assert score(r)["armse_pos"] < score(paper_fixed)["armse_pos"]


def test_best_fixed_rows_on_real_runs_contains_the_single_stay_search() -> None:
    """On the same training runs the pairs (a, a) score what ``best-fixed`` scores for a, so
    the per-row search is never worse on them."""
    from imm_gym.cli.policies import make_policy

    base = EnvConfig(scenario="random")
    _, _, single = make_policy("best-fixed", base, seed=5, train_runs=3)
    _, _, rows = make_policy("best-fixed-rows", base, seed=5, train_runs=3)
    assert rows["train_seeds"] == single["train_seeds"]
    for key, value in single["search"].items():
        assert rows["search"][f"{key}/{key}"] == pytest.approx(value, rel=1e-9)
    assert min(rows["search"].values()) <= min(single["search"].values())
    assert rows["search"][
        "/".join(f"{s:.4f}" for s in rows["stays"][:2])
    ] == min(rows["search"].values())
