"""What an agent's files say is what it acts in: its env id's preset under env.json, a
per-model network's frame layout equal to the environment's, ensemble members compared as they
act."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from helpers import shipped_agent

from agents import PRETRAINED_PER_MODEL
from agents.ensemble import write_ensemble
from agents.policy import load_agent
from imm_gym import EnvConfig
from imm_gym.cli.policies import agent_overrides
from imm_gym.evaluation.rollout import evaluation_config
from imm_gym.sim.config_file import tracker_of
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.validation import ConfigError


def _copy(source: Path, target: Path, file: str = "", **changes: object) -> Path:
    """A copy of an agent directory with ``changes`` written into ``file``."""
    directory = Path(shutil.copytree(source, target))
    if file:
        data = json.loads((directory / file).read_text())
        data.update(changes)
        (directory / file).write_text(json.dumps(data))
    return directory


def test_an_agent_acts_in_its_env_ids_preset(tmp_path: Path) -> None:
    """An agent trained on ``imm_gym/TPMAdaptParallel-v0`` (env.json: only the env_kwargs) is
    evaluated with that preset's parallel bank and floor, as train.py built its env."""
    agent = _copy(shipped_agent(), tmp_path / "a", "agent.json",
                  env_id="imm_gym/TPMAdaptParallel-v0")
    policy = load_agent(agent)
    assert policy.env_overrides["parallel"] is True and policy.env_overrides["p_min"] == 0.05
    base = EnvConfig.build({"scenario": "paper"})
    kept, _ = agent_overrides(policy, policy.env_overrides, base)
    config = evaluation_config(base, kept)
    assert (config.parallel, config.p_min, config.scenario) == (True, 0.05, "paper")
    # env.json's fields stay over the preset's
    assert policy.env_overrides["obs_features"] == tuple(
        json.loads((agent / "env.json").read_text())["obs_features"]
    )


@pytest.mark.parametrize("key", ["obs_features", "dim_z"])
def test_a_per_model_network_reads_the_frame_its_environment_gives(
    tmp_path: Path, key: str
) -> None:
    member = sorted(p for p in PRETRAINED_PER_MODEL.iterdir() if p.is_dir())[0]
    agent = _copy(member, tmp_path / "a")
    meta = json.loads((agent / "agent.json").read_text())
    features = meta["policy"]["obs_features"]
    if key == "obs_features":  # two features of one size swapped: the sizes still agree
        i, j = features.index("loglik"), features.index("prob_ema")
        features[i], features[j] = features[j], features[i]
    else:
        meta["policy"]["dim_z"] = 3
    (agent / "agent.json").write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match=rf"agent\.json: policy\.{key} is .* but the environment"):
        load_agent(agent)


def test_ensemble_members_are_compared_as_they_act(tmp_path: Path) -> None:
    """A member that spells out a default acts as one that leaves it out; a member whose env
    id's preset sets another floor and bank does not."""
    first = shipped_agent()
    spelled = _copy(first, tmp_path / "spelled", "env.json", p_min=EnvConfig().p_min)
    assert write_ensemble(tmp_path / "e1", [first, spelled]).is_file()
    parallel = _copy(first, tmp_path / "parallel", "agent.json",
                     env_id="imm_gym/TPMAdaptParallel-v0")
    with pytest.raises(ConfigError, match="p_min, parallel differ"):
        write_ensemble(tmp_path / "e2", [first, parallel])


def test_an_agent_trained_across_a_heterogeneous_bank_is_evaluated(tmp_path: Path) -> None:
    """A tracker of the heterogeneous bank among those an agent was trained across (its filter
    the EKF it needs): the notes rebuild each trained bank with its own filter (they built it
    with the default UKF, which that bank refuses, and the evaluation stopped)."""
    member = sorted(p for p in PRETRAINED_PER_MODEL.iterdir() if p.is_dir())[0]
    policy = load_agent(member)
    hetero = tracker_of(BANK_PRESETS["hetero"])
    assert hetero["filter"] == "ekf"
    policy.trained_across = (*policy.trained_across, hetero)
    base = EnvConfig.build({"scenario": "paper"})
    _, notes = agent_overrides(policy, policy.env_overrides, base)
    assert hetero in notes["trained_across"]


