"""The render modes: frames, determinism, the env checkers, the vector env's frames, the
histories behind a picture, ``"human"`` without a display, and nothing done without a mode."""

from __future__ import annotations

import copy
import itertools
import math
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from PIL import Image

import imm_gym.envs.tpm_adapt as tpm_adapt
import imm_gym.envs.vector as vector
from imm_gym.envs import TPMAdaptEnv, TPMAdaptVectorEnv
from imm_gym.sim.episodes import draw_batch
from imm_gym.sim.render import CHI2_2_95, TrackFigure, ellipse_axes
from imm_gym.validation import ConfigError

PAPER = "imm_gym/TPMAdaptPaper-v0"
#: a short episode with outliers and missed detections
CLUTTER = {
    "scenario": {"segments": [{"duration": 12}, {"duration": 13, "turn_rate_deg": 3.0}]},
    "sensor": {"outlier_prob": 0.2, "detection_prob": 0.8},
}


def _frames(env: gym.Env, seed: int, steps: int) -> list[np.ndarray]:
    env.reset(seed=seed)
    frames = [env.render()]
    action = np.full(env.action_space.shape, 0.3, dtype=np.float32)
    for _ in range(steps):
        env.step(action)
        frames.append(env.render())
    return frames


def test_frames_are_rgb_uint8_change_every_step_and_repeat_with_the_seed() -> None:
    env = gym.make(PAPER, render_mode="rgb_array")
    first = _frames(env, 5, 6)
    again = _frames(gym.make(PAPER, render_mode="rgb_array"), 5, 6)
    other = _frames(env, 6, 6)
    for frame in first:
        assert frame.dtype == np.uint8 and frame.shape == (400, 640, 3)
    for a, b in itertools.pairwise(first):
        assert np.count_nonzero(np.any(a != b, axis=-1)) > 100  # the picture moves every step
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a, b)
    assert any(np.any(a != b) for a, b in zip(first, other, strict=True))
    assert env.render() is not first[-1]  # a fresh array every call


@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
def test_a_copy_of_a_rendering_env_draws_the_same_frames(how: str) -> None:
    env = gym.make(PAPER, render_mode="rgb_array")
    env.reset(seed=3)
    for _ in range(4):
        env.step(np.zeros(9))
        env.render()
    twin = pickle.loads(pickle.dumps(env)) if how == "pickle" else copy.deepcopy(env)
    np.testing.assert_array_equal(twin.render(), env.render())
    for _ in range(3):
        env.step(np.full(9, 0.3))
        twin.step(np.full(9, 0.3))
        np.testing.assert_array_equal(twin.render(), env.render())


def test_a_new_episode_redraws_the_scene() -> None:
    """The scene's extent changes with the episode; the background must follow it."""
    env = gym.make("imm_gym/TPMAdapt-v0", render_mode="rgb_array")
    env.reset(seed=1)
    env.render()
    env.reset(seed=2)
    after_switch = env.render()
    fresh = gym.make("imm_gym/TPMAdapt-v0", render_mode="rgb_array")
    fresh.reset(seed=2)
    np.testing.assert_array_equal(after_switch, fresh.render())


@pytest.mark.parametrize("mode", ["rgb_array", "human"])
def test_gymnasium_checker_passes_without_warnings_with_a_render_mode(mode: str) -> None:
    env = gym.make(PAPER, render_mode=mode)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    assert [f"{w.category.__name__}: {w.message}" for w in caught] == []
    env.close()


def test_passive_checker_is_silent_with_rgb_array() -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make(PAPER, render_mode="rgb_array")
        env.reset(seed=0)
        env.render()
        env.step(env.action_space.sample())
        frame = env.render()
    assert [str(w.message) for w in caught] == []
    assert frame.shape == (400, 640, 3)


def test_metadata_follows_gymnasium() -> None:
    for cls in (TPMAdaptEnv, TPMAdaptVectorEnv):
        assert "rgb_array" in cls.metadata["render_modes"]
        assert cls.metadata["render_fps"] > 0
    assert "human" in TPMAdaptEnv.metadata["render_modes"]


