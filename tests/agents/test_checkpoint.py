"""Checkpoints (agents/checkpoint.py): a restored model is the saved one — weights, optimizer
moments, counters, normalizer statistics, weight average, generator states — and each training
slot continues its random streams instead of replaying its first episodes."""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file
from stable_baselines3 import PPO

from agents.asymmetric import AsymmetricActorCriticPolicy
from agents.checkpoint import (
    TENSORS_FILE,
    read_checkpoint,
    restore,
    restore_streams,
    save_checkpoint,
    stream_states,
)
from agents.training import (
    WeightAverage,
    algo_kwargs,
    build_algorithm,
    find_normalizer,
    jsonable,
    load_hyperparams,
    make_training_env,
)
from imm_gym.validation import ConfigError

ENV = "imm_gym/TPMAdapt-v0"
SMALL = {"n_envs": 4, "n_steps": 32, "batch_size": 64, "n_epochs": 1, "n_timesteps": 256}


def build(params: dict, seed: int = 0) -> tuple[PPO, object]:
    """The PPO and environment stack ``train.py`` builds for ``params`` (asymmetric critic)."""
    env = make_training_env(
        ENV, params["n_envs"], seed, params["env_kwargs"], True, params["frame_stack"], 0.9, True
    )
    kwargs = algo_kwargs(params)
    kwargs["policy_kwargs"] = {**kwargs["policy_kwargs"], "critic_dims": 11, "frame_stack": 4}
    return build_algorithm(PPO, AsymmetricActorCriticPolicy, env, seed, **kwargs), env


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> SimpleNamespace:
    """A model trained 256 steps and its checkpoint (and the generator states it recorded)."""
    params = {**load_hyperparams(ENV)[0], **SMALL}
    model, env = build(params)
    swa = WeightAverage(0)
    model.learn(256)
    swa.update(model)
    directory = tmp_path_factory.mktemp("ckpt") / "latest"
    run = {"algo": "ppo", "env_id": ENV, "seed": 0, "hyperparams": jsonable(params)}
    meta = {"env_id": ENV, "seed": 0, "critic_dims": 11, "num_timesteps": model.num_timesteps}
    generators = torch.get_rng_state(), np.random.get_state()[1]  # noqa: NPY002
    save_checkpoint(directory, model, env, run, meta, swa)
    return SimpleNamespace(
        directory=directory, params=params, model=model, env=env, swa=swa, generators=generators
    )


def test_a_saved_agent_records_that_it_normalizes_its_observations(saved) -> None:
    """agent.json says whether vecnormalize.json belongs to the agent (its loader requires it
    exactly then)."""
    assert find_normalizer(saved.env) is not None
    assert json.loads((saved.directory / "agent.json").read_text())["normalize"] is True
    assert (saved.directory / "vecnormalize.json").is_file()


def test_restore_gives_back_the_saved_training_state(saved) -> None:
    directory, params, model, env, swa = (
        saved.directory,
        saved.params,
        saved.model,
        saved.env,
        saved.swa,
    )
    torch_rng, numpy_rng = saved.generators
    state = read_checkpoint(directory)
    other, other_env = build(params, seed=0)
    other_swa = WeightAverage(0)
    restore(directory, state, other, other_env, other_swa)
    for name, value in model.policy.state_dict().items():
        assert torch.equal(value, other.policy.state_dict()[name]), name
    saved_opt = model.policy.optimizer.state_dict()["state"]
    restored_opt = other.policy.optimizer.state_dict()["state"]
    assert saved_opt.keys() == restored_opt.keys() and len(saved_opt) > 0
    for index, entries in saved_opt.items():
        for key, value in entries.items():
            assert torch.equal(value, restored_opt[index][key]), (index, key)
    assert (other.num_timesteps, other._n_updates) == (model.num_timesteps, model._n_updates)
    a, b = find_normalizer(env), find_normalizer(other_env)
    for rms in ("obs_rms", "ret_rms"):
        np.testing.assert_array_equal(getattr(a, rms).mean, getattr(b, rms).mean)
        np.testing.assert_array_equal(getattr(a, rms).var, getattr(b, rms).var)
        assert getattr(a, rms).count == getattr(b, rms).count
    assert other_swa.snapshots == swa.snapshots == 1 and other_swa.last_update == swa.last_update
    for name, value in swa.average.items():
        assert torch.equal(value, other_swa.average[name])
    # the generators are those of the moment of the checkpoint, not of the fresh build
    assert torch.equal(torch.get_rng_state(), torch_rng)
    np.testing.assert_array_equal(np.random.get_state()[1], numpy_rng)  # noqa: NPY002


