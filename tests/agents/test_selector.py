"""``agents.selector``: the selector's actions give the priors it chooses on the environment, a
saved selector loads as data and acts alike (several members on their mean prediction), the
evaluation takes it by path, and malformed directories are refused naming the file."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from agents.ensemble import load_policy
from agents.selector import (
    SELECTOR_FILE,
    StaySelector,
    load_selector,
    network,
    save_selector,
    set_action,
    stay_action,
)
from imm_gym.cli.comparison import evaluate
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.stay_bank import detector_tpm_rows
from imm_gym.tracking.tpm import apply_floor
from imm_gym.validation import ConfigError

FEATURES = ["shadow_probs", "stay_bank_evidence", "detector_belief"]
STAY_ENV: dict[str, Any] = {
    "obs_features": FEATURES, "action_mode": "stay", "stay_base": "uniform",
    "detector": "learned", "detector_share": 0.75, "logit_scale": 9.0,
}
SET_ENV: dict[str, Any] = {
    "obs_features": FEATURES, "action_mode": "set", "detector": "learned",
    "logit_scale": 10.0, "p_min": 1e-4,
}
GRID = np.array([1 / 3, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995])


def core_of(env: dict[str, Any], n: int, **changes: Any) -> TrackingCore:
    config = EnvConfig.build({**env, "obs_features": tuple(env["obs_features"]), **changes})
    core = TrackingCore(config, n)
    core.reset(np.arange(n), list(range(n)))
    return core


def stay_priors(share: float) -> np.ndarray:
    return np.stack([GRID, np.full(len(GRID), share)], axis=1)


def pair_priors() -> np.ndarray:
    return np.array([(s, v) for v in (0.0, 0.25, 1.0) for s in GRID])


@pytest.mark.parametrize("share", [0.0, 0.25, 0.75, 0.9])
def test_the_stay_action_gives_the_prior_at_the_chosen_stay(share: float) -> None:
    core = core_of(STAY_ENV, 7, detector_share=share, p_min=1e-9)  # no floor between the two
    obs = core.observe()
    for _ in range(3):
        belief = core.detector_belief.copy()
        np.testing.assert_allclose(obs[:, -3:], belief, atol=1e-6)  # observed last
        result = core.step(stay_action(GRID, belief, share, 9.0))
        np.testing.assert_allclose(
            result.info["tpm"], detector_tpm_rows(GRID, belief, share), atol=1e-9
        )
        obs = result.obs


def test_the_set_action_gives_any_stay_and_share_floored_at_p_min() -> None:
    core = core_of(SET_ENV, 21)
    priors = pair_priors()
    for _ in range(3):
        belief = core.detector_belief.copy()
        result = core.step(set_action(priors[:, 0], priors[:, 1], belief, 10.0, 1e-4))
        expected = apply_floor(detector_tpm_rows(priors[:, 0], belief, priors[:, 1]), 1e-4)
        assert expected.min() < 2e-4  # the floor is reached: share 1 at the stickiest stays
        np.testing.assert_allclose(result.info["tpm"], expected, atol=1e-9)
        assert np.all(np.diagonal(result.info["tpm"], axis1=1, axis2=2)[:, 0] >= 1 / 3 - 1e-9)


@pytest.mark.parametrize(("env", "priors"), [(STAY_ENV, stay_priors(0.75)),
                                             (SET_ENV, pair_priors())])
def test_a_saved_selector_acts_alike_and_two_act_on_their_mean(
    tmp_path: Path, env: dict[str, Any], priors: np.ndarray
) -> None:
    core = core_of(env, 6)
    obs = core.observe()
    torch.manual_seed(0)
    nets = [network(obs.shape[1], len(priors), hidden=16) for _ in range(2)]
    one = save_selector(tmp_path / "one", nets[:1], priors, env)
    two = save_selector(tmp_path / "two", nets, priors, env)
    fresh = StaySelector(nets[:1], priors, env, obs.shape[1])
    np.testing.assert_array_equal(one.predict(obs)[0], fresh.predict(obs)[0])
    x = torch.from_numpy(obs.astype(np.float32))
    with torch.no_grad():
        mean = (nets[0](x) + nets[1](x)) / 2
    np.testing.assert_array_equal(two.choose(obs), mean.argmin(1).numpy())
    assert isinstance(load_policy(tmp_path / "two"), StaySelector)  # the loaders' dispatch
    chosen = priors[two.choose(obs)]
    belief = core.detector_belief.copy()
    result = core.step(two.predict(obs)[0])
    expected = detector_tpm_rows(chosen[:, 0], belief, chosen[:, 1])
    np.testing.assert_allclose(result.info["tpm"], expected, atol=1e-3)  # the p_min floor


def test_networks_of_different_widths_are_refused_before_anything_is_written(
    tmp_path: Path,
) -> None:
    obs_size = core_of(STAY_ENV, 1).observe().shape[1]
    nets = [network(obs_size, len(GRID), hidden=h) for h in (8, 16)]
    with pytest.raises(ConfigError, match=r"different widths \[8, 16\]"):
        save_selector(tmp_path / "mixed", nets, stay_priors(0.75), STAY_ENV)
    assert not (tmp_path / "mixed").exists()


@pytest.mark.parametrize("policy_file", ["agent.json", "ensemble.json"])
def test_a_selector_is_not_written_into_another_policys_directory(
    tmp_path: Path, policy_file: str
) -> None:
    """save_selector wrote selector.json beside an agent's or an ensemble's file, a directory
    that then loaded one policy for the other; it is refused, the directory left as it was."""
    obs_size = core_of(STAY_ENV, 1).observe().shape[1]
    directory = tmp_path / "taken"
    directory.mkdir()
    (directory / policy_file).write_text("{}")
    with pytest.raises(ConfigError, match=rf"taken: holds {policy_file}, a policy of its own: "
                                          "a selector's directory must hold neither"):
        save_selector(directory, [network(obs_size, len(GRID), 8)], stay_priors(0.75), STAY_ENV)
    assert [p.name for p in directory.iterdir()] == [policy_file]


@pytest.mark.parametrize("fault", ["observation", "priors", "nan"])
def test_networks_that_would_not_load_are_refused_before_anything_is_written(
    tmp_path: Path, fault: str
) -> None:
    """A network reading another observation, predicting for other priors or holding NaN would
    be refused when loaded: saving refuses it first, naming the member and the shapes, and
    leaves no directory behind."""
    obs_size = core_of(STAY_ENV, 1).observe().shape[1]
    net = network(obs_size + (fault == "observation"), len(GRID) + (fault == "priors"), 8)
    if fault == "nan":
        with torch.no_grad():
            net[0].weight[0, 0] = float("nan")
    message = {
        "observation": rf"net_0\.safetensors does not fit an observation of {obs_size} "
                       rf"entries and {len(GRID)} priors at width 8 \(tensor '0\.weight': "
                       rf"\(8, {obs_size + 1}\) in the file, \(8, {obs_size}\)",
        "priors": rf"net_0\.safetensors does not fit .* \(tensor '4\.bias': \({len(GRID) + 1},\)",
        "nan": r"net_0\.safetensors: tensors \['0\.weight'\] hold NaN or infinite values",
    }[fault]
    with pytest.raises(ConfigError, match=message):
        save_selector(tmp_path / "sel", [net], stay_priors(0.75), STAY_ENV)
    assert not (tmp_path / "sel").exists()


def test_the_evaluation_takes_a_selector_by_path(tmp_path: Path) -> None:
    core = core_of(SET_ENV, 1)
    torch.manual_seed(1)
    nets = [network(core.observe().shape[1], len(pair_priors()), hidden=16)]
    save_selector(tmp_path / "sel", nets, pair_priors(), SET_ENV)
    results, rollouts = evaluate([str(tmp_path / "sel"), "fixed"], "paper", 2, 0,
                                 clairvoyant=False)
    armse = results["policies"][str(tmp_path / "sel")]["armse_pos"]
    assert np.isfinite(armse) and armse > 0
    tpms = rollouts[str(tmp_path / "sel")].tpm
    np.testing.assert_allclose(tpms.sum(axis=-1), 1.0, atol=1e-12)


def write_selector(tmp_path: Path, **changes: Any) -> Path:
    core = core_of(STAY_ENV, 1)
    torch.manual_seed(0)
    nets = [network(core.observe().shape[1], len(GRID), hidden=8)]
    directory = tmp_path / "sel"
    save_selector(directory, nets, stay_priors(0.75), STAY_ENV)
    data = json.loads((directory / SELECTOR_FILE).read_text())
    data.update(changes)
    (directory / SELECTOR_FILE).write_text(json.dumps(data))
    return directory


@pytest.mark.parametrize(("changes", "message"), [
    ({"code": "import os"}, "unknown keys ['code']"),
    ({"format": "pickle"}, "format must be 'imm_gym-stay-selector'"),
    ({"combine": "vote"}, "combine must be one of ['mean_prediction']"),
    ({"hidden": 0}, "hidden must be an integer in [1, 4096]"),
    ({"hidden": 10**9}, "hidden must be an integer in [1, 4096]"),
    ({"members": []}, "members must be a non-empty list"),
    ({"members": ["../net_0.safetensors"]}, "members must be a non-empty list"),
    ({"members": ["gone.safetensors"]}, "member 'gone.safetensors' is not a file of the dir"),
    ({"members": [".."]}, "member '..' is not a file of the directory"),
    ({"hidden": 9}, "does not fit an observation"),
    ({"priors": [[0.2, 0.75], [0.9, 0.75]]}, "every stay must be in [1/3, 1)"),
    ({"priors": [[0.5, 0.25], [0.9, 0.25]]}, "every share must be the environment's"),
    ({"priors": [[0.5, 1.5], [0.9, 0.75]]}, "every share must be in [0, 1]"),
    ({"priors": [[0.5, 0.75]]}, "at least two [stay, share] pairs"),
    # each prior an output of the networks: refused before a member is read or built
    ({"priors": [[0.5, 0.75]] * 60_000, "hidden": 4096},
     "priors must be at most 1024 [stay, share] pairs, got 60000"),
    ({"priors": [[10**400, 0.75], [0.9, 0.75]]}, "at least two [stay, share] pairs"),
    ({"priors": [["0.6", "0.75"], ["0.9", "0.75"]]}, "[stay, share] pairs of numbers"),
    ({"priors": [[0.6, 0.75], [True, 0.75]]}, "[stay, share] pairs of numbers"),
    ({"trained_across": [{"bank": [{"kind": "spiral"}]}]}, "trained_across: bank[0]"),
    ({"trained_across": [{"snsor": {}}]}, "trained_across[0]: unknown keys ['snsor']"),
])
def test_malformed_selectors_are_refused_naming_the_file(
    tmp_path: Path, changes: dict[str, Any], message: str
) -> None:
    directory = write_selector(tmp_path, **changes)
    with pytest.raises(ConfigError, match=r"selector\.json") as err:
        load_selector(directory)
    assert message in str(err.value)
    assert "\n" not in str(err.value)  # one line (torch's own messages are several)


@pytest.mark.parametrize(("value", "message"), [
    (float("nan"), "tensor '0.bias' holds NaN or infinite values"),
    (0.5, "member 'net_0.safetensors': tensors ['0.bias'] are not float32"),
])
def test_a_member_of_nan_or_other_dtype_is_refused(
    tmp_path: Path, value: float, message: str
) -> None:
    directory = write_selector(tmp_path)
    tensors = load_file(directory / "net_0.safetensors")
    tensors["0.bias"] = torch.full(tensors["0.bias"].shape, value, dtype=torch.float64)
    if value == value:  # finite: keep float64, the dtype is what is wrong
        save_file(tensors, directory / "net_0.safetensors")
    else:
        save_file({**tensors, "0.bias": tensors["0.bias"].float()}, directory / "net_0.safetensors")
    with pytest.raises(ConfigError) as err:
        load_selector(directory)
    assert message in str(err.value)


def test_a_member_of_float8_is_refused_naming_it(tmp_path: Path) -> None:
    """torch checks no float8 number for NaN (NotImplementedError): refused by its dtype."""
    directory = write_selector(tmp_path)
    file = directory / "net_0.safetensors"
    save_file({k: v.to(torch.float8_e4m3fn) for k, v in load_file(file).items()}, file)
    with pytest.raises(ConfigError, match=r"net_0\.safetensors: tensor .* is torch\.float8"):
        load_selector(directory)


def test_an_environment_without_features_is_refused_by_name(tmp_path: Path) -> None:
    directory = write_selector(tmp_path)
    env = {k: v for k, v in STAY_ENV.items() if k != "obs_features"}
    (directory / "env.json").write_text(json.dumps(env))
    with pytest.raises(ConfigError, match="must end with 'detector_belief'"):  # not a KeyError
        load_selector(directory)


def test_an_environment_without_the_belief_last_is_refused(tmp_path: Path) -> None:
    directory = write_selector(tmp_path)
    env = {**STAY_ENV, "obs_features": ["stay_bank_evidence", "detector_belief",
                                         "shadow_probs"]}
    (directory / "env.json").write_text(json.dumps(env))
    with pytest.raises(ConfigError, match="must end with 'detector_belief'"):
        load_selector(directory)


def test_a_tracker_of_its_training_files_is_read_whole(tmp_path: Path) -> None:
    """A tracker listed under ``trained_across`` with some fields given is read as the
    EnvConfig it makes (every tracker field), as an agent's is: the evaluation's notes compare
    field by field."""
    directory = write_selector(tmp_path, trained_across=[{"sensor": {"sigma_r": 10.0}}])
    (tracker,) = load_selector(directory).trained_across
    assert set(tracker) == {"sensor", "bank", "filter", "initial_stay", "sojourn"}
    assert tracker["sensor"]["sigma_r"] == 10.0


def test_a_detector_named_relative_is_read_beside_env_json_and_exported_with_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A relative ``detector_weights`` in a policy's env.json is the file beside env.json from
    any working directory, and the export copies it beside the exported policy."""
    from agents.export import DETECTOR_FILE, export
    from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS

    directory = write_selector(tmp_path)
    shutil.copy2(DEFAULT_WEIGHTS, directory / "turn.safetensors")
    env = json.loads((directory / "env.json").read_text())
    (directory / "env.json").write_text(json.dumps({**env, "detector_weights": "turn.safetensors"}))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    loaded = load_selector(directory)
    assert loaded.env_overrides["detector_weights"] == str(directory / "turn.safetensors")
    target = tmp_path / "shipped"
    export(directory, target)
    assert json.loads((target / "env.json").read_text())["detector_weights"] == DETECTOR_FILE
    shutil.rmtree(directory)
    shipped = load_selector(target)
    assert shipped.env_overrides["detector_weights"] == str(target / DETECTOR_FILE)
    obs = np.random.default_rng(0).normal(size=(3, shipped.obs_size))
    assert shipped.choose(obs).shape == (3,)