def test_bad_render_modes_and_render_before_reset() -> None:
    with pytest.raises(ValueError, match="render_mode"):
        TPMAdaptEnv(render_mode="ansi")
    with pytest.raises(ValueError, match="render_mode"):
        TPMAdaptVectorEnv(2, render_mode="human")
    with pytest.raises(ValueError, match="render_envs"):
        TPMAdaptVectorEnv(2, render_mode="rgb_array", render_envs=[2])
    with pytest.raises(ValueError, match="render_envs"):
        TPMAdaptVectorEnv(2, render_mode="rgb_array", render_envs=[True])
    # numpy's integers are indices too
    picked = TPMAdaptVectorEnv(2, render_mode="rgb_array", render_envs=np.array([1]))
    assert picked.render_envs == (1,) and type(picked.render_envs[0]) is int
    with pytest.raises(RuntimeError, match="reset"):
        TPMAdaptEnv(render_mode="rgb_array").render()


def test_render_envs_is_read_once_from_any_iterable_and_selects_a_sub_env() -> None:
    """A generator is read once: its indices are the ones checked and rendered (the check
    consumed it and no sub-env was drawn); a selection of none is refused by name."""
    venv = TPMAdaptVectorEnv(3, render_mode="rgb_array", render_envs=(i for i in [1, 2]))
    assert venv.render_envs == (1, 2)
    venv.reset(seed=0)
    assert len(venv.render()) == 2
    with pytest.raises(ValueError, match="render_envs"):
        TPMAdaptVectorEnv(3, render_mode="rgb_array", render_envs=iter([1, 3]))
    for none in ([], iter([]), np.array([], dtype=int)):
        with pytest.raises(ConfigError, match="render_envs must select at least one sub-env"):
            TPMAdaptVectorEnv(3, render_mode="rgb_array", render_envs=none)
    with pytest.raises(ConfigError, match="render_envs"):
        TPMAdaptVectorEnv(3, render_mode="rgb_array", render_envs=1)


def test_render_without_a_mode_warns_and_returns_none() -> None:
    env = TPMAdaptEnv()
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


def test_rendering_off_builds_no_renderer(monkeypatch) -> None:
    """Without a render mode no figure exists and no step records anything."""

    def refuse(*args, **kwargs):
        raise AssertionError("a renderer was built without a render mode")

    monkeypatch.setattr(tpm_adapt, "CoreRenderer", refuse)
    monkeypatch.setattr(vector, "CoreRenderer", refuse)
    env = gym.make(PAPER)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    venv = gym.make_vec(PAPER, num_envs=2, vectorization_mode="vector_entry_point")
    venv.reset(seed=0)
    venv.step(venv.action_space.sample())
    with pytest.raises(AssertionError, match="renderer"):
        gym.make(PAPER, render_mode="rgb_array")


def test_human_mode_without_a_display_draws_and_returns_none() -> None:
    import matplotlib.pyplot as plt

    probe = plt.figure()
    interactive = probe.canvas.required_interactive_framework is not None
    plt.close(probe)
    if interactive:
        pytest.skip("a display exists: 'human' would open a window during the tests")
    before = plt.get_fignums()
    env = gym.make(PAPER, render_mode="human")
    env.reset(seed=0)
    for _ in range(3):
        env.step(env.action_space.sample())
    assert env.render() is None
    assert plt.get_fignums() == before  # no pyplot figure left behind without a display
    env.close()


def test_vector_env_frames_are_the_sub_envs_pictures_through_autoresets() -> None:
    """Sub-env i's picture data equals that of a scalar env reset with seed + i, also after an
    autoreset; render() returns one frame per chosen sub-env."""
    venv = TPMAdaptVectorEnv(3, config=CLUTTER, render_mode="rgb_array", render_envs=[0, 2])
    scalars = [TPMAdaptEnv(config=CLUTTER, render_mode="rgb_array") for _ in range(3)]
    venv.reset(seed=10)
    for i, env in enumerate(scalars):
        env.reset(seed=10 + i)
    rng = np.random.default_rng(0)
    horizon = 25
    for k in range(horizon + 4):
        actions = rng.uniform(-1, 1, (3, 9)).astype(np.float32)
        venv.step(actions)
        for i, env in enumerate(scalars):
            if k == horizon:  # the vector env's autoreset step: the scalar envs reset
                env.reset()
            else:
                env.step(actions[i])
        if k in (3, horizon - 1, horizon, horizon + 3):
            for i, env in enumerate(scalars):
                a, b = venv._renderer.view(i), env._renderer.view(0)
                assert a.step == b.step
                for field in ("truth", "estimate", "covariance", "measurements", "detected",
                              "outlier", "mode_probs", "true_model", "tpm"):
                    np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    frames = venv.render()
    assert isinstance(frames, tuple) and len(frames) == 2
    assert all(f.shape == (400, 640, 3) and f.dtype == np.uint8 for f in frames)
    assert np.any(frames[0] != frames[1])
    assert len(TPMAdaptVectorEnv(2, render_mode="rgb_array").render_envs) == 2  # default: all