def test_a_resumed_slot_continues_its_streams_instead_of_replaying_them(saved) -> None:
    directory, params, env = saved.directory, saved.params, saved.env
    recorded = json.loads((directory / "resume.json").read_text())["streams"]
    core = env.unwrapped.core
    assert recorded == json.loads(json.dumps(stream_states(core)))
    fresh_env = build(params)[1]
    resumed_env = build(params)[1]
    restore_streams(resumed_env.unwrapped, recorded, directory / "resume.json")
    fresh_env.reset()  # a new run: the first episodes of the run's seeds
    resumed_env.reset()  # the resumed run: the episodes that come next
    core.reset(np.arange(core.n_envs), [None] * core.n_envs)  # the run, uninterrupted
    np.testing.assert_array_equal(resumed_env.unwrapped.core.truth, core.truth)
    np.testing.assert_array_equal(resumed_env.unwrapped.core.z, core.z)
    assert not np.array_equal(fresh_env.unwrapped.core.truth, core.truth)


def test_a_checkpoint_is_replaced_whole(saved, tmp_path) -> None:
    params, model, env, swa = saved.params, saved.model, saved.env, saved.swa
    target = tmp_path / "latest"
    run = {"algo": "ppo", "env_id": ENV, "seed": 0, "hyperparams": jsonable(params)}
    meta = {"critic_dims": 11, "num_timesteps": model.num_timesteps}
    (tmp_path / ".latest.partial").mkdir()  # left by a process killed while writing
    (tmp_path / ".latest.partial" / "junk").write_text("x")
    for _ in range(2):
        save_checkpoint(target, model, env, run, meta, swa)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["latest"]
    assert read_checkpoint(target)["num_timesteps"] == model.num_timesteps


def _truncate(directory: Path) -> None:
    file = directory / TENSORS_FILE
    file.write_bytes(file.read_bytes()[:5000])


def _edit(directory: Path, **changes: object) -> None:
    file = directory / "resume.json"
    file.write_text(json.dumps({**json.loads(file.read_text()), **changes}))


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (_truncate, f"{TENSORS_FILE}: not a readable safetensors file"),
        (lambda d: (d / "resume.json").write_text("{"), "resume.json: not valid JSON"),
        (lambda d: (d / "resume.json").write_text("[" * 100_000 + "]" * 100_000),
         r"resume.json: not valid JSON \(nested too deeply\)"),
        (lambda d: _tensors(d, lambda t: t.__setitem__("rng/torch", torch.zeros(2).to(
            torch.float8_e5m2))), f"{TENSORS_FILE}: tensor 'rng/torch' is torch.float8_e5m2"),
        (lambda d: _edit(d, seed=-1), "seed must be a non-negative integer"),
        (lambda d: _edit(d, format=2), "format 2 is not 1"),
        (lambda d: _edit(d, surprise=1), "resume.json: keys must be"),
        (lambda d: _edit(d, algo="dqn"), "algo must be one of"),
        (lambda d: _edit(d, hyperparams={"n_envs": "4"}), "n_envs must be a positive integer"),
        (lambda d: _edit(d, streams=[[{"state": 1}, {}]]), r"streams\[0\] is not two PCG64"),
        (lambda d: _edit(d, streams={}), "streams must be a list"),
        (lambda d: _edit(d, numpy_rng={"state": {}}), "numpy_rng is not an MT19937 state"),
        (lambda d: _edit(d, reward_normalizer={"mean": 0}), "reward_normalizer must be null"),
        (lambda d: _edit(d, swa={"snapshots": -1, "last_update": 0}), "swa must be null or"),
    ],
)
def test_a_damaged_checkpoint_is_refused_naming_the_file(saved, tmp_path, damage, message) -> None:
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    damage(directory)
    with pytest.raises(ConfigError, match=message):
        read_checkpoint(directory)


