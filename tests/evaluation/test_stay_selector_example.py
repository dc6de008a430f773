"""``examples/stay_selector.py``: its action gives the stay bank's prior at the chosen stay, its
targets are the discounted future errors by hand, and the policy it fits picks stays of the
grid."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers import load_example
from safetensors.torch import save_file

from imm_gym.sim.config_file import read_env_config
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.stay_bank import detector_tpm_rows

FILE = "examples/across_trackers.yaml"


def selector_core(example: object, n: int, share: float, **changes: object) -> TrackingCore:
    overrides = example.selector_overrides(  # type: ignore[attr-defined]
        read_env_config(FILE), share, None, None
    )
    core = TrackingCore(EnvConfig.build({**overrides, **changes}), n)
    core.reset(np.arange(n), list(range(n)))
    return core


@pytest.mark.parametrize("share", [0.0, 0.25, 0.75, 0.9])
def test_the_action_gives_the_banks_prior_at_the_chosen_stay(share: float) -> None:
    example = load_example("stay_selector")
    core = selector_core(example, 7, share, p_min=1e-9)  # no floor between the two
    grid = core.stay_bank.stays[:, 0]  # type: ignore[union-attr]
    assert grid.tolist() == pytest.approx([1 / 3, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995])
    obs = core.observe()
    for _ in range(3):
        belief = core.detector_belief.copy()
        np.testing.assert_allclose(obs[:, -3:], belief, atol=1e-6)  # observed last
        result = core.step(example.stay_action(grid, belief, share))
        np.testing.assert_allclose(
            result.info["tpm"], detector_tpm_rows(grid, belief, share), atol=1e-9
        )
        obs = result.obs


def test_the_targets_are_the_discounted_future_errors_relative_to_the_stays_mean() -> None:
    example = load_example("stay_selector")
    errors = np.array([[[1.0, 4.0], [2.0, 8.0], [4.0, 2.0]]])  # (R=1, K=3, S=2)
    y = example.future_error(errors, gamma=0.5, horizon=2)
    raw = np.log(np.array([
        [(1.0 + 0.5 * 2.0) / 1.5, (4.0 + 0.5 * 8.0) / 1.5],
        [(2.0 + 0.5 * 4.0) / 1.5, (8.0 + 0.5 * 2.0) / 1.5],
        [4.0, 2.0],  # the window is cut at the episode's end
    ]) + 1e-6)
    np.testing.assert_allclose(y[0], raw - raw.mean(axis=1, keepdims=True), rtol=1e-12)


def test_the_fitted_selector_picks_stays_of_the_grid() -> None:
    example = load_example("stay_selector")
    overrides = example.selector_overrides(read_env_config(FILE), 0.75, None, None)
    rng = np.random.default_rng(0)
    X, Y = example.collect(overrides, 8, example.SELECTOR_SEED_BASE, rng, 1.0, 30, 10)
    assert X.shape[0] == Y.shape[0] == 8 * 15 and Y.shape[1] == 7
    np.testing.assert_allclose(Y.mean(axis=1), 0.0, atol=1e-5)  # relative to the stays' mean
    again = example.collect(overrides, 8, example.SELECTOR_SEED_BASE,
                            np.random.default_rng(0), 1.0, 30, 10)
    np.testing.assert_array_equal(again[0], X)  # seeded: the same numbers
    net, held_out = example.fit(X, Y, 1, 0)
    assert np.isfinite(list(held_out.values())).all()
    core = selector_core(example, 5, 0.75)
    grid = core.stay_bank.stays[:, 0].copy()  # type: ignore[union-attr]
    selector = example.StaySelector([net], grid, 0.75, core.M)
    obs = core.observe()
    stays = selector.stays(obs)
    assert set(stays.tolist()) <= set(grid.tolist())
    action, _ = selector.predict(obs)
    belief = core.detector_belief.copy()
    result = core.step(action)
    np.testing.assert_allclose(
        result.info["tpm"], detector_tpm_rows(stays, belief, 0.75), atol=1e-3  # p_min floor
    )


@pytest.mark.parametrize(("option", "message"), [
    (["--share", "1.0"], "--share must be in [0, 0.9]"),
    (["--gamma", "3"], "--gamma must be in (0, 1]"),
    (["--horizon", "0"], "--horizon must be at least 1"),
    (["--scenario", "nowhere"], "--scenario 'nowhere' is not in the benchmark suite"),
])
def test_bad_options_are_refused_before_any_work(
    option: list[str], message: str, capsys: pytest.CaptureFixture[str],
) -> None:
    example = load_example("stay_selector")
    with pytest.raises(SystemExit):
        example.main(["--env-config", FILE, *option])
    assert message in capsys.readouterr().err


def test_a_saved_network_acts_alike_and_two_act_on_their_mean(tmp_path: object) -> None:
    example = load_example("stay_selector")
    core = selector_core(example, 6, 0.75)
    grid = core.stay_bank.stays[:, 0].copy()  # type: ignore[union-attr]
    obs = core.observe()
    torch.manual_seed(0)
    nets = [example.network(obs.shape[1], len(grid)) for _ in range(2)]
    paths = [f"{tmp_path}/net_{k}.safetensors" for k in range(2)]
    for net, path in zip(nets, paths, strict=True):
        save_file(net.state_dict(), path)
    loaded = [example.load_network(p, obs.shape[1], len(grid)) for p in paths]
    one = example.StaySelector(nets[:1], grid, 0.75, core.M)
    np.testing.assert_array_equal(example.StaySelector(loaded[:1], grid, 0.75, core.M).stays(obs),
                                  one.stays(obs))
    x = torch.from_numpy(obs)
    with torch.no_grad():
        mean = (nets[0](x) + nets[1](x)) / 2
    np.testing.assert_array_equal(example.StaySelector(loaded, grid, 0.75, core.M).stays(obs),
                                  grid[mean.argmin(1).numpy()])
    with pytest.raises(RuntimeError):  # a network for another observation is refused
        example.load_network(paths[0], obs.shape[1] + 1, len(grid))


def test_the_options_fill_in_what_a_file_does_not_set() -> None:
    example = load_example("stay_selector")
    plain = example.selector_overrides(read_env_config(FILE), 0.75, (0.5, 50.0), (1, 6))
    assert plain["vary"]["q_maneuver"] == [0.5, 50.0] and plain["family"]["n_segments"] == [1, 6]
    assert plain["vary"]["T"] == read_env_config(FILE)["vary"]["T"]  # the rest kept
    field = read_env_config("examples/across_trackers_field.yaml")
    kept = example.selector_overrides(field, 0.75, (0.5, 50.0), (2, 3))
    assert kept["vary"]["q_maneuver"] == field["vary"]["q_maneuver"] == [1.0, 50.0]
    assert kept["family"]["n_segments"] == field["family"]["n_segments"] == [1, 6]
