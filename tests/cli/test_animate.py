"""``python -m imm_gym.evaluate --animate``: the file, its frames, the panels' common random
numbers, and the errors raised before any evaluation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from matplotlib.animation import FFMpegWriter
from matplotlib.colors import to_rgb
from PIL import Image

import imm_gym.cli.evaluate as cli
from baselines import REGISTRY, BuildContext
from imm_gym.evaluation import animation
from imm_gym.evaluation.animation import (
    check_animation_path,
    gif_palette,
    rollout_view,
    side_by_side_frames,
    write_animation,
)
from imm_gym.evaluation.rollout import evaluation_config, rollout
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.sim.render import TrackFigure, model_labels
from imm_gym.validation import ConfigError

#: 20 steps with a turn, outliers and missed detections
SCENARIO = {
    "segments": [{"duration": 8}, {"duration": 12, "turn_rate_deg": 3.0}],
    "position": [3000.0, 4500.0],
    "velocity": [20.0, 15.0],
}
CLUTTER = EnvConfig(
    scenario=SCENARIO, sensor={"outlier_prob": 0.2, "detection_prob": 0.8}
)


def _rollouts(config: EnvConfig, seed: int, names=("fixed", "tip-imm")) -> dict:
    out = {}
    for name in names:
        policy, _ = REGISTRY[name].build(BuildContext(config, seed, 1, None))
        out[name] = rollout(policy, evaluation_config(config, policy.env_overrides), 2, seed)
    return out


def test_cli_writes_one_frame_per_step_with_the_policies_side_by_side(tmp_path, capsys) -> None:
    scenario = tmp_path / "short.json"
    scenario.write_text(json.dumps(SCENARIO))
    out = tmp_path / "anim" / "episode.gif"
    code = cli.main(
        ["--policy", "fixed", "--policy", "tip-imm", "--scenario", str(scenario), "--runs", "2",
         "--seed", "4", "--no-clairvoyant", "--quiet", "--animate", str(out)]
    )
    assert code == 0
    with Image.open(out) as gif:
        assert gif.n_frames == 20
        assert gif.size == (2 * 560, 350)
        assert gif.info["duration"] == 100 and gif.info["loop"] == 0
        gif.seek(0)
        first = np.asarray(gif.convert("RGB"))
        gif.seek(19)
        last = np.asarray(gif.convert("RGB"))
    assert np.any(first != last)
    assert f"wrote {out} (20 frames of seed 4: fixed, tip-imm)" in capsys.readouterr().out


def test_panels_share_the_target_and_the_noise_and_frames_repeat() -> None:
    rollouts = _rollouts(CLUTTER, 7)
    batch = draw_batch(CLUTTER.source, CLUTTER.sensor, 1, 7, CLUTTER.velocity_std)
    views = {
        name: rollout_view(r, batch, CLUTTER.sensor, name, 12) for name, r in rollouts.items()
    }
    fixed, tip = views["fixed"], views["tip-imm"]
    for field in ("truth", "measurements", "detected", "outlier", "true_model"):
        np.testing.assert_array_equal(getattr(fixed, field), getattr(tip, field))
    assert not fixed.detected.all() and fixed.outlier.any()  # both marks are exercised
    assert np.any(fixed.estimate != tip.estimate) and np.any(fixed.tpm != tip.tpm)
    np.testing.assert_array_equal(fixed.estimate[1:], rollouts["fixed"].estimate[0, :12, :2])
    np.testing.assert_array_equal(fixed.mode_probs[0], np.full(3, 1 / 3))
    once = list(side_by_side_frames(rollouts, CLUTTER, 7, scale=0.5))
    again = list(side_by_side_frames(rollouts, CLUTTER, 7, scale=0.5))
    assert len(once) == 20 and once[0].shape == (200, 2 * 320, 3) and once[0].dtype == np.uint8
    for a, b in zip(once, again, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_rollout_of_another_seed_is_refused(tmp_path) -> None:
    family = EnvConfig(scenario="random", family={"horizon": 20, "n_segments": [1, 2]})
    rollouts = _rollouts(family, 7, names=("fixed",))
    with pytest.raises(ValueError, match="not run 0 of seed 8"):
        write_animation(rollouts, family, 8, tmp_path / "a.gif")
    assert not (tmp_path / "a.gif").exists()


def test_the_palette_keeps_the_figure_colours() -> None:
    palette = gif_palette()
    assert palette.shape == (256, 3) and palette.dtype == np.uint8
    colours = {tuple(c) for c in palette}
    for i in range(10):
        assert tuple(np.round(np.array(to_rgb(f"C{i}")) * 255).astype(np.uint8)) in colours
    assert (0, 0, 0) in colours and (255, 255, 255) in colours


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--animate", "episode.avi"], "must end in .gif or .mp4"),
        (["--animate", "{tmp}"], "is a directory"),
        (["--animate", "a.gif", "--scenario", "seed002"], "does not apply"),
    ],
)
def test_bad_animation_requests_stop_before_evaluating(
    monkeypatch, capsys, tmp_path, extra, message
) -> None:
    (tmp_path / "dir.gif").mkdir()
    extra = [arg.format(tmp=tmp_path / "dir.gif") for arg in extra]

    def refuse(*args, **kwargs):
        raise AssertionError("evaluated before checking --animate")

    monkeypatch.setattr(cli, "evaluate", refuse)
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["--policy", "fixed", "--runs", "1", *extra])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.skipif(FFMpegWriter.isAvailable(), reason="ffmpeg is installed")
def test_mp4_without_ffmpeg_is_a_clear_usage_error(monkeypatch, capsys, tmp_path) -> None:
    monkeypatch.setattr(cli, "evaluate", lambda *a, **k: pytest.fail("evaluated"))
    with pytest.raises(SystemExit):
        cli.main(["--policy", "fixed", "--animate", str(tmp_path / "a.mp4")])
    assert "needs ffmpeg" in capsys.readouterr().err


@pytest.mark.skipif(not FFMpegWriter.isAvailable(), reason="ffmpeg is not installed")
def test_mp4_is_written_where_ffmpeg_is_installed(tmp_path) -> None:
    path = tmp_path / "a.mp4"
    assert write_animation(_rollouts(CLUTTER, 7), CLUTTER, 7, path, scale=0.5) == 20
    assert path.stat().st_size > 1000


def test_the_view_of_run_1_is_that_runs_step_and_its_picture_draws_it() -> None:
    """Run 1 of a random family (its true models not run 0's) at every step ``t``: the TPM and
    the covariance are those of step ``t`` (index ``t - 1`` of the roll-out; the TIP-IMM's TPM
    moves from step to step), the true models run 1's, and the figure's heatmap, ellipse and
    true-model bar show them."""
    family = EnvConfig(scenario="random", family={"horizon": 30, "n_segments": [1, 3]})
    tip = _rollouts(family, 0, names=("tip-imm",))["tip-imm"]
    assert not tip.diverged.any()
    assert np.any(tip.true_model[0] != tip.true_model[1])
    batch = draw_batch(family.source, family.sensor, 2, 0, family.velocity_std, family.vary)
    np.testing.assert_array_equal(batch.truth.states[1, 1:], tip.truth[1])
    picture = TrackFigure(model_labels(family.bank))
    moved = 0
    for t in range(1, 31):
        view = rollout_view(tip, batch, family.sensor, "tip-imm", t, run=1)
        np.testing.assert_array_equal(view.tpm, tip.tpm[1, t - 1])
        np.testing.assert_array_equal(view.covariance, tip.covariance[1, t - 1, :2, :2])
        np.testing.assert_array_equal(view.true_model[1:], tip.true_model[1, :t])
        np.testing.assert_array_equal(view.estimate[1:], tip.estimate[1, :t, :2])
        np.testing.assert_array_equal(view.truth, batch.truth.states[1, : t + 1, :2])
        moved += t > 1 and not np.array_equal(tip.tpm[1, t - 1], tip.tpm[1, t - 2])
        picture.frame(view)
        np.testing.assert_array_equal(picture.heat.get_array(), tip.tpm[1, t - 1])
        lam = np.linalg.eigvalsh(tip.covariance[1, t - 1, :2, :2])
        quantile = -2.0 * np.log(0.05)
        assert picture.ellipse.width == pytest.approx(2 * np.sqrt(quantile * lam[1]))
        assert picture.ellipse.height == pytest.approx(2 * np.sqrt(quantile * lam[0]))
        last = {
            j for j, bar in enumerate(picture.true_bars)
            if len(bar.get_ydata()) and np.isfinite(bar.get_ydata()[-1])
        }
        assert last == {int(tip.true_model[1, t - 1])}
    assert moved >= 15


@pytest.mark.parametrize("name", ["episode.GIF", "episode.Gif"])
def test_an_upper_case_gif_suffix_is_accepted(name: str, tmp_path) -> None:
    """The suffix is read whatever its case (a .GIF is written as a GIF)."""
    check_animation_path(tmp_path / name)
    with pytest.raises(ConfigError, match="must end in"):
        check_animation_path(tmp_path / "episode.GIFF")


def test_the_view_of_run_1_draws_that_runs_sensor_draws_and_scene() -> None:
    """Run 1 of a random family with outliers and misses: the detections, outliers and measured
    positions are run 1's own (its non-outlier measurements within a few noise deviations of
    its truth, its flags not run 0's), its track starts at its first measurement, and the scene
    holds its whole path and the sensor."""
    family = EnvConfig(
        scenario="random", family={"horizon": 30, "n_segments": [1, 3]},
        sensor={"outlier_prob": 0.2, "detection_prob": 0.7},
    )
    tip = _rollouts(family, 0, names=("tip-imm",))["tip-imm"]
    batch = draw_batch(family.source, family.sensor, 2, 0, family.velocity_std, family.vary)
    K = 30
    view = rollout_view(tip, batch, family.sensor, "tip-imm", K, run=1)
    truth = batch.truth.states[1, :, :2]
    assert np.linalg.norm(truth - batch.truth.states[0, :, :2], axis=1).min() > 500.0
    flags = batch.measurements
    assert np.any(flags.detected[0] != flags.detected[1])
    assert np.any(flags.outlier[0] != flags.outlier[1])
    np.testing.assert_array_equal(view.detected, flags.detected[1])
    np.testing.assert_array_equal(view.outlier, flags.outlier[1])
    # range-bearing noise: sigma_r and the bearing's arc at the target's range
    sensor = family.sensor
    rng = np.linalg.norm(truth - np.asarray(sensor.position), axis=1)
    bound = 5.0 * np.hypot(sensor.sigma_r, rng * np.radians(sensor.sigma_theta_deg))
    clean = view.detected & ~view.outlier
    assert clean.sum() >= 10
    miss = np.linalg.norm(view.measurements - truth, axis=1)
    assert np.all(miss[clean] < bound[clean])
    np.testing.assert_allclose(view.estimate[0], view.measurements[0], atol=1e-9)
    x_min, x_max, y_min, y_max = view.extent
    for x, y in (*truth, sensor.position):
        assert x_min < x < x_max and y_min < y < y_max


def test_a_rollout_of_another_bank_is_refused() -> None:
    """A roll-out of a three-model bank drawn as the configuration's two-model bank: refused by
    name (it drew three curves under two names)."""
    two = EnvConfig(
        scenario=SCENARIO,
        bank=[{"kind": "cv"}, {"kind": "ct", "turn_rate_deg": 3.0}],
    )
    rollouts = _rollouts(EnvConfig(scenario=SCENARIO), 7, names=("fixed",))
    with pytest.raises(ValueError, match="not of the configured bank"):
        next(side_by_side_frames(rollouts, two, 7))


def test_the_palette_holds_each_colour_blended_with_white() -> None:
    """The antialiased edges of a C0..C9 artist: the colour at 75, 50 and 25 % over white,
    ``a c + (1 - a)``, worked out here (to a unit of rounding)."""
    palette = gif_palette().astype(np.int64)
    for i in range(10):
        c = np.array(to_rgb(f"C{i}"))
        for a in (0.75, 0.5, 0.25):
            blend = (a * c + 1.0 - a) * 255.0
            assert np.abs(palette - blend).max(axis=1).min() <= 1.0, (i, a)


def test_the_mp4_writer_writes_every_frame_as_drawn(monkeypatch) -> None:
    """Each frame grabbed is the frame given, pixel for pixel (a writer that kept showing the
    first frame wrote a still MP4)."""
    import contextlib

    import matplotlib.animation

    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (20, 30, 3), dtype=np.uint8) for _ in range(4)]
    grabbed = []

    class Writer:
        def __init__(self, fps: float) -> None:
            pass

        @contextlib.contextmanager
        def saving(self, fig, path, dpi):
            self.fig = fig
            yield

        def grab_frame(self) -> None:
            self.fig.canvas.draw()
            grabbed.append(np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy())

    monkeypatch.setattr(matplotlib.animation, "FFMpegWriter", Writer)
    assert animation._write_mp4(iter(frames), Path("unused.mp4"), 10) == 4
    assert len(grabbed) == 4
    for written, frame in zip(grabbed, frames, strict=True):
        np.testing.assert_array_equal(written, frame)


def test_the_title_names_the_step_of_the_horizon_and_a_divergence_from_its_step() -> None:
    """The paper's scenario has 150 steps: the picture's title reads ``t = k / 150``; run 2 of
    these settings diverges at step 77, whose estimate is already missing: from that step on
    the title says so, the step before it does not."""
    config = EnvConfig.build({"scenario": "paper", "divergence_error": 60.0})
    policy, _ = REGISTRY["fixed"].build(BuildContext(config, 0, 1, None))
    run = rollout(policy, evaluation_config(config, policy.env_overrides), 3, 0)
    assert run.diverged_at(2) == 77
    batch = draw_batch(config.source, config.sensor, 3, 0, config.velocity_std)
    picture = TrackFigure(model_labels(config.bank))
    before = rollout_view(run, batch, config.sensor, "fixed", 76, 2)
    at = rollout_view(run, batch, config.sensor, "fixed", 77, 2)
    assert np.isfinite(before.estimate).all() and np.isnan(at.estimate[77]).all()
    assert (before.title, at.title) == ("fixed", "fixed, diverged at step 77")
    assert before.horizon == at.horizon == 150
    picture.update(at)
    assert picture.title.get_text() == "fixed, diverged at step 77   t = 77 / 150"