@pytest.mark.parametrize(
    ("change", "message"),
    [("rename", "'optimizer/0/exp_avg_sq2' is no entry of Adam's state"),
     ("drop", r"optimizer/0 holds \['exp_avg', 'step'\], Adam's state is"),
     ("step", "'optimizer/0/step' must be a scalar"),
     ("strip", r"optimizer state for 0 of \d+ parameters \(n_updates [1-9]")],
)
def test_an_incomplete_optimizer_state_is_refused_before_training(
    saved, tmp_path, change, message
) -> None:
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    file = directory / TENSORS_FILE
    tensors = load_file(file)
    if change == "rename":
        tensors["optimizer/0/exp_avg_sq2"] = tensors.pop("optimizer/0/exp_avg_sq")
    elif change == "drop":
        del tensors["optimizer/0/exp_avg_sq"]
    elif change == "strip":  # Adam would restart its moments silently
        tensors = {k: v for k, v in tensors.items() if not k.startswith("optimizer/")}
    else:
        tensors["optimizer/0/step"] = torch.ones(3)
    save_file(tensors, file)
    with pytest.raises(ConfigError, match=message):  # train.py's check of its arguments
        read_checkpoint(directory)
    state = read_checkpoint(saved.directory)
    model, env = build(saved.params)
    with pytest.raises(ConfigError, match=message):
        restore(directory, state, model, env, WeightAverage(0))


@pytest.mark.parametrize("alias", ["01", "\u0661", "+1", " 1"])
def test_an_optimizer_index_spelt_otherwise_is_refused(saved, tmp_path, alias) -> None:
    """``optimizer/01/exp_avg`` (or an Arabic-Indic one) beside ``optimizer/1/exp_avg`` read as
    parameter 1's: one of the two replaced the other silently."""
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    _tensors(directory, lambda t: t.__setitem__(
        f"optimizer/{alias}/exp_avg", torch.full_like(t["optimizer/1/exp_avg"], 1e6)))
    with pytest.raises(ConfigError, match=re.escape(f"'optimizer/{alias}/exp_avg' names no")):
        read_checkpoint(directory)


@pytest.mark.parametrize("name", ["resume.json", TENSORS_FILE])
def test_a_checkpoint_file_that_is_not_a_regular_file_is_named_so(saved, tmp_path, name) -> None:
    """A link to /dev/zero in place of a file was reported missing."""
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    (directory / name).unlink()
    (directory / name).symlink_to("/dev/zero")
    with pytest.raises(ConfigError, match=rf"{name}: not a regular file"):
        read_checkpoint(directory)


def test_streams_of_another_slot_count_are_refused(saved) -> None:
    directory, params = saved.directory, saved.params
    recorded = json.loads((directory / "resume.json").read_text())["streams"]
    env = build({**params, "n_envs": 2})[1]
    with pytest.raises(ConfigError, match="4 streams for 2 training slots"):
        restore_streams(env.unwrapped, recorded, directory / "resume.json")


def test_training_slots_start_from_the_training_seeds_not_the_held_out_ones() -> None:
    """Slot i of run seed s plays the episode of seed TRAIN_SEED_BASE + 10 000 s + i, as a
    core of one slot reset with that seed does — not held-out run s + i, which PPO's constructor
    seeds the environment with."""
    from agents.training import TRAIN_SEED_BASE
    from imm_gym.sim.core import TrackingCore

    params = {**load_hyperparams(ENV)[0], **SMALL}
    _, env = build(params, seed=3)
    env.reset()
    core = env.unwrapped.core
    for i in range(params["n_envs"]):
        for seed, same in ((TRAIN_SEED_BASE + 30_000 + i, True), (3 + i, False)):
            alone = TrackingCore(core.config, 1)
            alone.reset(np.array([0]), [seed])
            assert np.array_equal(core.truth[i], alone.truth[0]) == same, (i, seed)


def test_a_resumed_weight_average_keeps_the_step_it_began_at(saved, tmp_path) -> None:
    """A run resumed with another budget continues the mean from where it began (the start a
    fresh build computes from the new budget would mislabel it); a checkpoint written before
    the start was recorded began at its own budget's fraction."""
    state = read_checkpoint(saved.directory)
    assert state["swa"]["start"] == saved.swa.start == 0
    model, env = build(saved.params, seed=0)
    moved = WeightAverage(5_000)  # the start of a longer budget
    restore(saved.directory, state, model, env, moved)
    assert moved.start == 0 and moved.snapshots == saved.swa.snapshots
    older = tmp_path / "older"
    shutil.copytree(saved.directory, older)
    data = json.loads((older / "resume.json").read_text())
    del data["swa"]["start"], data["evaluation_config"]
    data["hyperparams"] = {**data["hyperparams"], "swa_start": 0.5, "n_timesteps": 1000}
    (older / "resume.json").write_text(json.dumps(data))
    state = read_checkpoint(older)
    assert state["evaluation_config"] is None
    restore(older, state, model, env, moved)
    assert moved.start == 500


