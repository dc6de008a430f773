"""``examples/stay_selector.py``: its targets are the discounted future errors by hand, the
policy it fits picks stays of the grid and sets their priors, and saved fits act as one (the
selector's actions and files: ``tests/agents/test_selector.py``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers import load_example

from agents.selector import StaySelector, combine, load_selector, network, save_selector
from imm_gym.sim.config_file import read_env_config
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.stay_bank import detector_tpm_rows
from imm_gym.validation import ConfigError

FILE = "examples/across_trackers.yaml"


def selector_core(example: object, n: int, share: float, **changes: object) -> TrackingCore:
    overrides = example.selector_overrides(  # type: ignore[attr-defined]
        read_env_config(FILE), share, None, None
    )
    core = TrackingCore(EnvConfig.build({**overrides, **changes}), n)
    core.reset(np.arange(n), list(range(n)))
    return core


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
    X, Y, episode = example.collect(overrides, 8, example.SELECTOR_SEED_BASE, rng, 1.0, 30, 10)
    assert X.shape[0] == Y.shape[0] == 8 * 15 and Y.shape[1] == 7
    # each sample's episode is its seed, the samples episode-major
    np.testing.assert_array_equal(episode, example.SELECTOR_SEED_BASE + np.arange(8).repeat(15))
    np.testing.assert_allclose(Y.mean(axis=1), 0.0, atol=1e-5)  # relative to the stays' mean
    again = example.collect(overrides, 8, example.SELECTOR_SEED_BASE,
                            np.random.default_rng(0), 1.0, 30, 10)
    np.testing.assert_array_equal(again[0], X)  # seeded: the same numbers
    net, held_out = example.fit(X, Y, episode, 1, 0)
    assert np.isfinite(list(held_out.values())).all()
    core = selector_core(example, 5, 0.75)
    grid = core.stay_bank.stays[:, 0].copy()  # type: ignore[union-attr]
    priors = np.stack([grid, np.full(len(grid), 0.75)], axis=1)
    obs = core.observe()
    selector = StaySelector([net], priors, overrides, obs.shape[1])
    stays = grid[selector.choose(obs)]
    action, _ = selector.predict(obs)
    belief = core.detector_belief.copy()
    result = core.step(action)
    np.testing.assert_allclose(
        result.info["tpm"], detector_tpm_rows(stays, belief, 0.75), atol=1e-3  # p_min floor
    )


def test_the_held_out_score_is_on_whole_episodes_the_fit_never_saw() -> None:
    """Samples of one episode are neighbouring steps: a network that knows an episode from its
    training samples would score well on that episode's held-out ones. Here each episode's
    observations name it and its targets are its own random draw, the same at every step: only
    a split by episode leaves nothing to learn for the held-out samples."""
    example = load_example("stay_selector")
    rng = np.random.default_rng(0)
    episodes, per = 60, 50
    names = rng.normal(size=(episodes, 8)).astype(np.float32)
    targets = rng.normal(size=(episodes, 7)).astype(np.float32)
    episode = np.arange(episodes).repeat(per) + 10**6
    X, Y = names.repeat(per, axis=0), targets.repeat(per, axis=0)
    held = example.held_out_episodes(episode, 0)
    assert held.sum() == 3 * per  # a twentieth of the episodes, whole
    assert not np.isin(episode[held], episode[~held]).any()
    _, score = example.fit(X, Y, episode, 300, 0)
    assert score["mse"] > 0.5 * score["variance"]  # a split of samples: 4e-12 (memorized)
    assert example.held_out_episodes(np.zeros(10, np.int64), 0).sum() == 0  # one episode: none


@pytest.mark.parametrize(("option", "message"), [
    (["--share", "1.0"], "--share must be in [0, 0.9]"),
    (["--shares", "0.5"], "--shares must be at least two distinct shares in [0, 1]"),
    (["--shares", "0", "1.5"], "--shares must be at least two distinct shares in [0, 1]"),
    (["--gamma", "3"], "--gamma must be in (0, 1]"),
    (["--horizon", "0"], "--horizon must be at least 1"),
    (["--scenario", "nowhere"], "--scenario 'nowhere' is not in the benchmark suite"),
    (["--targets", "branch", "--shares", "0", "1"], "--targets branch takes one share"),
    (["--behaviour", "no/such/selector"], "--behaviour: "),
])
def test_bad_options_are_refused_before_any_work(
    option: list[str], message: str, capsys: pytest.CaptureFixture[str],
) -> None:
    example = load_example("stay_selector")
    with pytest.raises(SystemExit):
        example.main(["--env-config", FILE, *option])
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(("option", "message"), [
    (["--runs", "0"], "--runs must be at least 1, got 0"),
    (["--seed", "-1"], "--seed must be >= 0, got -1"),
    (["--fit-seed", "-1"], "--fit-seed must be in [0, 100000000]"),
    (["--fit-seed", str(10**9)], "--fit-seed must be in [0, 100000000]"),
    (["--features-from", "no/such.yaml"], "--features-from: no/such.yaml: cannot read"),
    (["--env-config", FILE, "no/such.yaml", "--episodes", "2"],
     "--env-config: no/such.yaml: cannot read"),
    (["--env-config", "examples/probes/hetero.yaml"], "--env-config: "
     "examples/probes/hetero.yaml: "),  # built as the selector runs it
    (["--off-suite", "no/such/file.yaml"], "--off-suite: no/such/file.yaml: cannot read"),
    (["--off-suite", "examples/broad.yaml", "README.md"], "--off-suite: README.md: a "
     "configuration file ends in"),
    # a bank a compared policy cannot run on (ConfigError at the scoring, after the fit)
    (["--off-suite", "examples/probes/cvcact.yaml"], "--off-suite: examples/probes/cvcact.yaml: "
     "learned-prior cannot run on this configuration: detector 'learned' needs models of "
     "distinct turn rates"),
    (["--off-suite", "examples/probes/cv_ct.yaml"], "--off-suite: examples/probes/cv_ct.yaml: "
     "pretrained cannot run on this configuration: reads 44 observation entries"),
])
def test_the_runs_seeds_and_files_are_refused_before_collecting(
    option: list[str], message: str, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Usage errors (exit 2) before any work: --runs and --off-suite were met after collecting
    and fitting (about ten minutes by default), the rest as tracebacks."""
    example = load_example("stay_selector")
    monkeypatch.setattr(example, "collect", lambda *a, **k: pytest.fail("collected"))
    with pytest.raises(SystemExit) as exit_:
        example.main(["--env-config", FILE, "--episodes", "1", *option])
    assert exit_.value.code == 2 and message in capsys.readouterr().err


