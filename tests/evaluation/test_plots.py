"""The evaluation's figures: the mode probabilities named by the evaluated bank's models, the
time axis in seconds at the tracker's sampling period (in steps when it is drawn per episode),
no pyplot backend switched; the animation's first mode probabilities are the tracker's; a
diverged run is drawn up to its divergence and named so; an MP4's frames stream."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import matplotlib
import numpy as np
import pytest

from baselines import REGISTRY, BuildContext
from imm_gym import EnvConfig
from imm_gym.evaluation import animation
from imm_gym.evaluation.animation import rollout_view, start_probs
from imm_gym.evaluation.plots import figures
from imm_gym.evaluation.rollout import Rollout, evaluation_config, rollout
from imm_gym.sim.episodes import draw_batch
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.sim.render import TrackFigure, model_labels
from imm_gym.tracking.hetero import HeteroBank

META = {"scenario": "test", "runs": 2, "seeds": "0..1"}


def _fixed_rollout(config: EnvConfig, runs: int = 2, seed: int = 0):
    policy, _ = REGISTRY["fixed"].build(BuildContext(config, seed, 1, None))
    return rollout(policy, evaluation_config(config, policy.env_overrides), runs, seed)


def test_mode_probabilities_are_named_by_the_bank_and_time_is_in_seconds() -> None:
    scenario = {"segments": [{"duration": 12}], "position": [3000.0, 4500.0],
                "velocity": [20.0, 15.0], "T": 2.0}
    config = EnvConfig.build({"scenario": scenario, **BANK_PRESETS["hetero"]})
    run = _fixed_rollout(config)
    backend = matplotlib.get_backend()
    figs = figures({"fixed": run}, META, config)
    assert matplotlib.get_backend() == backend  # no pyplot backend switched
    legend = figs["mode_probs"].axes[0].get_legend()
    assert [text.get_text() for text in legend.get_texts()] == model_labels(config.bank)
    assert model_labels(config.bank) == ["NCV", "CT", "CTRA"]
    for name in ("mode_probs", "rmse"):
        ax = figs[name].axes[-1]
        assert ax.get_xlabel() == "time (s)"
        assert ax.get_lines()[0].get_xdata()[-1] == 2.0 * 12


def test_a_sampling_period_drawn_per_episode_counts_steps() -> None:
    config = EnvConfig.build({
        **BANK_PRESETS["cv-ct-continuous"], "vary": {"T": (0.5, 2.0)},
        "family": {"horizon": 20, "n_segments": (1, 2), "min_duration": 10},
    })
    run = _fixed_rollout(config)
    ax = figures({"fixed": run}, META, config)["rmse"].axes[0]
    assert ax.get_xlabel() == "step"
    assert ax.get_lines()[0].get_xdata()[-1] == 20


def test_the_animation_starts_from_the_trackers_mode_probabilities() -> None:
    np.testing.assert_array_equal(start_probs(HeteroBank()), [0.90, 0.08, 0.02])
    config = EnvConfig(scenario="paper")
    np.testing.assert_array_equal(start_probs(config.bank), np.full(3, 1 / 3))
    run = _fixed_rollout(config, runs=1)
    batch = draw_batch(config.source, config.sensor, 1, 0, config.velocity_std)
    view = rollout_view(run, batch, config.sensor, "fixed", 5, start=np.array([0.5, 0.3, 0.2]))
    np.testing.assert_array_equal(view.mode_probs[0], [0.5, 0.3, 0.2])
    np.testing.assert_array_equal(view.mode_probs[1:], run.mode_probs[0, :5])


def test_a_diverged_run_is_drawn_up_to_its_divergence_and_titled_so() -> None:
    """The roll-out holds a diverged run's estimate at the capped error, its mode probabilities
    uniform and its covariance I (the scoring's stand-ins): the pictures draw none of them."""
    config = EnvConfig.build({"scenario": "paper", "divergence_error": 60.0})
    run = _fixed_rollout(config, runs=3)
    np.testing.assert_array_equal(run.diverged, [True, False, True])
    assert np.flatnonzero(~run.live[2])[0] == 76  # run 2 diverges at step 77 (steps 1..K)
    batch = draw_batch(config.source, config.sensor, 3, 0, config.velocity_std)
    before = rollout_view(run, batch, config.sensor, "fixed", 76, 2)
    assert before.title == "fixed" and np.isfinite(before.estimate).all()
    view = rollout_view(run, batch, config.sensor, "fixed", 100, 2)
    assert view.title == "fixed, diverged at step 77"
    assert np.isfinite(view.estimate[:77]).all() and np.isnan(view.estimate[77:]).all()
    assert np.isfinite(view.mode_probs[:77]).all() and np.isnan(view.mode_probs[77:]).all()
    assert np.isnan(view.covariance).all()
    picture = TrackFigure(model_labels(config.bank))
    assert picture.frame(view).shape == (400, 640, 3)
    assert picture.error.get_text() == "" and not picture.ellipse.get_visible()

    shifted = Rollout(*(getattr(run, f.name)[2:] for f in fields(Rollout)))  # run 2 as run 0
    figs = figures({"fixed": shifted}, META, config)
    assert figs["mode_probs"].axes[0].get_title() == "fixed, diverged at step 77"
    assert "fixed diverged at step 77" in figs["trajectory"].axes[0].get_title()
    estimate = figs["trajectory"].axes[0].get_lines()[1].get_xydata()
    assert np.isfinite(estimate[:76]).all() and np.isnan(estimate[76:]).all()
    for line in figs["mode_probs"].axes[0].get_lines():
        assert np.isfinite(line.get_ydata()[:76]).all() and np.isnan(line.get_ydata()[76:]).all()


def test_the_mp4_writer_writes_each_frame_before_the_next_is_drawn(monkeypatch) -> None:
    """The frames stream to ffmpeg (a fake writer here): a 150-step episode of two panels is
    176 MB of RGB frames held at once otherwise."""
    import contextlib

    import matplotlib.animation

    drawn: list[int] = []
    written: list[int] = []

    def frames():
        for i in range(5):
            drawn.append(i)
            yield np.full((20, 30, 3), i, dtype=np.uint8)

    class Writer:
        def __init__(self, fps: float) -> None:
            pass

        @contextlib.contextmanager
        def saving(self, fig, path, dpi):
            yield

        def grab_frame(self) -> None:
            written.append(len(drawn))

    monkeypatch.setattr(matplotlib.animation, "FFMpegWriter", Writer)
    assert animation._write_mp4(frames(), Path("unused.mp4"), 10) == 5
    assert written == [1, 2, 3, 4, 5]  # frame i written when i + 1 frames were drawn


def test_the_figures_draw_run_0s_truth_and_the_root_mean_square_error() -> None:
    """Two runs of a random family (different paths): the trajectory's truth and estimate are
    run 0's, and the RMSE curve is ``sqrt(mean over runs of |p_hat - p|^2)`` worked out here."""
    config = EnvConfig(scenario="random", family={"horizon": 30, "n_segments": [1, 3]})
    run = _fixed_rollout(config)
    assert not run.diverged.any()
    assert not np.allclose(run.truth[0, :, :2], run.truth[1, :, :2])
    figs = figures({"fixed": run}, META, config)
    truth, estimate = figs["trajectory"].axes[0].get_lines()[:2]
    np.testing.assert_array_equal(truth.get_xydata(), run.truth[0, :, :2])
    np.testing.assert_array_equal(estimate.get_xydata(), run.estimate[0, :, :2])
    squared = ((run.estimate[:, :, :2] - run.truth[:, :, :2]) ** 2).sum(axis=-1)
    rmse = figs["rmse"].axes[0].get_lines()[0]
    np.testing.assert_allclose(rmse.get_ydata(), np.sqrt(squared.mean(axis=0)), rtol=1e-9)
    assert rmse.get_ydata().max() > 2.0  # the square root differs from the mean square


def test_the_tradeoff_figure_draws_the_fixed_curve_and_each_policys_point(
    tmp_path, monkeypatch
) -> None:
    """The fixed TPMs' curve at (100 · accuracy, ARMSE) in stay order, one point per policy."""
    from imm_gym.evaluation import plots

    drawn = []
    save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.append(fig) or save(fig, path))
    fixed = {
        0.99: {"mode_accuracy": 0.8, "armse_pos": 30.0},
        0.9: {"mode_accuracy": 0.7, "armse_pos": 25.0},
    }
    policies = {"a": {"mode_accuracy": 0.85, "armse_pos": 20.0, "mode_prob_tv": 0.1},
                "b": {"mode_accuracy": 0.6, "armse_pos": 40.0, "mode_prob_tv": 0.2}}
    path = plots.tradeoff_figure(policies, fixed, tmp_path / "t.png", META)
    assert path.exists() and len(drawn) == 1
    lines = drawn[0].axes[0].get_lines()
    assert len(lines) == 3
    np.testing.assert_allclose(lines[0].get_xydata(), [[70.0, 25.0], [80.0, 30.0]])
    np.testing.assert_allclose(lines[1].get_xydata(), [[85.0, 20.0]])
    np.testing.assert_allclose(lines[2].get_xydata(), [[60.0, 40.0]])