def test_the_initial_weights_enter_no_average() -> None:
    """With ``swa_start: 0`` the first rollout starts before any update: the untrained weights
    are no update's and stay out of the mean."""
    params = {**load_hyperparams(ENV)[0], **SMALL}
    model, _ = build(params)
    swa = WeightAverage(0)
    swa.update(model)
    assert swa.snapshots == 0 and swa.average == {}
    model.learn(128)
    swa.update(model)
    assert swa.snapshots == 1


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: _edit(d, env_id=5), "resume.json: env_id must be one of"),
        (lambda d: _edit(d, env_id=[ENV]), "resume.json: env_id must be one of"),
        (lambda d: _edit(d, env_id="imm_gym/Nope-v0"), "resume.json: env_id must be one of"),
        (lambda d: _edit(d, seed=2**40), r"resume.json: seed must be at most 4294967295"),
        (lambda d: _edit(d, evaluation_config={"bogus": 1}),
         r"resume.json: evaluation_config: EnvConfig: unknown key\(s\) \['bogus'\]"),
        (lambda d: _edit(d, evaluation_config={"sensor": 5}),
         "resume.json: evaluation_config: sensor must be"),
    ],
)
def test_the_run_a_checkpoint_records_is_checked_before_training(saved, tmp_path, change, message):
    """An env id of another type stopped train.py with an AttributeError; an evaluation
    configuration with an unknown key was found out after the whole budget was trained."""
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    change(directory)
    with pytest.raises(ConfigError, match=message):
        read_checkpoint(directory)


def _tensors(directory: Path, change) -> None:
    """``resume.safetensors`` of ``directory`` rewritten by ``change(tensors)``."""
    file = directory / TENSORS_FILE
    tensors = load_file(file)
    change(tensors)
    save_file(tensors, file)


def _drop_average(tensors: dict) -> None:
    for name in [k for k in tensors if k.startswith("swa/")]:
        del tensors[name]


def _half_average(tensors: dict) -> None:
    for name in [k for k in tensors if k.startswith("swa/") and tensors[k].is_floating_point()]:
        tensors[name] = tensors[name].half()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (_drop_average, r"weight average .*swa/.* missing"),
        (lambda t: t.__setitem__("swa/action_net.weight", torch.zeros(1)),
         r"'swa/action_net\.weight' is torch\.float32 \(1,\), the network"),
        (lambda t: t.__setitem__("swa/bogus", torch.zeros(2)), r"unexpected \['swa/bogus'\]"),
        (_half_average, r"'swa/action_net\.bias' is torch\.float16"),
        (lambda t: t.__setitem__("swa/mlp_extractor.index", t["swa/mlp_extractor.index"] + 1),
         r"'swa/mlp_extractor\.index' is not the network's"),
        (lambda t: t.__setitem__("bogus", torch.zeros(2)), r"'bogus' is no tensor of a checkpoint"),
    ],
)
def test_a_damaged_weight_average_is_refused_before_training(saved, tmp_path, change, message):
    """The weight average's tensors are the network's, name for name, shape, dtype: a checkpoint
    that lost them (while its snapshot count goes on) would resume a different mean; a tensor of
    another shape stopped the run at its end."""
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    _tensors(directory, change)
    with pytest.raises(ConfigError, match=f"{TENSORS_FILE}: .*{message}"):
        read_checkpoint(directory)


def test_weight_average_tensors_without_a_recorded_average_are_refused(saved, tmp_path) -> None:
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    _edit(directory, swa=None)
    with pytest.raises(ConfigError, match=f"{TENSORS_FILE}: .*weight average .*swa is null"):
        read_checkpoint(directory)


def test_a_weight_average_the_hyperparameters_keep_none_of_is_refused(saved, tmp_path) -> None:
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    hyperparams = json.loads((directory / "resume.json").read_text())["hyperparams"]
    _edit(directory, hyperparams={k: v for k, v in hyperparams.items() if k != "swa_start"})
    with pytest.raises(ConfigError, match=r"resume\.json: swa records a weight average"):
        read_checkpoint(directory)