def test_episode_start_none_continues_the_frame_stack_as_in_sb3_contrib() -> None:
    """Without ``episode_start`` an agent's frames go on (only a first call starts them), as the
    rules' ``predict`` and sb3-contrib's recurrent policies read None."""
    import numpy as np

    from agents import PRETRAINED

    policy = load_agent(sorted(p for p in PRETRAINED.iterdir() if p.is_dir())[0])
    assert policy.frame_stack > 1
    obs = np.random.default_rng(0).uniform(-1.0, 1.0, (5, 3, policy.obs_size))
    first, state = policy.predict(obs[0])
    state_on = state
    for t in range(1, 5):
        omitted, state = policy.predict(obs[t], state)
        given, state_on = policy.predict(obs[t], state_on, np.zeros(3, bool))
        np.testing.assert_array_equal(omitted, given)
    fresh, _ = policy.predict(obs[4])
    assert not np.array_equal(fresh, omitted)
    again, _ = policy.predict(obs[0])
    np.testing.assert_array_equal(again, first)


@pytest.mark.parametrize("weights", ["/etc/passwd", "../../x", "/dev/zero"])
def test_a_detector_file_is_named_only_for_the_learned_detector(
    tmp_path: Path, weights: str
) -> None:
    """env.json's detector_weights named any file while the detector was not 'learned' (it
    was then neither read nor checked), and the export copied that file (``/dev/zero`` without
    end) into the exported policy: it is refused by the loader and by the export, which
    leaves nothing beside its target."""
    from agents.export import export

    agent = _copy(shipped_agent(), tmp_path / "a", "env.json", detector_weights=weights)
    assert json.loads((agent / "env.json").read_text()).get("detector", "shadow") != "learned"
    message = r"env\.json: detector_weights must be null \(absent\) unless detector is 'learned'"
    with pytest.raises(ConfigError, match=message):
        load_agent(agent)
    with pytest.raises(ConfigError, match=message):
        export(agent, tmp_path / "shipped")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a"]


def test_the_export_copies_only_a_learned_detectors_checked_file(tmp_path: Path) -> None:
    """What the export copies beside a policy as its detector: a file the learned detector has
    read as a detector network, never another (a device, a file of another kind)."""
    from agents.export import _copy_agent
    from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS

    source = shipped_agent()
    for overrides, message in [
        ({"detector": "shadow", "detector_weights": "/etc/passwd"},
         "detector_weights must be null"),
        ({"detector_weights": str(DEFAULT_WEIGHTS)}, "detector_weights must be null"),
        ({"detector": "learned", "detector_weights": "/dev/zero"}, "'/dev/zero': no such file"),
        ({"detector": "learned", "detector_weights": str(source / "agent.json")},
         "not a safetensors file"),
    ]:
        with pytest.raises(ConfigError, match=message) as err:
            _copy_agent(source, tmp_path / "copy", overrides)
        assert str(source / "env.json") in str(err.value)
        assert not (tmp_path / "copy").exists()
    _copy_agent(source, tmp_path / "copy", {"detector": "learned",
                                            "detector_weights": str(DEFAULT_WEIGHTS)})
    assert (tmp_path / "copy" / "detector.safetensors").read_bytes() == DEFAULT_WEIGHTS.read_bytes()


def test_an_agent_trained_with_an_unread_detector_file_is_written_without_it(
    tmp_path: Path,
) -> None:
    """A configuration file may name a detector network for every part of a run: an agent of
    another detector is written without it (its loader would refuse it)."""
    from agents.policy import write_env_file

    for detector, kept in (("shadow", False), ("learned", True)):
        write_env_file(tmp_path, {"detector": detector, "detector_weights": "d.safetensors"})
        written = json.loads((tmp_path / "env.json").read_text())
        assert ("detector_weights" in written) is kept


def test_the_export_takes_a_file_in_the_policy_directory_as_its_loader_does(
    tmp_path: Path,
) -> None:
    """load_agent (and the evaluation) take ``DIR/agent.json`` as ``DIR``; the export copied
    from ``agent.json/<file>`` and failed (Not a directory)."""
    from agents.export import export

    agent = shipped_agent()
    export(agent / "agent.json", tmp_path / "from_file")
    export(agent, tmp_path / "from_directory")
    for name in ("agent.json", "env.json", "policy.safetensors", "vecnormalize.json"):
        written = (tmp_path / "from_file" / name).read_bytes()
        assert written == (tmp_path / "from_directory" / name).read_bytes() == (
            agent / name).read_bytes()


