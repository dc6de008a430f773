"""RLlib training pieces that need no Ray (run by ``make test`` too): seeds, the runner's env,
refused settings."""

from __future__ import annotations

import numpy as np
import pytest

from agents.rllib import RLlibVectorEnv, SeedLedger, make_env
from imm_gym.envs import PRESETS
from imm_gym.envs.vector import TPMAdaptVectorEnv
from imm_gym.seeding import RLLIB_SEED_BASE, RLLIB_SEED_FIELD, rllib_seed
from imm_gym.sim.actions import ActionError
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.mixture import MixtureCore

ENV_ID = "imm_gym/TPMAdapt-v0"


def test_rllib_seeds_are_distinct_and_above_every_other_range():
    tuples = [
        (s, w, i, g) for s in (0, 1, 7) for w in (0, 1, 2) for i in (0, 1, 63) for g in (0, 1)
    ]
    seeds = [rllib_seed(s, w, i, g) for s, w, i, g in tuples]
    assert len(set(seeds)) == len(tuples)
    assert min(seeds) >= RLLIB_SEED_BASE > 100_000_000 + 10_000 * 10**9
    # RLlib's own scheme (seed + w, then + i) repeats a seed across runners; this one does not
    assert rllib_seed(0, 1, 1) != rllib_seed(0, 2, 0)
    assert rllib_seed(0, 0, 1) - rllib_seed(0, 0, 0) == 1
    assert rllib_seed(0, 1, 0) - rllib_seed(0, 0, 0) == RLLIB_SEED_FIELD


@pytest.mark.parametrize(
    "args",
    [(-1, 0, 0, 0), (0, RLLIB_SEED_FIELD, 0, 0), (0, 0, RLLIB_SEED_FIELD, 0), (0, 0, 0, 1.0)],
)
def test_rllib_seed_refuses_out_of_range_fields(args):
    with pytest.raises(ValueError):
        rllib_seed(*args)


def test_ledger_gives_a_rebuilt_runner_new_seeds():
    ledger = SeedLedger(3)
    first = ledger.assign(1, 4, "node-a")
    other = ledger.assign(2, 4, "node-b")
    again = ledger.assign(1, 4, "node-a")  # runner 1 restarted: its second env
    assert first == [rllib_seed(3, 1, i, 0) for i in range(4)]
    assert again == [rllib_seed(3, 1, i, 1) for i in range(4)]
    assert len(set(first + other + again)) == 12
    assert [(r["runner"], r["generation"]) for r in ledger.records()] == [(1, 0), (2, 0), (1, 1)]


def test_runner_env_seeds_its_sub_envs_once_and_returns_no_infos():
    env = RLlibVectorEnv(3, ENV_ID)
    with pytest.raises(RuntimeError):
        env.reset(seed=0)
    seeds = [rllib_seed(0, 1, i) for i in range(3)]
    env.assign_seeds(seeds)
    obs, info = env.reset(seed=123)  # RLlib's seed is ignored
    assert info == {}
    reference = TPMAdaptVectorEnv(3, config=env.config)
    ref_obs, _ = reference.reset(seed=seeds)
    np.testing.assert_array_equal(obs, ref_obs)
    np.testing.assert_array_equal(env.core.truth, reference.core.truth)
    actions = np.zeros((3, env.core.action_dim), dtype=np.float32)
    out, ref = env.step(actions), reference.step(actions)
    assert out[4] == {} and ref[4]
    np.testing.assert_array_equal(out[0], ref[0])
    env.reset()  # a later reset continues each sub-env's streams
    reference.reset()
    np.testing.assert_array_equal(env.core.truth, reference.core.truth)


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"clip_range": "lin_0.2"}, "clip_range"),
        ({"target_kl": 0.02}, "target_kl"),
        ({"clip_range_vf": 0.1}, "clip_range_vf"),
        ({"use_sde": True}, "use_sde"),
        # RLlib always normalizes the advantages (over the iteration's batch)
        ({"normalize_advantage": False}, "normalize_advantage"),
        ({"policy_kwargs": {"net_arch": {"pi": [64], "vf": [128]}}}, "net_arch"),
        ({"policy_kwargs": {"activation_fn": "gelu"}}, "activation_fn"),
        ({"policy": "PerModelPolicy"}, "PerModelPolicy"),
        # a minibatch above an iteration's 16 x 8 samples (RLlib's configuration check)
        ({"n_envs": 8, "n_steps": 16, "batch_size": 256}, "batch_size 256"),
    ],
)
def test_rllib_refuses_what_it_has_no_equivalent_for(change, named):
    from agents.rllib import check_params
    from agents.training import load_hyperparams
    from imm_gym.validation import ConfigError

    params, _ = load_hyperparams(ENV_ID)
    check_params(params, 1)  # the default entry trains (with what is not ported said)
    with pytest.raises(ConfigError, match=named):
        check_params({**params, **change}, 1)


def test_rllib_says_what_it_trains_otherwise_than_sb3():
    """RLlib normalizes the advantages over an iteration's whole batch (SB3 over each minibatch)
    and starts from PyTorch's initialization (SB3's ``ortho_init``, on by default, is
    orthogonal): both are said for the default entry; ``ortho_init: false`` is SB3's start too."""
    from agents.rllib import NOT_PORTED, not_ported
    from agents.training import load_hyperparams

    params, _ = load_hyperparams(ENV_ID)
    said = not_ported(params)
    assert {"normalize_advantage", "ortho_init"} <= set(said)
    assert said["normalize_advantage"] == NOT_PORTED["normalize_advantage"]
    kwargs = {**params.get("policy_kwargs", {}), "ortho_init": False}
    assert "ortho_init" not in not_ported({**params, "policy_kwargs": kwargs})