def _optimizer(name: str, value) -> Callable[[dict], None]:
    """Every ``optimizer/<i>/<name>`` tensor replaced by ``value(tensor)``."""

    def change(tensors: dict) -> None:
        for key in [k for k in tensors if k.startswith("optimizer/") and k.endswith(f"/{name}")]:
            tensors[key] = value(tensors[key])

    return change


def _reward(**changes: object) -> Callable[[Path], None]:
    def damage(directory: Path) -> None:
        recorded = json.loads((directory / "resume.json").read_text())["reward_normalizer"]
        _edit(directory, reward_normalizer={**recorded, **changes})

    return damage


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (_reward(count=-4.0), "resume.json: reward_normalizer must be null or finite"),
        (_reward(count=0.0), "resume.json: reward_normalizer must be null or finite"),
        (_reward(mean=10**400), "resume.json: reward_normalizer must be null or finite"),
        (lambda d: _tensors(d, _optimizer("step", lambda t: torch.tensor(-3.0))),
         r"'optimizer/0/step' must be a finite count >= 0, got -3\.0"),
        (lambda d: _tensors(d, _optimizer("step", lambda t: torch.tensor(-1.0))),
         r"'optimizer/0/step' must be a finite count >= 0, got -1\.0"),
        (lambda d: _tensors(d, _optimizer("exp_avg_sq", lambda t: -t - 1.0)),
         r"'optimizer/0/exp_avg_sq' holds negative values"),
        (lambda d: _tensors(d, _optimizer("exp_avg", lambda t: t.double())),
         r"'optimizer/0/exp_avg' is torch\.float64, not torch\.float32"),
    ],
)
def test_a_checkpoint_whose_numbers_break_training_is_refused(saved, tmp_path, damage, message):
    """A reward normalizer of count <= 0 or Adam's state with a negative step or second moment
    divided by zero or took square roots of negatives (NaN) once training resumed."""
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    damage(directory)
    with pytest.raises(ConfigError, match=message):
        read_checkpoint(directory)


def test_resume_tensors_declaring_an_extra_tensor_are_refused_before_they_are_read(
    saved, tmp_path
) -> None:
    """A ``resume.safetensors`` whose header declares a tensor of a gigabyte (a hole on disk)
    beyond the checkpoint's is refused from its header, the gigabyte never allocated; so is one
    whose torch generator state is a gigabyte."""
    from declared import declare_tensor, peak_growth

    for name, message in [
        ("optimizer/0/junk", "'optimizer/0/junk' is no entry of Adam's state"),
        ("rng/torch", r"'rng/torch' is torch.float32 (268435456,), torch's generator state"),
    ]:
        directory = Path(shutil.copytree(saved.directory, tmp_path / name.replace("/", "_")))
        file = directory / TENSORS_FILE
        if name == "rng/torch":
            _tensors(directory, lambda t: t.pop("rng/torch"))
        declare_tensor(file, name, 2**30)
        growth, refusal = peak_growth(
            "from pathlib import Path; from agents.checkpoint import read_checkpoint; "
            f"read_checkpoint(Path({str(saved.directory)!r}))",
            f"read_checkpoint(Path({str(directory)!r}))",
        )
        assert f"{TENSORS_FILE}: {message}" in refusal
        assert growth < 100 * 2**20, f"{name}: {growth / 2**20:.0f} MiB"


@pytest.mark.parametrize(
    ("key", "value"),
    [("seed", True), ("num_timesteps", False), ("n_updates", True), ("episode_num", True),
     ("episode_num", -1), ("episode_num", "3"), ("episode_num", 2.0)],
)
def test_a_counter_that_is_no_count_is_refused(saved, tmp_path, key, value) -> None:
    """JSON's true and false are Python ints, 1 and 0: a seed or counter written as a boolean
    was taken as one; the episode count (SB3's ``_episode_num``) was not checked at all."""
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    _edit(directory, **{key: value})
    with pytest.raises(ConfigError, match=rf"resume\.json: {key} must be a non-negative integer"):
        read_checkpoint(directory)