def test_the_export_leaves_a_directory_named_like_its_target_alone(tmp_path: Path) -> None:
    """The export wrote into ``<target>.export`` beside the target, deleting whatever
    directory of that name was there; it writes into a fresh one of its own."""
    from agents.export import export

    mine = tmp_path / "shipped.export"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    export(shipped_agent(), tmp_path / "shipped")
    assert (mine / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shipped", "shipped.export"]
    assert load_agent(tmp_path / "shipped").obs_size == load_agent(shipped_agent()).obs_size


def test_an_env_file_of_a_large_bank_is_refused_before_the_observation_is_laid_out(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """env.json's bank of 300 models observing their TPM gives a frame of 90,600 entries: the
    loader sums the features' sizes (a bank of 30,000 models made it build 6.7 GiB of bounds
    before comparing), and refuses a bank beyond what any network reads before building the
    configuration."""
    import imm_gym.sim.features

    def bounds(*args: object) -> None:
        pytest.fail("the observation's bounds were built")

    monkeypatch.setattr(imm_gym.sim.features, "bounds", bounds)
    agent = _copy(shipped_agent(), tmp_path / "a")
    env = {"bank": [{"kind": "cv"}] * 300, "p_min": 0.0, "obs_features": ["tpm"], "shadow": "fixed"}
    (agent / "env.json").write_text(json.dumps(env))
    with pytest.raises(ConfigError, match=r"env\.json gives \d+ frames of 906\d\d entries"):
        load_agent(agent)
    from agents.policy import MAX_MODELS

    agent = _copy(agent, tmp_path / "b", "env.json", bank=[{"kind": "cv"}] * (MAX_MODELS + 1))
    with pytest.raises(ConfigError, match=rf"env\.json: bank holds {MAX_MODELS + 1} models, more "):
        load_agent(agent)


@pytest.mark.parametrize("name", ["agent.json", "policy.safetensors"])
@pytest.mark.parametrize("kind", ["directory", "/dev/zero"])
def test_an_agent_file_that_is_not_a_regular_file_is_named_so(
    tmp_path: Path, name: str, kind: str
) -> None:
    """A directory or a link to /dev/zero in place of a file was reported missing."""
    agent = _copy(shipped_agent(), tmp_path / "a")
    (agent / name).unlink()
    if kind == "directory":
        (agent / name).mkdir()
    else:
        (agent / name).symlink_to(kind)
    with pytest.raises(ConfigError, match=rf"{name}: not a regular file"):
        load_agent(agent)


def test_an_agent_recorded_as_normalizing_needs_its_normalizer(tmp_path: Path) -> None:
    """An agent copied without vecnormalize.json loaded silently and acted on raw observations;
    agent.json records whether it normalizes, and the file must be there exactly then."""
    agent = _copy(shipped_agent(), tmp_path / "a")
    assert json.loads((agent / "agent.json").read_text())["normalize"] is True
    (agent / "vecnormalize.json").unlink()
    with pytest.raises(ConfigError, match=r"vecnormalize\.json: missing, but .*agent\.json "
                       "records normalize: true"):
        load_agent(agent)
    raw = _copy(shipped_agent(), tmp_path / "raw", "agent.json", normalize=False)
    with pytest.raises(ConfigError, match=r"vecnormalize\.json: present, but .*normalize: false"):
        load_agent(raw)
    (raw / "vecnormalize.json").unlink()
    assert load_agent(raw).obs_mean is None
    with pytest.raises(ConfigError, match=r"agent\.json: normalize must be true or false"):
        load_agent(_copy(agent, tmp_path / "b", "agent.json", normalize=1))
    # an agent.json written before the field: the normalizer the directory gives, a warning
    # when there is none
    old = _copy(agent, tmp_path / "old")
    meta = json.loads((old / "agent.json").read_text())
    del meta["normalize"]
    (old / "agent.json").write_text(json.dumps(meta))
    with pytest.warns(UserWarning, match=r"does not record whether the agent normalizes"):
        assert load_agent(old).obs_mean is None
    shutil.copy(shipped_agent() / "vecnormalize.json", old)
    assert load_agent(old).obs_mean is not None


def test_a_shipped_agent_acts_as_sb3_normalizes_and_stacks_its_frames() -> None:
    """Two episodes through one state (the second flagged by ``episode_start``, as a vector
    env's reset) act as SB3's ``VecFrameStack(VecNormalize(env))`` built independently: each
    frame ``clip((o - mean) / sqrt(var + epsilon), ±clip_obs)`` with vecnormalize.json's
    statistics (the critic's entries zeros), stacked oldest first with zeros before an
    episode's first frame (SB3's ``StackedObservations``), then the network's deterministic
    action. Outliers push some entries past ``clip_obs``, so the clip is exercised."""
    import numpy as np
    from gymnasium import spaces
    from stable_baselines3.common.vec_env.stacked_observations import StackedObservations

    from imm_gym.envs.tpm_adapt import TPMAdaptEnv

    member = shipped_agent()
    policy = load_agent(member)
    stats = json.loads((member / "vecnormalize.json").read_text())
    mean, var = np.array(stats["mean"]), np.array(stats["var"])
    clip, eps = stats["clip_obs"], stats["epsilon"]
    frame = mean.size
    assert policy.frame_stack > 1 and frame == policy.obs_size + policy.critic_dims
    env = TPMAdaptEnv(EnvConfig.build({**policy.env_overrides, "sensor": {"outlier_prob": 0.1}}))
    observations, actions, starts, state = [], [], [], None
    for seed in (1, 2):
        obs, _ = env.reset(seed=seed)
        first = True
        while True:
            action, state = policy.predict(obs[None], state, np.array([first]))
            observations.append(obs)
            actions.append(action[0])
            starts.append(first)
            obs, _, terminated, truncated, _ = env.step(action[0])
            first = False
            if terminated or truncated:
                break
    full = np.concatenate(
        [np.array(observations, np.float64), np.zeros((len(observations), policy.critic_dims))], 1
    )
    raw = (full - mean) / np.sqrt(var + eps)
    assert np.any(np.abs(raw) > clip)  # the outliers reach past the clip
    normalized = np.clip(raw, -clip, clip).astype(np.float32)
    stacker = StackedObservations(
        1, policy.frame_stack, spaces.Box(-np.inf, np.inf, (frame,), np.float32)
    )
    reference = []
    for t, z in enumerate(normalized):
        if t == 0:
            stacked = stacker.reset(z[None])
        else:
            infos = [{"terminal_observation": normalized[t - 1]}] if starts[t] else [{}]
            stacked, _ = stacker.update(z[None], np.array([starts[t]]), infos)
        action, _ = policy.model.predict(stacked.copy(), deterministic=True)
        reference.append(np.clip(action[0], -1.0, 1.0))
    np.testing.assert_array_equal(np.array(actions), np.array(reference))


def _with_network(source: Path, target: Path, policy: dict, **changes: object) -> Path:
    """A copy of an agent directory whose agent.json describes the network ``policy`` (with
    ``changes`` to its other entries) and whose weights are that network's, freshly built."""
    from agents.network import build_policy, save_weights
    from agents.schema import check_spec

    directory = _copy(source, target, "agent.json", policy=policy, **changes)
    save_weights(build_policy(check_spec("test", policy), "test"), directory)
    return directory


def test_a_network_writing_another_action_size_is_refused(tmp_path: Path) -> None:
    """The shipped agent acts on a bank of 3 models with one stay logit each (env.json): its
    network rebuilt as is loads, one writing 4 entries is refused though it reads the right
    observation."""
    shipped = load_agent(shipped_agent())
    config = EnvConfig.build(shipped.env_overrides)
    assert (len(config.bank), config.action_mode) == (3, "stay")
    policy = json.loads((shipped_agent() / "agent.json").read_text())["policy"]
    assert load_agent(_with_network(shipped_agent(), tmp_path / "same", policy)).obs_size == 44
    agent = _with_network(shipped_agent(), tmp_path / "wide", {**policy, "action_size": 4})
    with pytest.raises(ConfigError, match=r"writes 4, but the environment of .*env\.json gives "
                       r"4 frames of 55 entries and takes 3"):
        load_agent(agent)


def test_a_recurrent_agent_with_critic_only_entries_is_refused(tmp_path: Path) -> None:
    """RecurrentPPO has no asymmetric critic: an LSTM network whose input holds the critic's
    entries (4 frames of 44 + 11, the sizes agreeing) would act on the zeros put in their
    place; it is refused naming critic_dims."""
    lstm = {
        "class": "MlpLstmPolicy", "observation_size": 4 * (44 + 11), "action_size": 3,
        "net_arch": [8], "activation_fn": "tanh", "lstm_hidden_size": 4, "n_lstm_layers": 1,
        "shared_lstm": False, "enable_critic_lstm": False,
    }
    agent = _with_network(shipped_agent(), tmp_path / "a", lstm, algo="recurrent-ppo")
    with pytest.raises(ConfigError, match=r"agent\.json: critic_dims 11 with algo 'recurrent-ppo'"):
        load_agent(agent)


def test_an_agent_json_without_critic_dims_has_no_critic_only_entries(tmp_path: Path) -> None:
    """``critic_dims`` may be absent (a plain MlpPolicy agent): it is 0, the network reads the
    environment's 4 frames of 44 entries, and it acts on them."""
    import numpy as np

    mlp = {"class": "MlpPolicy", "observation_size": 4 * 44, "action_size": 3, "net_arch": [8],
           "activation_fn": "tanh"}
    agent = _with_network(shipped_agent(), tmp_path / "a", mlp, normalize=False)
    (agent / "vecnormalize.json").unlink()
    meta = json.loads((agent / "agent.json").read_text())
    del meta["critic_dims"]
    (agent / "agent.json").write_text(json.dumps(meta))
    policy = load_agent(agent)
    assert (policy.critic_dims, policy.obs_size, policy.frame_stack) == (0, 44, 4)
    action, _ = policy.predict(np.zeros((2, 44)))
    assert action.shape == (2, 3)


@pytest.mark.parametrize("key", ["seed", "num_timesteps"])
def test_a_boolean_seed_or_step_count_is_refused(tmp_path: Path, key: str) -> None:
    """JSON's true is Python's 1: agent.json's seed or step count written as a boolean is
    refused, not taken as 1 (an export would name the member seed_True)."""
    agent = _copy(shipped_agent(), tmp_path / "a", "agent.json", **{key: True})
    with pytest.raises(ConfigError, match=rf"agent\.json: {key} must be an integer >= 0, got True"):
        load_agent(agent)


def test_an_unknown_key_of_the_weight_average_record_is_refused(tmp_path: Path) -> None:
    """agent.json's swa holds swa_start and snapshots only: a misspelt key with a valid count
    is refused, not recorded silently."""
    agent = _copy(shipped_agent(), tmp_path / "a", "agent.json",
                  swa={"swa_start": 3_000_000, "snapshot": 245})
    with pytest.raises(ConfigError, match=r"agent\.json: swa must map swa_start and snapshots"):
        load_agent(agent)


@pytest.mark.parametrize("key", ["count", "clip_obs", "epsilon"])
def test_a_normalizer_count_clip_or_epsilon_of_zero_is_refused(tmp_path: Path, key: str) -> None:
    """Each is positive: a clip of 0 clips every normalized entry to 0 (the agent would act
    blind), an epsilon of 0 divides by a zero variance, a count of 0 is no statistic."""
    agent = _copy(shipped_agent(), tmp_path / "a", "vecnormalize.json", **{key: 0.0})
    with pytest.raises(ConfigError, match=rf"vecnormalize\.json: {key} must be a positive number"):
        load_agent(agent)


def test_the_normalizer_divides_by_its_files_epsilon(tmp_path: Path) -> None:
    """vecnormalize.json's epsilon, not SB3's default 1e-8: an entry one above its mean with
    variance 0.25 and epsilon 0.75 normalizes to 1 / sqrt(0.25 + 0.75) = 1, and with variance 0
    to 1 / sqrt(0.75)."""
    import numpy as np

    stats = json.loads((shipped_agent() / "vecnormalize.json").read_text())
    var = np.full(len(stats["var"]), 0.25)
    var[::2] = 0.0
    agent = _copy(shipped_agent(), tmp_path / "a", "vecnormalize.json", epsilon=0.75,
                  var=var.tolist())
    policy = load_agent(agent)
    assert policy.epsilon == 0.75
    z = policy.normalize(np.array(stats["mean"])[None] + 1.0)[0]
    expected = np.where(var == 0.0, 1.0 / np.sqrt(0.75), 1.0)
    np.testing.assert_allclose(z, expected, rtol=1e-6)