def test_priors_the_action_cannot_set_are_refused_before_collecting(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A stay the action does not reach at some belief (here at a smaller logit_scale than the
    script's) was refused only when the selector was saved, after collecting and fitting."""
    example = load_example("stay_selector")
    monkeypatch.setattr(example, "collect", lambda *a, **k: pytest.fail("collected"))
    monkeypatch.setattr(example, "GAIN", 4.0)
    with pytest.raises(SystemExit) as exit_:
        example.main(["--env-config", FILE, "--episodes", "1"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2
    assert f"--env-config {FILE}: the stay action does not reach the stay" in err
    assert "logit_scale >= 7.37" in err


def test_the_shares_cores_replay_the_episodes_each_share_alone_gives() -> None:
    example = load_example("stay_selector")
    base = read_env_config(FILE)
    single = example.selector_overrides(base, 0.75, None, None)
    pairs = example.selector_overrides(base, 0.75, None, None, "set")
    assert pairs["action_mode"] == "set" and pairs["detector_share"] == 0.0
    _, Y1, _ = example.collect(single, 8, example.SELECTOR_SEED_BASE,
                               np.random.default_rng(0), 1.0, 30, 10)
    X2, Y2, _ = example.collect(pairs, 8, example.SELECTOR_SEED_BASE,
                             np.random.default_rng(0), 1.0, 30, 10, [0.0, 0.75])
    assert Y2.shape == (8 * 15, 14) and X2.shape[0] == Y1.shape[0]
    # the bank errors do not depend on the action: share 0.75's block, re-centred, is the
    # single-share collection's targets
    block = Y2[:, 7:] - Y2[:, 7:].mean(axis=1, keepdims=True)
    np.testing.assert_allclose(block, Y1, atol=1e-5)


def test_a_branch_is_the_stay_banks_imm_where_the_tracker_ran_its_prior() -> None:
    """From the episode's start every branch is the stay bank's IMM of its stay (both start
    from the tracker's initial posterior); later, the branch at the stay the tracker has run
    since the start is that stay's IMM too (the ``stay`` action gives its prior exactly below
    the grid's last stay, which the belief can put out of the action's reach)."""
    example = load_example("stay_selector")
    n, stride, horizon = 6, 10, 30
    core = selector_core(example, n, 0.75)
    grid = core.stay_bank.stays[:, 0].copy()  # type: ignore[union-attr]
    pick = np.arange(n) % (len(grid) - 1)
    K, M = core.horizon, core.M
    points = np.arange(0, K, stride)
    beliefs, bank = np.zeros((n, K, M)), np.zeros((n, K, len(grid)))
    starts = []
    for k in range(K):
        beliefs[:, k] = core.detector_belief
        if k % stride == 0:
            starts.append(core.state_a)
        result = core.step(example.stay_action(grid[pick], core.detector_belief, 0.75,
                                               example.GAIN))
        truth = result.info["true_state"][:, None, :2]
        estimates = core.stay_bank.estimates()[:, :, :2]  # type: ignore[union-attr]
        bank[:, k] = np.sum((estimates - truth) ** 2, axis=-1)
    assert not result.info["diverged"].any()
    y = example.branch_errors(core, starts, points, beliefs, grid, 1.0, horizon)
    assert y.shape == (n, len(points), len(grid))
    np.testing.assert_allclose(y[:, 0], np.log(bank[:, :horizon].mean(axis=1) + 1e-6),
                               rtol=1e-9)
    own = np.stack([np.log(bank[np.arange(n), b:b + horizon, pick].mean(axis=1) + 1e-6)
                    for b in points], axis=1)
    np.testing.assert_allclose(y[np.arange(n), :, pick], own, rtol=1e-6)
    overrides = example.selector_overrides(read_env_config(FILE), 0.75, None, None)
    X, Y, episode = example.collect(overrides, 8, example.SELECTOR_SEED_BASE,
                                    np.random.default_rng(0), 1.0, horizon, stride, None, True)
    assert X.shape[0] == Y.shape[0] == 8 * len(points) and Y.shape[1] == len(grid)
    np.testing.assert_array_equal(episode, example.SELECTOR_SEED_BASE
                                  + np.arange(8).repeat(len(points)))
    np.testing.assert_allclose(Y.mean(axis=1), 0.0, atol=1e-5)
    # another stay's branch is not its bank IMM's once the histories differ
    other = (pick + 3) % len(grid)
    later = np.log(bank[np.arange(n), 50:50 + horizon, other].mean(axis=1) + 1e-6)
    assert np.abs(y[np.arange(n), 5, other] - later).max() > 1e-3


def test_half_of_the_slots_follow_a_behaviour_selector() -> None:
    """``--behaviour``: the even slots follow the selector (here one that always picks the grid's
    third stay), the odd slots run the random stays they run without it."""
    example = load_example("stay_selector")
    overrides = example.selector_overrides(read_env_config(FILE), 0.75, None, None)
    core = selector_core(example, 1, 0.75)
    grid = core.stay_bank.stays[:, 0].copy()  # type: ignore[union-attr]
    priors = np.stack([grid, np.full(len(grid), 0.75)], axis=1)
    net = network(core.observe().shape[1], len(grid), hidden=4)
    with torch.no_grad():
        net[-1].weight.zero_()
        net[-1].bias.copy_(torch.tensor([0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0]))
    third = StaySelector([net], priors, overrides, core.observe().shape[1])
    args = (overrides, 4, example.SELECTOR_SEED_BASE)
    X, _, _ = example.collect(*args, np.random.default_rng(0), 1.0, 30, 10)
    Xb, _, _ = example.collect(*args, np.random.default_rng(0), 1.0, 30, 10, behaviour=third)
    per_slot = X.shape[0] // 4
    X, Xb = X.reshape(4, per_slot, -1), Xb.reshape(4, per_slot, -1)
    np.testing.assert_array_equal(Xb[1::2], X[1::2])
    assert not np.array_equal(Xb[0::2], X[0::2])
    other = StaySelector([net], priors[::-1].copy(), overrides, core.observe().shape[1])
    with pytest.raises(ConfigError, match="other priors"):
        example.collect(*args, np.random.default_rng(0), 1.0, 30, 10, behaviour=other)


def test_saved_selectors_act_as_one_and_are_written_as_one(tmp_path: object) -> None:
    example = load_example("stay_selector")
    overrides = example.selector_overrides(read_env_config(FILE), 0.75, None, None)
    core = selector_core(example, 6, 0.75)
    grid = core.stay_bank.stays[:, 0].copy()  # type: ignore[union-attr]
    priors = np.stack([grid, np.full(len(grid), 0.75)], axis=1)
    obs = core.observe()
    torch.manual_seed(0)
    nets = [network(obs.shape[1], len(grid)) for _ in range(2)]
    for k, net in enumerate(nets):
        save_selector(f"{tmp_path}/fit_{k}", [net], priors, overrides)
    both = combine([load_selector(f"{tmp_path}/fit_{k}") for k in range(2)])
    x = torch.from_numpy(obs)
    with torch.no_grad():
        mean = (nets[0](x) + nets[1](x)) / 2
    np.testing.assert_array_equal(both.choose(obs), mean.argmin(1).numpy())
    other = save_selector(f"{tmp_path}/other", [network(obs.shape[1], len(grid) - 1)],
                          priors[:-1], overrides)
    with pytest.raises(ConfigError, match="other priors"):
        combine([both, other])


def test_saved_selectors_are_scored_without_a_training_file(
    tmp_path: object, capsys: pytest.CaptureFixture[str],
) -> None:
    example = load_example("stay_selector")
    with pytest.raises(SystemExit):
        example.main([])
    assert "give --env-config FILE ... (collect and fit) or --weights" in capsys.readouterr().err
    overrides = example.selector_overrides(read_env_config(FILE), 0.75, None, None)
    core = selector_core(example, 1, 0.75)
    grid = core.stay_bank.stays[:, 0].copy()  # type: ignore[union-attr]
    torch.manual_seed(0)
    net = network(core.observe().shape[1], len(grid), hidden=8)
    save_selector(f"{tmp_path}/fit", [net], np.stack([grid, np.full(7, 0.75)], axis=1),
                  overrides)
    example.main(["--weights", f"{tmp_path}/fit", f"{tmp_path}/fit", "--save", f"{tmp_path}/two",
                  "--scenario", "paper", "--runs", "2"])
    assert "wrote" in capsys.readouterr().out
    assert len(load_selector(f"{tmp_path}/two").nets) == 2


def test_the_options_fill_in_what_a_file_does_not_set() -> None:
    example = load_example("stay_selector")
    plain = example.selector_overrides(read_env_config(FILE), 0.75, (0.5, 50.0), (1, 6))
    assert plain["vary"]["q_maneuver"] == [0.5, 50.0] and plain["family"]["n_segments"] == [1, 6]
    assert plain["vary"]["T"] == read_env_config(FILE)["vary"]["T"]  # the rest kept
    field = read_env_config("examples/across_trackers_field.yaml")
    kept = example.selector_overrides(field, 0.75, (0.5, 50.0), (2, 3))
    assert kept["vary"]["q_maneuver"] == field["vary"]["q_maneuver"] == [1.0, 50.0]
    assert kept["family"]["n_segments"] == field["family"]["n_segments"] == [1, 6]