def test_the_largest_seed_numpy_takes_is_kept(saved, tmp_path) -> None:
    """The run seeds numpy's global generator, which takes 0 to 2**32 - 1: the last one is a
    checkpoint's seed, the next is refused."""
    np.random.RandomState().seed(2**32 - 1)
    with pytest.raises(ValueError):
        np.random.RandomState().seed(2**32)
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    _edit(directory, seed=2**32 - 1)
    assert read_checkpoint(directory)["seed"] == 4_294_967_295
    _edit(directory, seed=2**32)
    with pytest.raises(ConfigError, match=r"resume\.json: seed must be at most 4294967295"):
        read_checkpoint(directory)


def test_a_reward_normalizer_of_variance_zero_is_kept(saved, tmp_path) -> None:
    """Returns all alike have variance 0 (>= 0 is the bound; SB3 divides by sqrt(var + eps)),
    a variance below it is refused."""
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    _reward(var=0.0)(directory)
    assert read_checkpoint(directory)["reward_normalizer"]["var"] == 0.0
    _reward(var=-1e-12)(directory)
    with pytest.raises(ConfigError, match=r"resume\.json: reward_normalizer must be null or"):
        read_checkpoint(directory)


@pytest.mark.parametrize("name", ["policy/action_net.weight", "optimizers/0/step", "rng/numpy"])
def test_a_tensor_under_another_prefix_is_refused(saved, tmp_path, name) -> None:
    """Only ``optimizer/...``, ``rng/torch`` and ``swa/...``: a name under another prefix, or
    ``rng/`` with another generator, is no tensor of a checkpoint."""
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    _tensors(directory, lambda t: t.__setitem__(name, torch.zeros(2)))
    with pytest.raises(ConfigError, match=re.escape(f"{TENSORS_FILE}: {name!r} is no tensor")):
        read_checkpoint(directory)


@pytest.mark.parametrize("kind", ["shape", "dtype"])
def test_a_torch_generator_state_of_another_shape_or_dtype_is_refused(saved, tmp_path, kind):
    """``rng/torch`` is refused when either its shape or its dtype is not that of
    ``torch.get_rng_state()`` (a uint8 vector of 5056 bytes for the CPU's Mersenne Twister),
    before training, not only when both differ."""
    own = torch.get_rng_state()
    assert own.dtype == torch.uint8 and own.dim() == 1
    state = torch.zeros(7, dtype=torch.uint8) if kind == "shape" else own.float()
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    _tensors(directory, lambda t: t.__setitem__("rng/torch", state))
    with pytest.raises(ConfigError, match=rf"{TENSORS_FILE}: 'rng/torch' is torch\.\w+ \("):
        read_checkpoint(directory)


def test_a_slightly_negative_second_moment_is_refused(saved, tmp_path) -> None:
    """Adam takes the square root of ``exp_avg_sq``: one entry at -1e-6 is NaN in the first
    update, as one at -10 is."""
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))

    def dent(t: torch.Tensor) -> torch.Tensor:
        t = t.clone()
        t.view(-1)[0] = -1e-6
        return t

    _tensors(directory, _optimizer("exp_avg_sq", dent))
    assert torch.isnan(torch.sqrt(torch.tensor(-1e-6)))
    with pytest.raises(ConfigError, match=r"'optimizer/0/exp_avg_sq' holds negative values"):
        read_checkpoint(directory)


def test_one_update_needs_adams_state_none_needs_none(saved, tmp_path) -> None:
    """A run that updated its weights once has Adam's moments for every parameter (a resumed
    run without them would restart them silently); one before its first update has none."""
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    _tensors(directory, lambda t: [t.pop(k) for k in list(t) if k.startswith("optimizer/")])
    _edit(directory, n_updates=1)
    with pytest.raises(ConfigError, match=r"optimizer state for 0 of \d+ parameters \(n_updates 1"):
        read_checkpoint(directory)
    _edit(directory, n_updates=0)
    assert read_checkpoint(directory)["n_updates"] == 0


def test_restore_sets_the_recorded_episode_count(saved, tmp_path) -> None:
    """Each counter from its own entry of ``resume.json`` (the next checkpoint writes it back)."""
    directory = Path(shutil.copytree(saved.directory, tmp_path / "latest"))
    recorded = json.loads((directory / "resume.json").read_text())
    _edit(directory, episode_num=recorded["n_updates"] + 5)
    state = read_checkpoint(directory)
    model, env = build(saved.params)
    restore(directory, state, model, env, WeightAverage(0))
    assert model._episode_num == recorded["n_updates"] + 5
    assert model._n_updates == recorded["n_updates"]
    assert model.num_timesteps == recorded["num_timesteps"]