def test_the_tradeoff_figure_leaves_out_what_has_no_mode_accuracy(tmp_path, monkeypatch) -> None:
    """A mode accuracy None (no step's true model in the bank) has no point, a TV None reads
    "TV —" (100 · None raised TypeError)."""
    from imm_gym.evaluation import plots

    drawn = []
    save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.append(fig) or save(fig, path))
    fixed = {0.99: {"mode_accuracy": 0.8, "armse_pos": 30.0},
             0.9: {"mode_accuracy": None, "armse_pos": 25.0}}
    policies = {"a": {"mode_accuracy": None, "armse_pos": 20.0, "mode_prob_tv": 0.1},
                "b": {"mode_accuracy": 0.6, "armse_pos": 40.0, "mode_prob_tv": None}}
    plots.tradeoff_figure(policies, fixed, tmp_path / "t.png", META)
    lines = drawn[0].axes[0].get_lines()
    assert len(lines) == 2
    np.testing.assert_allclose(lines[0].get_xydata(), [[80.0, 30.0]])
    np.testing.assert_allclose(lines[1].get_xydata(), [[60.0, 40.0]])
    assert lines[1].get_label() == "b (TV —)"


def test_the_tradeoff_figure_makes_its_missing_directories(tmp_path) -> None:
    """The CLI accepts a --tradeoff path whose directories do not exist yet (as --json and
    --plots): the figure makes them (it raised FileNotFoundError after the whole evaluation)."""
    from imm_gym.evaluation import plots

    fixed = {0.9: {"mode_accuracy": 0.7, "armse_pos": 25.0}}
    policies = {"a": {"mode_accuracy": 0.85, "armse_pos": 20.0, "mode_prob_tv": 0.1}}
    path = tmp_path / "new" / "deeper" / "t.png"
    assert plots.tradeoff_figure(policies, fixed, path, META) == path
    assert path.is_file()