def test_the_export_takes_the_selector_file_as_its_directory(tmp_path: Path) -> None:
    from agents.export import export

    directory = write_selector(tmp_path)
    export(directory / SELECTOR_FILE, tmp_path / "shipped")
    assert sorted(p.name for p in (tmp_path / "shipped").iterdir()) == sorted(
        p.name for p in directory.iterdir()
    )
    assert isinstance(load_selector(tmp_path / "shipped"), StaySelector)


@pytest.mark.parametrize(("env", "priors", "message"), [
    ({**STAY_ENV, "detector_share": 1.0}, stay_priors(1.0),
     "does not reach the stay 0.995 at env.json's detector_share 1 and logit_scale 9: it needs "
     "detector_share in [0, 0.951"),
    ({**STAY_ENV, "logit_scale": 4.0}, stay_priors(0.75),
     "does not reach the stay 0.995 at env.json's detector_share 0.75 and logit_scale 4: it "
     "needs logit_scale >= 7.37"),
    ({**SET_ENV, "logit_scale": 3.0}, pair_priors(),
     "does not set the prior [0.333333, 1] (floored to p_min 0.0001) at env.json's "
     "logit_scale 3: it needs logit_scale >= 4.6"),
])
def test_priors_the_action_cannot_reach_are_refused_naming_env_json(
    tmp_path: Path, env: dict[str, Any], priors: np.ndarray, message: str
) -> None:
    """The action clips to [-1, 1]: a prior beyond it at some belief would silently not be the
    TPM the selector chose. Saving refuses it before anything is written."""
    obs_size = core_of(env, 1).observe().shape[1]
    with pytest.raises(ConfigError, match=r"selector\.json") as err:
        save_selector(tmp_path / "sel", [network(obs_size, len(priors), 8)], priors, env)
    assert message in str(err.value)
    assert not (tmp_path / "sel").exists()