def test_rllib_minibatch_may_take_every_runners_samples():
    """An iteration holds ``n_steps * n_envs`` samples of each runner (of the driver with none):
    the minibatch may be up to that, and no more."""
    from agents.rllib import check_params, iteration_samples
    from agents.training import load_hyperparams
    from imm_gym.validation import ConfigError

    params, _ = load_hyperparams(ENV_ID)
    params = {**params, "n_envs": 8, "n_steps": 16, "batch_size": 256}
    assert [iteration_samples(params, k) for k in (0, 1, 2, 3)] == [128, 128, 256, 384]
    check_params(params, 2)
    check_params(params, 3)
    for runners in (0, 1):
        with pytest.raises(ConfigError, match=f"--env-runners {runners}"):
            check_params(params, runners)


def test_runner_env_trains_a_mixture_each_part_on_its_share():
    """The default entry's env_mixture on an RLlib runner's sub-envs: slot for slot each part's
    own vector env (reset and steps, autoresets included), as the SB3 adapter's mixture."""
    from agents.training import load_hyperparams

    params, _ = load_hyperparams(ENV_ID)
    config = {"num_envs": 4, "env_id": ENV_ID, "env_kwargs": params["env_kwargs"]}
    env = make_env({**config, "env_mixture": params["env_mixture"]})  # RLlib's env creator
    assert isinstance(env.core, MixtureCore) and not hasattr(make_env(config).core, "cores")
    seeds = [rllib_seed(0, 1, i) for i in range(4)]
    env.assign_seeds(seeds)
    obs, _ = env.reset()
    parts = [env.config, EnvConfig.build({**PRESETS[ENV_ID],
                                          **params["env_mixture"][0]["env_kwargs"]})]
    references = [TPMAdaptVectorEnv(2, config=c) for c in parts]
    ref_obs = [r.reset(seed=seeds[2 * i : 2 * i + 2])[0] for i, r in enumerate(references)]
    np.testing.assert_array_equal(obs, np.concatenate(ref_obs))
    assert references[0].config.vary.active and references[1].config.bank[0].noise != "continuous"
    rng = np.random.default_rng(1)
    for _ in range(160):  # through the 150-step episodes' ends
        actions = rng.uniform(-1, 1, (4, env.core.action_dim)).astype(np.float32)
        out = env.step(actions)
        ref = [r.step(actions[2 * i : 2 * i + 2]) for i, r in enumerate(references)]
        for k in range(4):
            np.testing.assert_array_equal(out[k], np.concatenate([r[k] for r in ref]))
    with pytest.raises(ActionError):
        env.step(np.full((4, env.core.action_dim), np.nan, dtype=np.float32))


def test_a_filter_entry_that_never_varies_exports_as_a_normalizer_the_loader_takes(tmp_path):
    """``std = 0`` (a feature constant over training) gives ``var = 0``, not a rounding below
    zero; the loader's ``(x - mean) / sqrt(var + epsilon)`` is RLlib's ``(x - mean) /
    (std + 1e-6)``."""
    import json

    from agents.policy import _check_normalizer
    from agents.rllib import filter_as_normalizer

    mean = np.array([0.5, -2.0, 3.0], dtype=np.float32)
    std = np.array([0.0, 1.5, 1e-3], dtype=np.float32)
    stats = filter_as_normalizer(mean, std, 128)
    assert min(stats["var"]) >= 0.0
    file = tmp_path / "vecnormalize.json"
    file.write_text(json.dumps(stats))
    m, var, _, eps = _check_normalizer(file, 3)
    x = np.array([1.0, 1.0, 1.0])
    np.testing.assert_allclose((x - m) / np.sqrt(var + eps),
                               (x - mean) / (std + np.float32(1e-6)), rtol=1e-6)


def test_rllib_says_every_sb3_setting_of_the_entry_it_trains_without():
    """The default entry sets the asymmetric critic, the weight average and the normalization
    (its YAML: critic_state true, swa_start 0.75, normalize true) and leaves the advantage
    normalization and ortho_init at SB3's defaults (on): all five are said; without the first
    three, only the last two."""
    from agents.rllib import NOT_PORTED, not_ported
    from agents.training import load_hyperparams

    params, _ = load_hyperparams(ENV_ID)
    assert params["critic_state"] and params["swa_start"] == 0.75 and params["normalize"]
    said = not_ported(params)
    assert set(said) == {"critic_state", "swa_start", "normalize", "normalize_advantage",
                         "ortho_init"}
    assert said == {k: NOT_PORTED[k] for k in said}
    plain = {k: v for k, v in params.items() if k not in ("critic_state", "swa_start", "normalize")}
    assert set(not_ported(plain)) == {"normalize_advantage", "ortho_init"}


def test_runner_env_kwargs_override_the_preset_and_keep_its_other_fields():
    """An id whose preset the entry's ``env_kwargs`` contradict (``--env
    imm_gym/TPMAdaptPaper-v0`` trained with the default entry's ``scenario: random``): the
    runner's env has the kwargs' value; the preset's fields they leave alone stay (the parallel
    id's ``parallel``)."""
    paper = RLlibVectorEnv(2, "imm_gym/TPMAdaptPaper-v0", {"scenario": "random"})
    assert paper.config == EnvConfig.build({"scenario": "random"})
    assert paper.config != EnvConfig.build({"scenario": "paper"})
    parallel = RLlibVectorEnv(2, "imm_gym/TPMAdaptParallel-v0", {"p_min": 0.1})
    assert parallel.config.parallel and parallel.config.p_min == 0.1