def test_a_tradeoff_without_any_mode_accuracy_says_so(tmp_path, monkeypatch) -> None:
    """No stay and no policy with a mode accuracy (no step's true model in the bank): the figure
    says there is nothing to plot (it was empty axes, written silently)."""
    from imm_gym.evaluation import plots

    drawn = []
    save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.append(fig) or save(fig, path))
    fixed = {0.9: {"mode_accuracy": None, "armse_pos": 25.0}}
    policies = {"a": {"mode_accuracy": None, "armse_pos": 20.0, "mode_prob_tv": 0.1}}
    assert plots.tradeoff_figure(policies, fixed, tmp_path / "t.png", META).is_file()
    ax = drawn[0].axes[0]
    assert not ax.get_lines() and not ax.axison
    assert [t.get_text() for t in ax.texts] == [
        "no mode accuracy to plot:\nno step's true model is in the bank"
    ]
    assert ax.get_title().startswith("ARMSE vs mode integrity (test, 2 runs")


def test_two_policies_each_have_their_estimate_mode_panel_and_rmse_curve_named() -> None:
    """Two policies on one scenario: the trajectory draws each one's run-0 estimate under its
    name, the mode probabilities take one panel per policy (titled by it, probabilities 0..1
    in view, the time axis named under the bottom panel), the RMSE one curve per policy named
    by it; the titles name the scenario, the runs and the seeds of ``meta``."""
    scenario = {"segments": [{"duration": 10}, {"duration": 10, "turn_rate_deg": 3.0}],
                "position": [3000.0, 4500.0], "velocity": [20.0, 15.0]}
    config = EnvConfig.build({"scenario": scenario})
    runs = {}
    for name in ("fixed", "tip-imm"):
        policy, _ = REGISTRY[name].build(BuildContext(config, 0, 1, None))
        runs[name] = rollout(policy, evaluation_config(config, policy.env_overrides), 2, 0)
    assert not any(r.diverged.any() for r in runs.values())
    assert not np.allclose(runs["fixed"].estimate, runs["tip-imm"].estimate)
    meta = {"scenario": "short turn", "runs": 2, "seeds": "0..1"}
    figs = figures(runs, meta, config)

    ax = figs["trajectory"].axes[0]
    _, *estimates = ax.get_lines()
    assert [line.get_label() for line in ax.get_lines()] == ["truth", "fixed", "tip-imm"]
    for line, name in zip(estimates, runs, strict=True):
        np.testing.assert_array_equal(line.get_xydata(), runs[name].estimate[0, :, :2])
    assert ax.get_title() == "Trajectory, run 0 (short turn)"
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["truth", "fixed", "tip-imm"]

    top, bottom = figs["mode_probs"].axes[:2]
    for ax, name in ((top, "fixed"), (bottom, "tip-imm")):
        assert ax.get_title() == name
        low, high = ax.get_ylim()
        assert low < 0.0 and high > 1.0  # a probability of 1 is in view
        for j, line in enumerate(ax.get_lines()):
            np.testing.assert_array_equal(line.get_ydata(), runs[name].mode_probs[0, :, j])
    assert bottom.get_xlabel() == "time (s)" and top.get_xlabel() == ""

    ax = figs["rmse"].axes[0]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["fixed", "tip-imm"]
    assert ax.get_title() == "RMSE over time (short turn, 2 runs, seeds 0..1)"
    assert ax.get_ylabel() == "position RMSE (m)"