@pytest.mark.parametrize("mode", ["stay", "set"])
def test_the_reach_is_the_action_unclipped_at_a_certain_belief(tmp_path: Path, mode: str) -> None:
    """The bound is exact: the selector loads at a logit_scale a little above the stickiest
    prior's (whose action there is just within [-1, 1]) and is refused a little below."""
    M, certain = 3, np.eye(3)[1:2]  # a belief of 0 in mode 0
    if mode == "stay":
        env, priors = STAY_ENV, stay_priors(0.75)
        r = (0.995 - 1 / M) / (1 - 1 / M)
        need = np.log1p(r / ((1 - r) * 0.25 / M))
    else:
        env, priors = SET_ENV, pair_priors()
        need = 0.5 * np.log((1 - 2e-4) / 1e-4)  # share 1: a row certain of one mode, floored
    obs_size = core_of(env, 1).observe().shape[1]
    for k, scale in enumerate((1 + 1e-6, 1 - 1e-6)):
        gain = need * scale
        nets = [network(obs_size, len(priors), 8)]
        if scale < 1:
            with pytest.raises(ConfigError, match=f"logit_scale >= {need:.6g}"):
                save_selector(tmp_path / f"{k}", nets, priors, {**env, "logit_scale": gain})
            continue
        save_selector(tmp_path / f"{k}", nets, priors, {**env, "logit_scale": gain})
        s, v = priors.T
        largest = (np.abs(stay_action(s, certain, 0.75, gain)) if mode == "stay"
                   else np.abs(set_action(s, v, np.eye(3)[:1], gain, 1e-4))).max()
        assert 1 - 1e-5 < largest <= 1


def test_a_selector_exported_with_its_detector_is_replaced_by_another(tmp_path: Path) -> None:
    """The export of a selector of the learned detector writes detector.safetensors beside it:
    exporting again over it replaces that file with the rest, nothing refused."""
    from agents.export import DETECTOR_FILE, export
    from imm_gym.sim.learned_detector import DEFAULT_WEIGHTS

    directory = write_selector(tmp_path)
    shutil.copy2(DEFAULT_WEIGHTS, directory / "turn.safetensors")
    env = json.loads((directory / "env.json").read_text())
    (directory / "env.json").write_text(json.dumps({**env, "detector_weights": "turn.safetensors"}))
    target = tmp_path / "shipped"
    export(directory, target)
    export(directory, target)
    assert (target / DETECTOR_FILE).read_bytes() == DEFAULT_WEIGHTS.read_bytes()
    assert isinstance(load_selector(target), StaySelector)