def test_a_validation_score_of_zero_is_read_back(tmp_path) -> None:
    """An ARMSE is >= 0: 0 (a perfect track) is a score, best or in the history; below is not."""
    from agents.checkpoint import read_validation

    record = {"armse_pos": 0, "timesteps": 0, "history": [{"timesteps": 0, "armse_pos": 0.0}]}
    file = tmp_path / "validation.json"
    file.write_text(json.dumps(record))
    assert read_validation(file) == record
    file.write_text(json.dumps({**record, "armse_pos": -0.5}))
    with pytest.raises(ConfigError, match="armse_pos must be null or a finite number >= 0"):
        read_validation(file)


@pytest.mark.parametrize(
    "content",
    ['{"armse_pos": 1.0, "timesteps": 1.5}', '{"armse_pos": 1.0, "timesteps": true}',
     '{"armse_pos": 1.0, "history": [{"timesteps": 5, "armse_pos": 1.0, "step": 5}]}'],
)
def test_a_validation_record_of_another_shape_is_refused(content, tmp_path) -> None:
    """A step count that is not an integer, or a history entry with a key besides
    ``timesteps`` and ``armse_pos`` (a misspelt or foreign record), is refused naming the file."""
    from agents.checkpoint import read_validation

    file = tmp_path / "validation.json"
    file.write_text(content)
    with pytest.raises(ConfigError, match=re.escape(f"{file}: ")):
        read_validation(file)


def test_a_checkpoint_before_the_average_begins_records_none(saved, tmp_path) -> None:
    """A run whose weight average has no snapshot yet (its start not reached) writes ``swa``
    null and no ``swa/...`` tensors, and resumes; an empty average recorded would be refused."""
    params, model, env = saved.params, saved.model, saved.env
    target = tmp_path / "latest"
    run = {"algo": "ppo", "env_id": ENV, "seed": 0, "hyperparams": jsonable(params)}
    meta = {"critic_dims": 11, "num_timesteps": model.num_timesteps}
    waiting = WeightAverage(10**9)
    assert waiting.snapshots == 0
    save_checkpoint(target, model, env, run, meta, waiting)
    assert json.loads((target / "resume.json").read_text())["swa"] is None
    assert not [name for name in load_file(target / TENSORS_FILE) if name.startswith("swa/")]
    assert read_checkpoint(target)["swa"] is None


def test_a_checkpoint_records_the_episode_count_of_the_model(saved, tmp_path) -> None:
    """resume.json's ``episode_num`` is the model's episodes, not another counter (a resumed
    run would report its episodes from it)."""
    model = saved.model
    run = {"algo": "ppo", "env_id": ENV, "seed": 0, "hyperparams": jsonable(saved.params)}
    meta = {"critic_dims": 11, "num_timesteps": model.num_timesteps}
    episodes = model._episode_num
    model._episode_num = model._n_updates + 13
    try:
        save_checkpoint(tmp_path / "latest", model, saved.env, run, meta, saved.swa)
    finally:
        model._episode_num = episodes
    recorded = json.loads((tmp_path / "latest" / "resume.json").read_text())
    assert recorded["episode_num"] == recorded["n_updates"] + 13 == model._n_updates + 13


def test_fewer_streams_than_slots_are_refused_naming_the_file(saved) -> None:
    """A checkpoint's 4 streams for 8 slots: refused as a ConfigError naming resume.json, not
    the core's ValueError."""
    directory, params = saved.directory, saved.params
    recorded = json.loads((directory / "resume.json").read_text())["streams"]
    env = build({**params, "n_envs": 8})[1]
    with pytest.raises(ConfigError, match=r"resume\.json: 4 streams for 8 training slots"):
        restore_streams(env.unwrapped, recorded, directory / "resume.json")


def test_a_validation_record_with_a_misspelt_key_is_refused(tmp_path) -> None:
    """``timestep`` for ``timesteps``: refused naming the key, not read as a record without
    its step."""
    from agents.checkpoint import read_validation

    file = tmp_path / "validation.json"
    file.write_text('{"armse_pos": 1.0, "timestep": 5}')
    with pytest.raises(ConfigError, match=re.escape(f"{file}: unknown keys ['timestep']")):
        read_validation(file)
