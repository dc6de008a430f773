"""The policy shared by the models (agents/per_model.py): its layout reads every model's entries
alike, its actor is equivariant under a reordering of the models, the same weights act on a
bank of any size, and its normalizer's statistics are those of the models' pooled samples."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import torch
from helpers import train_small
from hypothesis import given, settings
from hypothesis import strategies as st

import train
from agents.network import build_policy, save_weights
from agents.per_model import (
    TiedRunningMeanStd,
    frame_groups,
    refit_normalizer,
)
from agents.policy import LearnedPolicy, load_agent
from agents.schema import check_spec
from agents.training import (
    DEFAULT_ENTRY,
    HYPERPARAMS,
    check_hyperparams,
    load_hyperparams,
    read_yaml,
)
from imm_gym import EnvConfig, TrackingCore
from imm_gym.cli.comparison import evaluate
from imm_gym.cli.policies import cannot_run
from imm_gym.cli.track import main as track_main
from imm_gym.sim.core import critic_state_size
from imm_gym.sim.features import FEATURES, model_kinds, model_turn_rates
from imm_gym.sim.model_order import frame_layout
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.tracking.models import MotionModel
from imm_gym.validation import ConfigError

#: per-model layouts of every kind ("M", "Mm", "kM") and shared blocks, as the default reads them
FEATURES_READ = ["loglik", "innovation", "shadow_probs", "turn_rate", "turn_rate_ema",
                 "prob_ema", "speed", "stay_bank_evidence", "model_turn_rate"]
DIM_Z = 2


def labels(features: list[str], M: int, dim_z: int) -> list[tuple[str, int | None, int]]:
    """Each entry of a frame as (block, model or None, entry within the model's part), written
    out from the features' declared layouts."""
    out: list[tuple[str, int | None, int]] = [("mu(t)", j, 0) for j in range(M)]
    out += [("mu(t-1)", j, 0) for j in range(M)]
    for name in features:
        f = FEATURES[name]
        size = f.size(M, dim_z)
        if f.models == "":
            out += [(name, None, i) for i in range(size)]
        elif f.models == "M":
            out += [(name, j, 0) for j in range(M)]
        elif f.models == "kM":
            out += [(name, j, k) for k in range(size // M) for j in range(M)]
        elif f.models == "Mm":
            out += [(name, j, i) for j in range(M) for i in range(dim_z)]
    return out


@settings(max_examples=30, deadline=None)
@given(M=st.integers(2, 6), dim_z=st.integers(1, 3))
def test_the_layout_gives_each_model_its_own_entries_column_by_column(M, dim_z) -> None:
    features = [*FEATURES_READ, "nis", "tracking_index", "shadow_evidence", "model_kind"]
    per_model, shared = frame_layout(features, M, dim_z)
    label = labels(features, M, dim_z)
    assert sorted([*per_model.ravel(), *shared]) == list(range(len(label)))
    for j in range(M):
        assert all(label[i][1] == j for i in per_model[j])
    for column in per_model.T:
        assert len({(label[i][0], label[i][2]) for i in column}) == 1
    assert all(label[i][1] is None for i in shared)


def test_a_block_per_pair_of_models_is_refused() -> None:
    with pytest.raises(ValueError, match="tpm"):
        frame_layout(["loglik", "tpm"], 3, DIM_Z)
    with pytest.raises(ConfigError, match=r"obs_features.*tpm"):
        frame_groups(["tpm"], 3, DIM_Z, critic=False)


def test_the_model_s_turn_rate_and_kind_say_which_model_an_entry_is() -> None:
    bank = (
        MotionModel("ct", -5.0),
        MotionModel("cv"),
        MotionModel("ct", 2.0),
        MotionModel("ca", noise="continuous", intensity=0.1),
    )
    assert model_turn_rates(bank) == pytest.approx([-1.0, 0.0, 0.4, 0.0])
    # is CA, then is CT, factor-major: the CA model is no longer read as a CV
    assert model_kinds(bank).tolist() == [0, 0, 0, 1, 1, 0, 1, 0]
    config = EnvConfig(bank=bank, obs_features=("model_kind",))
    core = TrackingCore(config, 2)
    core.reset(np.arange(2), [0, 1])
    np.testing.assert_array_equal(core.observe()[:, 8:], np.tile(model_kinds(bank), (2, 1)))


def spec_for(
    M: int, frame_stack: int = 2, critic: bool = True, vf: tuple[int, ...] = (16,)
) -> dict:
    per_model, shared = frame_layout(FEATURES_READ, M, DIM_Z)
    critic_dims = critic_state_size(M) if critic else 0
    return check_spec("test", {
        "class": "PerModelPolicy",
        "observation_size": frame_stack * (per_model.size + shared.size + critic_dims),
        "action_size": M,
        "net_arch": {"pi": [16, 16], "vf": list(vf)},
        "activation_fn": "tanh",
        "log_std_init": -1.0,
        "ortho_init": False,
        "share_features_extractor": True,
        "use_sde": False,
        "critic_dims": critic_dims,
        "frame_stack": frame_stack,
        "obs_features": FEATURES_READ,
        "dim_z": DIM_Z,
    })


def mean_action(policy, obs: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        dist = policy.get_distribution(torch.as_tensor(obs, dtype=torch.float32))
    return dist.distribution.mean.numpy()


@pytest.mark.parametrize("M", [2, 3, 5])
def test_the_actor_is_equivariant_and_blind_to_the_critics_ground_truth(M) -> None:
    torch.manual_seed(0)
    policy = build_policy(spec_for(M), "test")
    frame_stack = 2
    per_model, shared = frame_groups(FEATURES_READ, M, DIM_Z, critic=True)
    frame = per_model.size + shared.size
    rng = np.random.default_rng(1)
    obs = rng.normal(size=(4, frame_stack * frame))
    perm = rng.permutation(M)
    permuted = obs.copy()
    for f in range(frame_stack):
        permuted[:, f * frame + per_model] = obs[:, f * frame + per_model[perm]]
    a = mean_action(policy, obs)
    assert mean_action(policy, permuted) == pytest.approx(a[:, perm], abs=1e-6)
    truth = obs.copy()
    critic = frame - critic_state_size(M) + np.arange(critic_state_size(M))
    for f in range(frame_stack):
        truth[:, f * frame + critic] = rng.normal(size=(4, critic.size))
    assert mean_action(policy, truth) == pytest.approx(a, abs=1e-7)
    assert not np.allclose(mean_action(policy, obs + 0.1), a)


def tied_stats(M: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    per_model, shared = frame_groups(FEATURES_READ, M, DIM_Z, critic=True)
    mean, var = np.zeros(per_model.size + shared.size), np.zeros(per_model.size + shared.size)
    mean[per_model] = rng.normal(size=per_model.shape[1])[None]
    var[per_model] = rng.uniform(0.1, 2.0, size=per_model.shape[1])[None]
    mean[shared], var[shared] = rng.normal(size=shared.size), rng.uniform(0.1, 2.0, shared.size)
    return mean, var


@pytest.mark.parametrize("vf", [(16,), ()])
def test_every_model_duplicated_gives_every_action_twice(vf) -> None:
    """Mean pooling: a bank whose every model appears twice has the same context, so each copy
    acts as the model did in the bank of three (normalizer and frame stack included). With
    ``net_arch.vf`` empty the value head reads the whole observation: it is not carried over
    either (it was refused as a tensor depending on the number of models)."""
    torch.manual_seed(2)
    rng = np.random.default_rng(3)
    spec = spec_for(3, vf=vf)
    model = build_policy(spec, "test")
    mean, var = tied_stats(3, rng)
    agent = LearnedPolicy(model, {}, mean, var, frame_stack=2, critic_dims=critic_state_size(3),
                          spec=spec)
    twice = agent.for_models(6)
    three, _ = frame_layout(FEATURES_READ, 3, DIM_Z)
    six, shared6 = frame_layout(FEATURES_READ, 6, DIM_Z)
    _, shared3 = frame_layout(FEATURES_READ, 3, DIM_Z)
    assert twice.obs_size == six.size + shared6.size
    state3 = state6 = None
    for step in range(3):
        obs3 = rng.normal(size=(5, agent.obs_size))
        obs6 = np.zeros((5, twice.obs_size))
        obs6[:, six] = obs3[:, three[[0, 1, 2, 0, 1, 2]]]
        obs6[:, shared6] = obs3[:, shared3]
        start = np.full(5, step == 0)
        a3, state3 = agent.predict(obs3, state3, start)
        a6, state6 = twice.predict(obs6, state6, start)
        assert a6 == pytest.approx(np.concatenate([a3, a3], axis=1), abs=1e-5)
    assert agent.for_models(3) is agent


def test_the_normalizer_keeps_the_models_pooled_statistics() -> None:
    M = 4
    per_model, shared = frame_groups(FEATURES_READ, M, DIM_Z, critic=True)
    size = per_model.size + shared.size
    rms = TiedRunningMeanStd(per_model, (size,))
    rng = np.random.default_rng(4)
    batches = [rng.normal(rng.normal(size=size), rng.uniform(0.5, 3, size), (64, size))
               for _ in range(5)]
    for batch in batches:
        rms.update(batch)
    data = np.concatenate(batches)
    for column in per_model.T:
        pooled = data[:, column].ravel()
        assert rms.mean[column] == pytest.approx(pooled.mean(), abs=1e-4)
        assert rms.var[column] == pytest.approx(pooled.var(), rel=1e-3)
    assert rms.mean[shared] == pytest.approx(data[:, shared].mean(axis=0), abs=1e-4)
    assert rms.var[shared] == pytest.approx(data[:, shared].var(axis=0), rel=1e-3)
    mean, var = refit_normalizer(rms.mean, rms.var, FEATURES_READ, DIM_Z, M, 2, critic=True)
    two, shared2 = frame_groups(FEATURES_READ, 2, DIM_Z, critic=True)
    assert mean[two[1]] == pytest.approx(rms.mean[per_model[0]])
    assert var[shared2] == pytest.approx(rms.var[shared])
    untied = rms.mean.copy()
    untied[per_model[0, 0]] += 1.0
    with pytest.raises(ConfigError, match="not shared by the models"):
        refit_normalizer(untied, rms.var, FEATURES_READ, DIM_Z, M, 2, critic=True)


def test_untied_statistics_are_refused_naming_the_agent_s_normalizer(tmp_path) -> None:
    """An agent of the shipped per-model policy whose normalizer's statistics differ between
    the models cannot be carried to another bank: the message names its vecnormalize.json."""
    import shutil

    from agents import PRETRAINED_PER_MODEL
    from agents.ensemble import member_paths

    agent = shutil.copytree(member_paths(PRETRAINED_PER_MODEL)[0], tmp_path / "agent")
    meta = json.loads((agent / "agent.json").read_text())
    spec = meta["policy"]
    per_model, _ = frame_groups(spec["obs_features"], 3, spec["dim_z"], bool(meta["critic_dims"]))
    stats = json.loads((agent / "vecnormalize.json").read_text())
    stats["mean"][int(per_model[0, 0])] += 1.0
    (agent / "vecnormalize.json").write_text(json.dumps(stats))
    policy = load_agent(agent)
    message = f"{agent / 'vecnormalize.json'}: the normalizer's statistics are not shared"
    with pytest.raises(ConfigError, match=re.escape(message)):
        policy.for_models(5)


def test_a_description_without_its_layout_is_refused() -> None:
    spec = dict(spec_for(3))
    del spec["obs_features"]
    with pytest.raises(ConfigError, match=r"missing.*obs_features"):
        check_spec("agent.json: policy", spec)
    with pytest.raises(ConfigError, match="obs_features must be a list of names"):
        check_spec("agent.json: policy", {**spec_for(3), "obs_features": "loglik"})


PER_MODEL = """policy: PerModelPolicy
normalize: true
frame_stack: 2
critic_state: true
env_kwargs:
  obs_features: [loglik, innovation, shadow_probs, turn_rate, prob_ema, model_turn_rate]
  action_mode: stay
  stay_base: tracker
"""

FIVE = [
    {"kind": "cv", "noise": "continuous", "intensity": 0.1},
    {"kind": "ct", "turn_rate_deg": 2.0, "noise": "continuous", "intensity": 0.05},
    {"kind": "ct", "turn_rate_deg": -2.0, "noise": "continuous", "intensity": 0.05},
    {"kind": "ct", "turn_rate_deg": 5.0, "noise": "continuous", "intensity": 0.05},
    {"kind": "ct", "turn_rate_deg": -5.0, "noise": "continuous", "intensity": 0.05},
]


@pytest.fixture(scope="module")
def per_model_agent(tmp_path_factory):
    out = tmp_path_factory.mktemp("per_model")
    tracker = out / "tracker.yaml"
    tracker.write_text("scenario: random\n")
    argv = ["--timesteps", "256", "--no-eval", "--env-config", str(tracker)]
    assert train_small(out, *argv, extra=PER_MODEL) == 0
    return out / "seed_0" / "agent"


def test_a_trained_agent_acts_on_banks_of_other_sizes(per_model_agent) -> None:
    meta = json.loads((per_model_agent / "agent.json").read_text())
    assert meta["policy"]["class"] == "PerModelPolicy"
    stats = json.loads((per_model_agent / "vecnormalize.json").read_text())
    per_model, _ = frame_groups(meta["policy"]["obs_features"], 3, DIM_Z, critic=True)
    mean = np.asarray(stats["mean"])
    assert np.all(mean[per_model] == mean[per_model[:1]])
    results, _ = evaluate(
        [str(per_model_agent), "tip-imm"], "random", 2, 0, clairvoyant=False,
        env_config={"bank": FIVE},
    )
    row = results["policies"][str(per_model_agent)]
    assert np.isfinite(row["armse_pos"]) and "models_differ" not in row
    assert row["tracker_differs"] == ["bank"]
    two = {"bank": FIVE[:1] + FIVE[3:4]}
    results, _ = evaluate([str(per_model_agent)], "random", 2, 0, clairvoyant=False,
                          env_config=two)
    assert np.isfinite(results["policies"][str(per_model_agent)]["armse_pos"])


def test_a_resumed_run_keeps_the_statistics_tied(per_model_agent, tmp_path) -> None:
    run = per_model_agent.parents[1]
    argv = ["--timesteps", "512", "--config", str(run / "small.yml"), "--out", str(tmp_path),
            "--resume", str(run / "seed_0" / "checkpoints" / "latest"), "--no-eval",
            "--no-progress"]
    assert train.main(argv) == 0
    stats = json.loads((tmp_path / "seed_0" / "agent" / "vecnormalize.json").read_text())
    features = json.loads((per_model_agent / "agent.json").read_text())["policy"]["obs_features"]
    per_model, _ = frame_groups(features, 3, DIM_Z, critic=True)
    for key in ("mean", "var"):
        values = np.asarray(stats[key])
        assert np.all(values[per_model] == values[per_model[:1]])
    assert stats["count"] > json.loads((per_model_agent / "vecnormalize.json").read_text())[
        "count"]


@pytest.mark.parametrize("shipped", [False, True])
def test_the_agent_tracks_recorded_measurements_with_a_bank_of_five(
    per_model_agent, shipped, tmp_path, capsys
) -> None:
    config = EnvConfig.build({"bank": FIVE})
    core = TrackingCore(config, n_envs=1)
    core.reset(np.arange(1), np.array([7]))
    np.savez(tmp_path / "z.npz", z=core.z[0])
    (tmp_path / "five.yaml").write_text(json.dumps({"bank": FIVE}))
    policy = "pretrained-per-model" if shipped else str(per_model_agent)
    argv = ["--measurements", str(tmp_path / "z.npz"), "--policy", policy,
            "--env-config", str(tmp_path / "five.yaml"), "--out", str(tmp_path / "out.npz")]
    assert track_main(argv) == 0
    assert "reads the evaluated bank's models" not in capsys.readouterr().err
    with np.load(tmp_path / "out.npz") as result:
        estimate = result["estimate"]
    argv[3], argv[-1] = "fixed", str(tmp_path / "fixed.npz")
    assert track_main(argv) == 0
    with np.load(tmp_path / "fixed.npz") as result:
        assert estimate.shape == result["estimate"].shape
    assert np.all(np.isfinite(estimate))


def test_an_agent_reading_models_by_position_is_still_refused_on_another_bank(tmp_path) -> None:
    spec = {**spec_for(3), "class": "AsymmetricMlpPolicy"}
    del spec["obs_features"], spec["dim_z"]
    agent = LearnedPolicy(build_policy(spec, "test"), {}, frame_stack=2,
                          critic_dims=critic_state_size(3), spec=spec)
    assert agent.for_models(5) is agent and not agent.shares_models
    save_weights(agent.model, tmp_path)
    with pytest.raises(ConfigError, match="cannot be evaluated"):
        evaluate(["tip-imm"], "random", 1, 0, clairvoyant=False, env_config={"bank": FIVE},
                 extra={"mlp": (agent, {"obs_features": FEATURES_READ, "action_mode": "stay"})})


def test_the_policy_needs_one_action_per_model(tmp_path, capsys) -> None:
    extra = PER_MODEL.replace("action_mode: stay", "action_mode: set")
    tracker = tmp_path / "tracker.yaml"
    tracker.write_text("scenario: random\n")
    with pytest.raises(SystemExit):
        train_small(tmp_path, "--timesteps", "64", "--no-eval", "--env-config", str(tracker),
                    extra=extra)
    assert "PerModelPolicy writes one action entry per model" in capsys.readouterr().err


def test_the_per_model_configuration_adds_the_models_role_and_ca_trackers() -> None:
    """agents/hyperparams/per_model.yml, a ``--config`` file: the default entry's features with
    ``model_turn_rate`` and ``model_kind``; its second part of the slots at 0.35, and its first
    part's tracker at 0.15 twice with a CA model in place of CT(-4 °/s), then of CT(+4 °/s)."""
    default, _ = load_hyperparams(DEFAULT_ENTRY, "ppo")
    extra = check_hyperparams("per_model.yml", read_yaml(HYPERPARAMS / "per_model.yml"), "ppo",
                              complete=False)
    features = [*default["env_kwargs"]["obs_features"], "model_turn_rate", "model_kind"]
    assert extra["policy"] == "PerModelPolicy"
    assert extra["env_kwargs"]["obs_features"] == features
    (default_part,) = default["env_mixture"]
    paper, *ca = extra["env_mixture"]
    assert paper == {"share": 0.35,
                     "env_kwargs": {**default_part["env_kwargs"], "obs_features": features}}
    main = {k: v for k, v in default["env_kwargs"].items() if k != "bank"}
    cv, ct_plus, ct_minus = default["env_kwargs"]["bank"]
    for part, kept in zip(ca, (ct_plus, ct_minus), strict=True):
        assert part["share"] == 0.15
        kinds = [(m["kind"], m.get("turn_rate_deg"), m["intensity"]) for m in
                 part["env_kwargs"]["bank"]]
        assert kinds == [("cv", None, cv["intensity"]), ("ca", None, kept["intensity"]),
                         ("ct", kept["turn_rate_deg"], kept["intensity"])]
        tracker = {k: v for k, v in part["env_kwargs"].items() if k != "bank"}
        assert tracker == {**main, "obs_features": features}


def test_load_agent_reads_the_class(per_model_agent) -> None:
    agent = load_agent(per_model_agent)
    assert agent.shares_models and agent.for_models(4).model.action_space.shape == (4,)


def test_the_shipped_per_model_policy_acts_on_banks_of_any_size() -> None:
    """``pretrained-per-model``: five seeds of the policy shared by the models, shipped as data
    (a few hundred KiB each), evaluated by name on banks of two, four (with a CA model) and five
    models."""
    from agents import PRETRAINED_PER_MODEL
    from agents.ensemble import load_policy, member_paths

    size = sum(p.stat().st_size for p in PRETRAINED_PER_MODEL.rglob("*") if p.is_file())
    assert size < 5 * 1024 * 1024
    members = member_paths(PRETRAINED_PER_MODEL)
    assert len(members) == 5
    assert {load_agent(m).spec["class"] for m in members} == {"PerModelPolicy"}
    assert load_policy(PRETRAINED_PER_MODEL).shares_models
    with_ca = [FIVE[0], {"kind": "ca", "noise": "continuous", "intensity": 0.05}, *FIVE[3:]]
    for bank in (FIVE, FIVE[:1] + FIVE[3:4], with_ca):
        results, _ = evaluate(["pretrained-per-model"], "random", 2, 0, clairvoyant=False,
                              env_config={"bank": bank})
        row = results["policies"]["pretrained-per-model"]
        assert np.isfinite(row["armse_pos"]) and row["diverged"] == 0
        assert "models_differ" not in row


def test_the_shipped_mlp_policy_names_the_per_model_one_on_another_bank() -> None:
    with pytest.raises(ConfigError, match=r"'pretrained-per-model'.*reads a bank of any size"):
        evaluate(["pretrained"], "random", 1, 0, clairvoyant=False, env_config={"bank": FIVE})


def test_the_python_api_rebuilds_the_agent_for_the_bank(per_model_agent) -> None:
    """``imm_gym.run_policy`` and ``rollout`` take the agent as loaded, for a bank of five, and
    act as with the agent rebuilt for five beforehand."""
    import imm_gym
    from imm_gym.evaluation.rollout import rollout
    from imm_gym.sim.config_file import TRACKER_FIELDS

    agent = load_agent(per_model_agent)
    overrides = {k: v for k, v in agent.env_overrides.items() if k not in TRACKER_FIELDS}
    config = EnvConfig.build({"bank": FIVE}).replace(**overrides)
    core = TrackingCore(config, 2)
    core.reset(np.arange(2), [3, 4])
    loaded = imm_gym.run_policy(core.z[:, :40], agent, config, overrides={})
    rebuilt = imm_gym.run_policy(core.z[:, :40], agent.for_models(5), config, overrides={})
    assert loaded.mode_probs.shape[-1] == 5
    np.testing.assert_array_equal(loaded.estimate, rebuilt.estimate)
    runs = [rollout(policy, config, 2, 0) for policy in (agent, agent.for_models(5))]
    np.testing.assert_array_equal(runs[0].estimate, runs[1].estimate)


def test_run_policy_tracks_a_trained_policy_on_the_configured_tracker() -> None:
    """Without ``overrides``, a trained policy keeps its own settings and tracks with the
    configuration given — its bank and its sensor — not the tracker it was trained on."""
    import imm_gym
    from agents import PRETRAINED_PER_MODEL
    from agents.ensemble import load_policy

    policy = load_policy(PRETRAINED_PER_MODEL)
    core = TrackingCore(EnvConfig.build({"bank": FIVE}), 1)
    core.reset(np.arange(1), [3])
    z = core.z[:, :30]
    out = imm_gym.run_policy(z, policy, EnvConfig.build({"bank": FIVE}))
    assert out.mode_probs.shape[-1] == 5
    fine, coarse = (
        imm_gym.run_policy(z, policy, EnvConfig.build({"bank": FIVE, "sensor": {"sigma_r": s}}))
        for s in (20.0, 200.0)
    )
    assert not np.array_equal(fine.covariance, coarse.covariance)


@pytest.mark.parametrize("pi", [[], [128]])
def test_a_per_model_actor_of_fewer_than_two_layers_is_refused_before_it_is_sized(
    pi, tmp_path
) -> None:
    """The weights file's size check reads the layers too: a description the network refuses
    is that refusal (a ConfigError), never an IndexError."""
    import shutil

    from agents import PRETRAINED_PER_MODEL

    agent = tmp_path / "agent"
    shutil.copytree(PRETRAINED_PER_MODEL / "seed_0", agent)
    meta = json.loads((agent / "agent.json").read_text())
    meta["policy"]["net_arch"]["pi"] = pi
    (agent / "agent.json").write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match=r"needs two layers or more"):
        load_agent(agent)


@pytest.mark.parametrize("feature", ["model_turn_rate", "model_kind"])
def test_which_model_an_entry_is_needs_a_linear_bank(feature: str) -> None:
    """The heterogeneous bank's models (NCV, CT, CTRA) have no kind or fixed turn rate these
    features read: refused, naming the feature (every model's entries were 0, a CT and a CTRA
    model read as CV ones)."""
    with pytest.raises(ConfigError, match=rf"'{feature}' needs a linear bank"):
        EnvConfig.build({**BANK_PRESETS["hetero"], "obs_features": ("loglik", feature)})


def test_the_shipped_per_model_policy_is_not_run_on_a_heterogeneous_bank() -> None:
    """A suite leaves the shipped per-model policy out of a heterogeneous bank's case, saying
    why (it ran there reading every model as a CV one)."""
    base = EnvConfig.build({"scenario": "random", **BANK_PRESETS["hetero"]})
    reason = cannot_run("pretrained-per-model", base, 0)
    assert reason is not None and "needs a linear bank" in reason
    assert cannot_run("pretrained-per-model", EnvConfig.build({"scenario": "random"}), 0) is None


def test_gsde_is_refused_for_the_per_model_policy_when_loaded(tmp_path) -> None:
    """Its one log standard deviation (shape (1,)) is no matrix gSDE can use: an agent.json
    with ``use_sde: true`` loaded, then failed on its first action (RuntimeError)."""
    import shutil

    from agents import PRETRAINED_PER_MODEL
    from agents.ensemble import member_paths

    agent = shutil.copytree(member_paths(PRETRAINED_PER_MODEL)[0], tmp_path / "agent")
    meta = json.loads((agent / "agent.json").read_text())
    meta["policy"]["use_sde"] = True
    (agent / "agent.json").write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match=r"agent\.json: policy\.use_sde must be false for a "
                                          r"PerModelPolicy .*got true"):
        load_agent(agent)


def test_gsde_is_refused_for_the_per_model_policy_before_training(tmp_path, capsys) -> None:
    from agents.training import check_policy

    tracker = tmp_path / "tracker.yaml"
    tracker.write_text("scenario: random\n")
    with pytest.raises(SystemExit):
        train_small(tmp_path, "--timesteps", "64", "--no-eval", "--env-config", str(tracker),
                    extra=PER_MODEL + "use_sde: true\n")
    err = capsys.readouterr().err
    assert "small.yml: use_sde must be false for a PerModelPolicy" in err
    assert not (tmp_path / "seed_0").exists()
    # an entry's use_sde under a --config file's policy: the merged entry is checked
    with pytest.raises(ConfigError, match="use_sde must be false for a PerModelPolicy"):
        check_policy({"policy": "PerModelPolicy", "use_sde": True}, [])


def _hand_policy_spec(**extra) -> dict:
    """A PerModelPolicy of 3 models, 2 frames of loglik, innovation and speed (16 entries:
    mu(t), mu(t-1), loglik, innovation (2 per model), speed) and the critic's 11 entries."""
    return check_spec("test", {
        "class": "PerModelPolicy", "observation_size": 2 * (16 + 11), "action_size": 3,
        "net_arch": {"pi": [6, 5], "vf": [4]}, "activation_fn": "tanh", "critic_dims": 11,
        "frame_stack": 2, "obs_features": ["loglik", "innovation", "speed"], "dim_z": 2,
        **extra,
    })


def test_the_actor_is_the_deep_set_of_its_docstring_worked_by_hand() -> None:
    """a_j = w . psi([e_j, mean_i e_i]) + b with e_j = phi([x_j, g]), in numpy from the
    network's weights: model j's token x_j is, in each of the 2 frames of 27 entries (oldest
    first), its entries j, 3 + j, 6 + j, 9 + 2 j, 10 + 2 j written out from the frame's layout,
    g the speed (entry 15) of each frame; the critic's 11 entries are read by no model."""
    policy = build_policy(_hand_policy_spec(), "test")
    torch.manual_seed(5)
    with torch.no_grad():
        for p in policy.parameters():
            p.normal_(0.0, 0.5)
    obs = np.random.default_rng(5).normal(size=(4, 54)).astype(np.float32)
    with torch.no_grad():
        mean = policy.get_distribution(torch.as_tensor(obs)).distribution.mean.numpy()
    w = {k: v.detach().numpy().astype(np.float64) for k, v in policy.state_dict().items()}
    x = obs.astype(np.float64)
    tokens = np.stack([
        np.concatenate([x[:, [27 * f + j, 27 * f + 3 + j, 27 * f + 6 + j, 27 * f + 9 + 2 * j,
                              27 * f + 10 + 2 * j]] for f in range(2)], axis=1)
        for j in range(3)
    ], axis=1)  # (4, 3, 10)
    g = x[:, [15, 27 + 15]]
    inputs = np.concatenate([tokens, np.repeat(g[:, None, :], 3, axis=1)], axis=-1)
    e = np.tanh(inputs @ w["mlp_extractor.phi.0.weight"].T + w["mlp_extractor.phi.0.bias"])
    context = np.repeat(e.mean(axis=1, keepdims=True), 3, axis=1)
    h = np.tanh(np.concatenate([e, context], axis=-1) @ w["mlp_extractor.psi.0.weight"].T
                + w["mlp_extractor.psi.0.bias"])
    by_hand = (h @ w["action_net.linear.weight"].T)[..., 0] + w["action_net.linear.bias"]
    np.testing.assert_allclose(mean, by_hand, rtol=1e-4, atol=1e-5)


def test_the_shared_action_head_starts_small_and_the_log_std_at_log_std_init() -> None:
    """As SB3's action layer: orthogonal with gain 0.01 (a 1 x 5 orthogonal matrix has a row
    of norm 1, so 0.01 here) and a zero bias; one log standard deviation, log_std_init's, so
    every model's action has standard deviation exp(-0.7)."""
    policy = build_policy(_hand_policy_spec(log_std_init=-0.7), "test")
    weight = policy.action_net.linear.weight.detach().numpy()
    assert np.linalg.norm(weight) == pytest.approx(0.01, rel=1e-5)
    assert policy.action_net.linear.bias.detach().numpy() == pytest.approx([0.0])
    obs = torch.zeros((2, 54))
    with torch.no_grad():
        std = policy.get_distribution(obs).distribution.stddev.numpy()
    assert std == pytest.approx(np.full((2, 3), np.exp(-0.7)), rel=1e-6)


def test_the_policy_saved_by_sb3_loads_with_its_layout(tmp_path) -> None:
    """SB3's own save and load (an earlier agent's pickled format) rebuild the same network:
    the layout arguments survive, and the loaded actor's means equal the saved one's."""
    from agents.per_model import PerModelActorCriticPolicy

    policy = build_policy(_hand_policy_spec(), "test")
    policy.save(str(tmp_path / "policy.pt"))
    loaded = PerModelActorCriticPolicy.load(str(tmp_path / "policy.pt"), device="cpu")
    assert (loaded.obs_features, loaded.dim_z, loaded.frame_stack, loaded.critic_dims) == (
        ["loglik", "innovation", "speed"], 2, 2, 11)
    obs = torch.as_tensor(np.random.default_rng(2).normal(size=(3, 54)).astype(np.float32))
    with torch.no_grad():
        assert torch.equal(policy.get_distribution(obs).distribution.mean,
                           loaded.get_distribution(obs).distribution.mean)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        # 5 ground-truth entries a frame, the observation sized for them: the critic's are 11
        ({"critic_dims": 5, "observation_size": 2 * (16 + 5)},
         "critic_dims must be 0 or 11 for 3 models, got 5"),
        # one entry more or two than the 2 frames of 16 + 11 entries the layout reads
        ({"observation_size": 55},
         "a PerModelPolicy of 3 models reads 54 entries .*, the observation has 55"),
        ({"observation_size": 56},
         "a PerModelPolicy of 3 models reads 54 entries .*, the observation has 56"),
    ],
)
def test_a_description_whose_sizes_disagree_with_its_layout_is_refused(changes, message) -> None:
    """The actor reads each model's entries by their place in a frame of 16 + 11 entries: an
    observation of another size, or ground-truth entries other than the critic's 11 for 3
    models, would make it read other entries as a model's; the network is not built."""
    with pytest.raises(ConfigError, match=f"SB3 cannot build this network \\({message}"):
        build_policy(_hand_policy_spec(**changes), "test")


def test_refitting_keeps_the_actor_and_refuses_an_actor_tensor_of_another_shape() -> None:
    """A network of 3 models carried to one of 5: the actor's tensors are the trained ones, the
    critic's first layer (it reads the whole observation) the new network's; a target whose
    phi reads tokens of another width is refused naming the tensor, not filled in."""
    from agents.per_model import refit_state

    trained = build_policy(_hand_policy_spec(), "test").state_dict()
    five = _hand_policy_spec(action_size=5, observation_size=2 * (26 + 13), critic_dims=13)
    target = build_policy(five, "test").state_dict()
    out = refit_state(trained, target)
    assert torch.equal(out["mlp_extractor.phi.0.weight"], trained["mlp_extractor.phi.0.weight"])
    assert out["mlp_extractor.value_net.0.weight"] is target["mlp_extractor.value_net.0.weight"]
    wider = build_policy(_hand_policy_spec(obs_features=["loglik", "innovation"],
                                           observation_size=2 * (15 + 11)), "test").state_dict()
    with pytest.raises(ConfigError, match=r"tensor 'mlp_extractor\.phi\.0\.weight' depends on"):
        refit_state(trained, wider)


def test_the_policy_saved_by_sb3_keeps_a_three_dimensional_measurement(tmp_path) -> None:
    """dim_z 3 (an innovation of 3 entries a model: frames of 19 + 11 entries) is not the
    default 2: SB3's load rebuilds it with its own, and acts as the saved network does."""
    from agents.per_model import PerModelActorCriticPolicy

    policy = build_policy(_hand_policy_spec(dim_z=3, observation_size=2 * (19 + 11)), "test")
    policy.save(str(tmp_path / "policy.pt"))
    loaded = PerModelActorCriticPolicy.load(str(tmp_path / "policy.pt"), device="cpu")
    assert loaded.dim_z == 3
    obs = torch.as_tensor(np.random.default_rng(3).normal(size=(2, 60)).astype(np.float32))
    with torch.no_grad():
        assert torch.equal(policy.get_distribution(obs).distribution.mean,
                           loaded.get_distribution(obs).distribution.mean)