def test_the_tradeoff_figure_names_the_stays_and_the_policies_in_its_legend(
    tmp_path, monkeypatch
) -> None:
    """Each stay written beside its point of the curve (three significant digits), each policy
    in the legend with its total variation (two decimals), a long name (an agent's directory)
    cut to its last 27 characters after an ellipsis, and the axes named."""
    from imm_gym.evaluation import plots

    drawn = []
    save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.append(fig) or save(fig, path))
    fixed = {0.975: {"mode_accuracy": 0.8, "armse_pos": 30.0},
             0.9: {"mode_accuracy": 0.7, "armse_pos": 25.0}}
    agent = "runs/agents/2026-12-07/ppo-long-directory-name/best"
    policies = {"a": {"mode_accuracy": 0.85, "armse_pos": 20.0, "mode_prob_tv": 0.1234},
                agent: {"mode_accuracy": 0.6, "armse_pos": 40.0, "mode_prob_tv": 0.2}}
    plots.tradeoff_figure(policies, fixed, tmp_path / "t.png", META)
    ax = drawn[0].axes[0]
    stays = {t.get_text(): t.xy for t in ax.texts}
    assert stays == {"0.9": (70.0, 25.0), "0.975": (80.0, 30.0)}
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [
        "fixed TPM (stay on the diagonal)",
        "a (TV 0.12)",
        "…po-long-directory-name/best (TV 0.20)",  # 51 characters: the last 27 kept
    ]
    assert ax.get_xlabel().startswith("mode accuracy (%)")
    assert ax.get_ylabel() == "position ARMSE (m)"
    assert ax.get_title() == "ARMSE vs mode integrity (test, 2 runs, seeds 0..1)"


@pytest.mark.parametrize("which", ["stays only", "policies only"])
def test_a_tradeoff_with_only_stays_or_only_policies_draws_them(
    tmp_path, monkeypatch, which
) -> None:
    """Mode accuracies for the stays but none for the policies (or the reverse): what has one is
    drawn; "no mode accuracy to plot" is for a figure where nothing has one."""
    from imm_gym.evaluation import plots

    drawn = []
    save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.append(fig) or save(fig, path))
    stays_have = which == "stays only"
    fixed = {0.9: {"mode_accuracy": 0.7 if stays_have else None, "armse_pos": 25.0}}
    policies = {"a": {"mode_accuracy": None if stays_have else 0.85, "armse_pos": 20.0,
                      "mode_prob_tv": 0.1}}
    plots.tradeoff_figure(policies, fixed, tmp_path / "t.png", META)
    ax = drawn[0].axes[0]
    assert ax.axison
    assert not any("no mode accuracy" in t.get_text() for t in ax.texts)
    points = [line.get_xydata().tolist() for line in ax.get_lines() if len(line.get_xdata())]
    assert points == ([[[70.0, 25.0]]] if stays_have else [[[85.0, 20.0]]])