def test_vector_env_frames_after_a_slots_first_only_redraw_what_moves(monkeypatch) -> None:
    """Each sub-env keeps the background of its own scene: over steps that move no axis limit a
    frame blits, and it is the picture a fresh figure draws in full (one figure for every
    sub-env drew its whole background again at every frame, each scene's extent differing)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    full = []
    draw = FigureCanvasAgg.draw

    def counted(canvas: FigureCanvasAgg) -> None:
        full.append(canvas)
        draw(canvas)

    monkeypatch.setattr(FigureCanvasAgg, "draw", counted)
    venv = TPMAdaptVectorEnv(3, render_mode="rgb_array")  # render_envs None: all three
    venv.reset(seed=0)
    assert len({view.extent for view in map(venv._renderer.view, range(3))}) == 3
    action = np.zeros((3, 9), dtype=np.float32)
    counts = []
    for _ in range(6):
        venv.step(action)
        frames = venv.render()
        counts.append(len(full))
    assert counts == [3] * 6  # a full draw at each sub-env's first frame, blitting after it
    fresh = TrackFigure(venv._renderer.labels)
    for i, frame in enumerate(frames):
        np.testing.assert_array_equal(frame, fresh.frame(venv._renderer.view(i)))


def test_the_scenes_tick_labels_stand_apart() -> None:
    """Over 40 episodes of the default family the scene's x tick labels are at least 3 px apart
    (five on the panel's 116 px read as one number: '−4000' and '−2000' 1.8 px apart, seed 1)."""
    env = gym.make("imm_gym/TPMAdapt-v0", render_mode="rgb_array")
    gaps = []
    for seed in range(40):
        env.reset(seed=seed)
        env.render()
        figure = env.unwrapped._renderer.figure(0)
        ax, renderer = figure.ax_scene, figure.fig.canvas.get_renderer()
        low, high = ax.get_xlim()
        boxes = [
            label.get_window_extent(renderer)
            for tick, label in zip(ax.get_xticks(), ax.get_xticklabels(), strict=True)
            if low <= tick <= high
        ]
        assert len(boxes) >= 2
        gaps += [right.x0 - left.x1 for left, right in itertools.pairwise(boxes)]
    assert min(gaps) >= 3.0


def test_the_picture_marks_misses_and_outliers_of_the_episode() -> None:
    env = TPMAdaptEnv(config=CLUTTER, render_mode="rgb_array")
    env.reset(seed=3)
    for _ in range(25):
        env.step(np.zeros(9, dtype=np.float32))
    view = env._renderer.view(0)
    cfg = env.config
    batch = draw_batch(cfg.source, cfg.sensor, 1, 3, cfg.velocity_std)
    drawn = batch.measurements
    np.testing.assert_array_equal(view.detected, drawn.detected[0])
    assert not view.detected.all()
    np.testing.assert_array_equal(view.outlier, drawn.outlier[0])  # the sensor's own draws
    assert view.outlier.any()
    np.testing.assert_allclose(view.truth, batch.truth.states[0, :, :2])


def test_ellipse_axes_are_the_95_percent_contour() -> None:
    width, height, angle = ellipse_axes(np.diag([4.0, 1.0]))
    assert width == pytest.approx(2 * math.sqrt(CHI2_2_95 * 4.0))
    assert height == pytest.approx(2 * math.sqrt(CHI2_2_95))
    assert angle % 180.0 == pytest.approx(0.0, abs=1e-9)
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    rot = np.array([[c, -s], [s, c]])
    width, height, angle = ellipse_axes(rot @ np.diag([9.0, 1.0]) @ rot.T)
    assert (width, height) == pytest.approx((6 * math.sqrt(CHI2_2_95), 2 * math.sqrt(CHI2_2_95)))
    assert angle % 180.0 == pytest.approx(30.0)
    assert CHI2_2_95 == pytest.approx(5.991464547107979)


def test_a_frame_loop_writes_a_gif(tmp_path) -> None:
    env = gym.make(PAPER, render_mode="rgb_array")
    frames = _frames(env, 0, 4)
    path = tmp_path / "episode.gif"
    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=100, loop=0)
    with Image.open(path) as gif:
        assert gif.n_frames == 5 and gif.size == (640, 400)


def test_record_video_writes_a_file_when_moviepy_is_installed(tmp_path) -> None:
    pytest.importorskip("moviepy", reason="RecordVideo needs moviepy (not a dependency)")
    env = gym.wrappers.RecordVideo(
        gym.make(PAPER, render_mode="rgb_array", scenario={"segments": [{"duration": 5}]}),
        str(tmp_path),
        episode_trigger=lambda episode: True,
    )
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        done = terminated or truncated
    env.close()
    assert list(tmp_path.glob("*.mp4"))


@pytest.mark.parametrize("make", ["scalar", "vector"])
def test_an_env_whose_constructor_failed_closes_quietly(make) -> None:
    """Gymnasium closes an env whose constructor raised: no AttributeError from the renderer."""
    from imm_gym.envs.tpm_adapt import TPMAdaptEnv
    from imm_gym.envs.vector import TPMAdaptVectorEnv

    cls = TPMAdaptEnv if make == "scalar" else TPMAdaptVectorEnv
    env = cls.__new__(cls)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env.close()


def test_closing_the_vector_env_releases_every_slots_figure() -> None:
    """Each drawn slot has its figure (several megabytes); ``close`` lets them go (the renderer
    kept every figure until the env itself was collected), and a later frame draws anew."""
    env = TPMAdaptVectorEnv(3, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    renderer = env._renderer
    assert len(renderer.figures) == 3
    env.close()
    assert renderer.figures == {}
    np.testing.assert_array_equal(renderer.frame(0), first[0])


#: 50 steps, a turn from step 31 on, outliers and missed detections
LONG_CLUTTER = {
    "scenario": {
        "segments": [{"duration": 30}, {"duration": 20, "turn_rate_deg": 3.0}],
        "position": [3000.0, 4500.0],
        "velocity": [20.0, 15.0],
    },
    "sensor": {"outlier_prob": 0.2, "detection_prob": 0.8},
}


def _xy(line) -> np.ndarray:
    return np.column_stack([line.get_xdata(), line.get_ydata()]).astype(np.float64)


def _drawn_rows(line) -> np.ndarray:
    return np.isfinite(_xy(line)).all(axis=1)


def test_the_drawn_artists_are_the_steps_data() -> None:
    """Every step's picture, read from its artists, against the step's own ``info`` (and the
    sensor's draws): the heatmap is the non-symmetric TPM the step used, the ellipse the 95 %
    contour of the position covariance around the estimate (an eigen-decomposition done here),
    the tracks the truth and the estimates relative to the true target, the misses on the truth
    where the step had no detection, the outliers where the sensor drew one, the mode
    probabilities of each step at that step, the true-model bar the step's true model, and the
    mode probabilities' window moving on by 20 steps when the step reaches its right end."""
    seed = 4
    env = TPMAdaptEnv(config=LONG_CLUTTER, render_mode="rgb_array")
    env.reset(seed=seed)
    env.render()
    figure = env._renderer.figure(0)
    cfg = env.config
    batch = draw_batch(cfg.source, cfg.sensor, 1, seed, cfg.velocity_std)
    outlier = batch.measurements.outlier[0]
    rng = np.random.default_rng(1)
    truth, estimate, detected, probs, models = [], [], [True], {}, {}
    horizon = env.core.horizon
    assert horizon >= 45
    first_of = {10: 0, 39: 0, 40: 20, 45: 20}
    asymmetric = 0
    seen = set()
    for k in range(1, horizon + 1):
        _, _, terminated, _, info = env.step(rng.uniform(-1, 1, 9).astype(np.float32))
        assert not terminated or k == horizon
        env.render()
        truth.append(info["true_state"][:2])
        estimate.append(info["estimate"][:2])
        detected.append(bool(info["detected"]))
        probs[k], models[k] = info["mode_probs"], int(info["true_model"])
        seen.add(models[k])
        p, x = info["true_state"][:2], info["estimate"][:2]

        tpm = np.asarray(info["tpm"])
        np.testing.assert_allclose(figure.heat.get_array(), tpm)
        asymmetric += not np.allclose(tpm, tpm.T, atol=1e-3)

        cov = np.asarray(info["covariance"])[:2, :2]
        lam, vec = np.linalg.eigh(cov)
        quantile = -2.0 * math.log(0.05)
        ellipse = figure.ellipse
        assert ellipse.get_visible()
        np.testing.assert_allclose(ellipse.get_center(), x - p, atol=1e-9)
        assert ellipse.width == pytest.approx(2 * math.sqrt(quantile * lam[1]))
        assert ellipse.height == pytest.approx(2 * math.sqrt(quantile * lam[0]))
        major = math.degrees(math.atan2(vec[1, 1], vec[0, 1]))
        turn = (ellipse.angle - major) % 180.0
        assert min(turn, 180.0 - turn) == pytest.approx(0.0, abs=1e-6)
        np.testing.assert_allclose(_xy(figure.now), [x - p], atol=1e-9)

        near = figure.tracks[0]
        np.testing.assert_allclose(_xy(near[0])[1:], np.array(truth) - p, atol=1e-9)
        np.testing.assert_allclose(_xy(near[1])[1:], np.array(estimate) - p, atol=1e-9)
        scene = figure.tracks[1]
        np.testing.assert_allclose(_xy(scene[0])[1:], np.array(truth), atol=1e-9)
        np.testing.assert_allclose(_xy(scene[1])[1:], np.array(estimate), atol=1e-9)
        missed = ~np.array(detected)
        for lines, origin in ((near, p), (scene, np.zeros(2))):
            np.testing.assert_array_equal(_drawn_rows(lines[4]), missed)
            np.testing.assert_allclose(
                _xy(lines[4])[1:][missed[1:]], (np.array(truth) - origin)[missed[1:]], atol=1e-9
            )
            np.testing.assert_array_equal(
                _drawn_rows(lines[3]), ~missed & outlier[: k + 1]
            )
            np.testing.assert_array_equal(_drawn_rows(lines[2]), ~missed)

        for j, line in enumerate(figure.mu_lines):
            steps, values = line.get_xdata(), line.get_ydata()
            assert steps[-1] == k
            for t, value in zip(steps, values, strict=True):
                if t >= 1:
                    assert value == pytest.approx(probs[int(t)][j])
        bars = {}
        for j, bar in enumerate(figure.true_bars):
            centres, heights = np.asarray(bar.get_xdata())[0::2] + 0.5, bar.get_ydata()[0::2]
            for t, h in zip(centres.tolist(), heights, strict=True):
                if np.isfinite(h):
                    assert round(t) not in bars
                    bars[round(t)] = j
        first = int(figure.mu_lines[0].get_xdata()[0])
        assert bars == {t: models[t] for t in range(max(first, 1), k + 1)}
        if k in first_of:
            assert first == first_of[k]
            assert figure.ax_mu.get_xlim() == (first_of[k], first_of[k] + 40)
    assert asymmetric >= 40
    assert len(seen) >= 2 and outlier.any() and not all(detected)


def test_models_of_one_kind_are_told_apart_by_their_noise_or_index() -> None:
    """The shipped probes' two CVs (q 0.05 and q 5) were both ``CV`` in every legend and tick; a
    name no other model has stays as it is."""
    from imm_gym import EnvConfig
    from imm_gym.sim.config_file import read_env_config
    from imm_gym.sim.render import model_labels, short_labels
    from imm_gym.tracking.hetero import HeteroBank
    from imm_gym.tracking.models import MotionModel

    bank = EnvConfig.build(read_env_config("examples/probes/cv2ct.yaml")).bank
    assert model_labels(bank) == ["CV q=0.05", "CV q=5", "CT(+3°/s)"]
    assert short_labels(model_labels(bank)) == ["CV q=0.05", "CV q=5", "CT+"]
    picture = TrackFigure(model_labels(bank))
    ticks = [t.get_text() for t in picture.ax_tpm.get_xticklabels()]
    assert ticks == ["CV q=0.05", "CV q=5", "CT+"]
    assert [t.get_text() for t in picture.ax_mu.get_legend().get_texts()] == model_labels(bank)

    discrete = (MotionModel("cv"), MotionModel("cv", q=(1.0, 1.0, 2.0, 2.0)))
    assert model_labels(discrete) == ["CV q=0.1/0.12", "CV q=1/2"]
    same = (MotionModel("ct", 4.0), MotionModel("ct", 4.0), MotionModel("ct", 2.0))
    assert model_labels(same) == ["CT(+4°/s) [0]", "CT(+4°/s) [1]", "CT(+2°/s)"]
    assert short_labels(model_labels(same)) == ["CT+4 [0]", "CT+4 [1]", "CT+2"]
    hetero = HeteroBank(models=("ncv", "ncv", "ct"), q_scale=(1.0, 2.0, 1.0))
    assert model_labels(hetero) == ["NCV Q×1", "NCV Q×2", "CT"]
    assert model_labels(HeteroBank()) == ["NCV", "CT", "CTRA"]
    assert short_labels(["CV", "CT(+4°/s)", "CT(-4°/s)"]) == ["CV", "CT+", "CT−"]


@pytest.mark.parametrize("labels", [
    ["CV", "CT(+2°/s)", "CT(+6°/s)", "CT(-2.5°/s)", "CT(-6°/s)"],
    ["CV q=0.05", "CV q=5", "CT(+3°/s)"],
])
def test_the_tpm_heatmaps_labels_and_stays_stand_apart(labels: list[str]) -> None:
    """Five models, or three with long names: the column labels do not run together and each
    stay's text stays inside its cell (they overlapped at 6 points side by side)."""
    from imm_gym.sim.render import TrackView

    M, k = len(labels), 5
    path = np.column_stack([np.arange(k + 1) * 10.0, np.zeros(k + 1)])
    tpm = np.full((M, M), 0.02 / (M - 1))
    np.fill_diagonal(tpm, 0.98)
    view = TrackView("test", k, 10, path, path + 1.0, np.eye(2), path, np.ones(k + 1, bool),
                     np.zeros(k + 1, bool), np.full((k + 1, M), 1.0 / M),
                     np.zeros(k + 1, np.int64), tpm, np.zeros(2), (-10.0, 60.0, -10.0, 10.0))
    picture = TrackFigure(labels)
    picture.frame(view)
    renderer = picture.fig.canvas.get_renderer()
    ticks = [t.get_window_extent(renderer) for t in picture.ax_tpm.get_xticklabels()]
    assert all(a.x1 <= b.x0 for a, b in itertools.pairwise(ticks))
    cell = picture.ax_tpm.get_window_extent(renderer).width / M
    assert all(t.get_text() == "0.980" for t in picture.stays)
    assert all(t.get_window_extent(renderer).width < cell for t in picture.stays)


@pytest.mark.parametrize(("M", "rows"), [(3, 1), (4, 1), (5, 2), (9, 3)])
def test_the_models_legend_stays_within_the_mode_probabilities_axes(M: int, rows: int) -> None:
    """One row of legend for nine models ran past both edges of the figure; the legend takes as
    few rows as keep it within the axes' width, one where it fits."""
    from imm_gym.sim.render import model_labels
    from imm_gym.tracking.models import MotionModel

    rates = (2.0, -2.0, 5.0, -5.0, 8.0, -8.0, 1.0, -1.0)[: M - 1]
    labels = model_labels([MotionModel("cv"), *(MotionModel("ct", r) for r in rates)])
    picture = TrackFigure(labels)
    picture.fig.canvas.draw()
    legend = picture.ax_mu.get_legend()
    assert [t.get_text() for t in legend.get_texts()] == labels
    box, axes = legend.get_window_extent(), picture.ax_mu.get_window_extent()
    assert axes.x0 <= box.x0 and box.x1 <= axes.x1
    heights = {round(t.get_window_extent().y0) for t in legend.get_texts()}
    assert len(heights) == rows
    picture.close()


def test_the_first_picture_draws_the_tracks_start() -> None:
    """At reset (``t = 0``) the picture holds the track's start as the sensor's first
    measurement initiated it (:func:`draw_batch`'s ``x0``, ``P0``: its position, the position
    block of its covariance as the 95 % ellipse) and the tracker's first mode probabilities
    (a heterogeneous bank's 0.90, 0.08, 0.02, not uniform), drawn at step 0."""
    config = {**CLUTTER, "bank": {"models": ["ncv", "ct", "ctra"]}, "filter": "ekf"}
    env = TPMAdaptEnv(config=config, render_mode="rgb_array")
    env.reset(seed=3)
    env.render()
    cfg = env.config
    batch = draw_batch(cfg.source, cfg.sensor, 1, 3, cfg.velocity_std)
    view = env._renderer.view(0)
    np.testing.assert_allclose(view.estimate[0], batch.x0[0, :2], atol=1e-9)
    np.testing.assert_allclose(view.covariance, batch.P0[0, :2, :2], rtol=1e-9)
    np.testing.assert_allclose(view.mode_probs[0], [0.90, 0.08, 0.02], atol=1e-12)
    figure = env._renderer.figure(0)
    p = batch.truth.states[0, 0, :2]
    lam = np.linalg.eigvalsh(batch.P0[0, :2, :2])
    assert figure.ellipse.get_visible()
    assert figure.ellipse.width == pytest.approx(2 * math.sqrt(CHI2_2_95 * lam[1]))
    assert figure.ellipse.height == pytest.approx(2 * math.sqrt(CHI2_2_95 * lam[0]))
    np.testing.assert_allclose(figure.ellipse.get_center(), batch.x0[0, :2] - p, atol=1e-9)
    np.testing.assert_allclose(_xy(figure.tracks[1][1]), [batch.x0[0, :2]], atol=1e-9)
    for line, value in zip(figure.mu_lines, (0.90, 0.08, 0.02), strict=True):
        assert list(line.get_xdata()) == [0] and line.get_ydata()[0] == pytest.approx(value)


def test_the_measurements_drawn_are_the_sensors_draws_at_their_steps() -> None:
    """Each step's measured position is that step's draw of the sensor (polar to Cartesian,
    worked out here from :func:`draw_batch`'s ranges and bearings), drawn where detected."""
    env = TPMAdaptEnv(config=CLUTTER, render_mode="rgb_array")
    env.reset(seed=3)
    for _ in range(25):
        env.step(np.zeros(9, dtype=np.float32))
    env.render()
    cfg = env.config
    z = draw_batch(cfg.source, cfg.sensor, 1, 3, cfg.velocity_std).measurements.z[0]
    position = np.asarray(cfg.sensor.position)
    xy = position + z[:, :1] * np.column_stack([np.cos(z[:, 1]), np.sin(z[:, 1])])
    view = env._renderer.view(0)
    np.testing.assert_allclose(view.measurements, xy, rtol=1e-12, atol=1e-6)
    drawn = _xy(env._renderer.figure(0).tracks[1][2])
    np.testing.assert_allclose(drawn[view.detected], xy[view.detected], atol=1e-6)


def test_the_title_names_the_scenario_the_sub_env_and_the_step() -> None:
    """The scalar env's picture is titled by its scenario, a vector env's by the scenario and
    the sub-env drawn; both say the step of the horizon (the paper's 150 steps)."""
    env = gym.make(PAPER, render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.zeros(9, dtype=np.float32))
    env.render()
    assert env.unwrapped._renderer.figure(0).title.get_text() == "paper scenario   t = 1 / 150"
    venv = TPMAdaptVectorEnv(3, config={"scenario": "paper"}, render_mode="rgb_array",
                             render_envs=[2])
    venv.reset(seed=0)
    venv.render()
    assert venv._renderer.figure(2).title.get_text() == (
        "paper scenario, sub-env 2   t = 0 / 150"
    )
    custom = TPMAdaptEnv(config=CLUTTER, render_mode="rgb_array")
    custom.reset(seed=0)
    custom.render()
    assert custom._renderer.figure(0).title.get_text() == "custom scenario   t = 0 / 25"
