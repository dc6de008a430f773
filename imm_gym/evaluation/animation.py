"""An animation of one episode with every evaluated policy side by side.

:func:`write_animation` draws run ``run`` of the policies' roll-outs (:class:`Rollout`, the same
targets and sensor noise for every policy: common random numbers) with
:class:`imm_gym.sim.render.TrackFigure`, one panel per policy, one frame per step ``t = 1..K``,
and writes a GIF with Pillow or an MP4 with matplotlib's ``FFMpegWriter`` when ffmpeg is
installed. The measurements, detections and outlier flags are the sensor's draws of that run,
drawn again from its seed (:func:`imm_gym.sim.episodes.draw_batch`: the draws every policy saw).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imm_gym.evaluation.rollout import Rollout
from imm_gym.sim.core import design_bank
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import Batch, draw_batch
from imm_gym.sim.render import RENDER_FPS, TrackFigure, TrackView, model_labels, scene_extent
from imm_gym.tracking.hetero import HeteroBank
from imm_gym.tracking.models import MotionModel
from imm_gym.tracking.sensors import Sonar
from imm_gym.validation import ConfigError

Array = NDArray[np.float64]

#: The file types :func:`write_animation` writes.
FORMATS = (".gif", ".mp4")
#: A panel's scale: 560 x 350 pixels (two panels of a 150-step episode: a GIF of ~1.3 MB).
PANEL_SCALE = 0.875


def check_animation_path(path: Path) -> None:
    """Raise :class:`ConfigError` unless ``path`` ends in ``.gif``, or in ``.mp4`` with ffmpeg
    installed (checked before a long evaluation, not after)."""
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ConfigError(f"an animation file must end in {' or '.join(FORMATS)}, got {path}")
    if suffix == ".mp4":
        from matplotlib.animation import FFMpegWriter

        if not FFMpegWriter.isAvailable():
            raise ConfigError(
                f"writing {path} needs ffmpeg (matplotlib's FFMpegWriter), which is not "
                "installed; write a .gif instead"
            )


def rollout_view(
    rollout: Rollout, batch: Batch, sensor: Sonar, title: str, t: int, run: int = 0,
    start: Array | None = None,
) -> TrackView:
    """What run ``run`` of ``rollout`` shows at step ``t`` (1..K); ``batch`` holds the run's
    truth, measurements and track start as ``sensor`` made them (run ``run`` of both must be the
    same episode); ``start`` the tracker's mode probabilities at ``t = 0`` (uniform if None).

    The estimates, mode probabilities and ellipse are the tracker's
    (:meth:`Rollout.tracker_records`): none from the step the run diverged at, and from that step
    the title says ``"diverged at step k"``."""
    M = rollout.mode_probs.shape[-1]
    start = np.full(M, 1.0 / M) if start is None else np.asarray(start, dtype=np.float64)
    measurements = batch.measurements
    position = np.asarray(sensor.position, dtype=np.float64)
    estimate, mode_probs, covariance = rollout.tracker_records(run)
    lost = rollout.diverged_at(run)
    return TrackView(
        title=title if lost is None or t < lost else f"{title}, diverged at step {lost}",
        step=t,
        horizon=rollout.truth.shape[1],
        truth=batch.truth.states[run, : t + 1, :2],
        estimate=np.vstack([batch.x0[run, :2], estimate[:t, :2]]),
        covariance=covariance[t - 1, :2, :2],
        measurements=sensor.initial_position(measurements.z[run, : t + 1])[0],
        detected=measurements.detected[run, : t + 1],
        outlier=measurements.outlier[run, : t + 1],
        mode_probs=np.vstack([start, mode_probs[:t]]),
        true_model=np.concatenate([[-1], rollout.true_model[run, :t]]),
        tpm=rollout.tpm[run, t - 1],
        sensor=position,
        extent=scene_extent(batch.truth.states[run], position),
    )


def side_by_side_frames(
    rollouts: Mapping[str, Rollout],
    config: EnvConfig,
    seed: int,
    run: int = 0,
    scale: float = PANEL_SCALE,
) -> Iterator[NDArray[np.uint8]]:
    """The frames ``(H, W · P, 3)`` ``uint8`` of run ``run`` (seed ``seed + run``) for
    ``t = 1..K``, the P policies' pictures left to right in the order of ``rollouts``.

    Args:
        rollouts: the policies' roll-outs by name, all from seed ``seed`` on ``config``'s
            scenario, sensor and bank.
        config: the configuration evaluated (scenario, sensor, bank).
        seed: the roll-outs' seed.
        run: the run shown; scale: a panel is ``640·scale`` x ``400·scale`` pixels.

    Raises:
        ValueError: a roll-out whose truth is not run ``run``'s (a roll-out of another seed
            of a random family; a fixed scenario's truth is the same for every seed) or whose
            bank is not ``config``'s.
    """
    batch = draw_batch(
        config.source, config.sensor, run + 1, seed, config.velocity_std, config.vary,
        design_bank(config),
    )
    labels = model_labels(config.bank)
    for name, rollout in rollouts.items():
        if not np.array_equal(rollout.truth[run], batch.truth.states[run, 1:]):
            raise ValueError(f"the roll-out of {name!r} is not run {run} of seed {seed}")
        if rollout.mode_probs.shape[-1] != len(labels):
            raise ValueError(f"the roll-out of {name!r} is not of the configured bank")
    figures = {name: TrackFigure(labels, scale) for name in rollouts}
    start = start_probs(config.bank)
    for t in range(1, batch.horizon + 1):
        yield np.hstack(
            [
                figures[name].frame(
                    rollout_view(rollout, batch, config.sensor, name, t, run, start)
                )
                for name, rollout in rollouts.items()
            ]
        )


def start_probs(bank: Sequence[MotionModel] | HeteroBank) -> Array:
    """The mode probabilities a tracker of ``bank`` starts from: uniform, or a heterogeneous
    bank's own (``HeteroBank.probs``)."""
    if isinstance(bank, HeteroBank):
        return np.asarray(bank.probs, dtype=np.float64)
    return np.full(len(bank), 1.0 / len(bank))


def write_animation(
    rollouts: Mapping[str, Rollout],
    config: EnvConfig,
    seed: int,
    path: Path,
    fps: float = RENDER_FPS,
    run: int = 0,
    scale: float = PANEL_SCALE,
) -> int:
    """Write :func:`side_by_side_frames` to ``path`` (``.gif``: Pillow, ``.mp4``: ffmpeg) at
    ``fps`` frames per second, looping; returns the number of frames."""
    check_animation_path(path)
    frames = side_by_side_frames(rollouts, config, seed, run, scale)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        return _write_gif(frames, path, fps)
    return _write_mp4(frames, path, fps)


def gif_palette() -> NDArray[np.uint8]:
    """``(256, 3)`` the colours of a frame: matplotlib's colour cycle (``C0``..``C9``) and 24
    samples of viridis (the TPM), each pure and blended with white at 75, 50 and 25 % (the
    antialiased edges), and a ramp of greys (text, axes) filling the rest. One palette for every
    frame keeps the colours of small artists (an adaptive palette merges them) and leaves the
    unchanged pixels equal from frame to frame, which the GIF encoder stores once."""
    from matplotlib import colormaps
    from matplotlib.colors import to_rgb

    pure = np.array(
        [to_rgb(f"C{i}") for i in range(10)]
        + [tuple(c[:3]) for c in colormaps["viridis"](np.linspace(0.0, 1.0, 24))]
    )
    alpha = np.array([1.0, 0.75, 0.5, 0.25])[:, None, None]
    blends = (alpha * pure[None] + (1.0 - alpha)).reshape(-1, 3)
    greys = np.repeat(np.linspace(0.0, 1.0, 256 - len(blends))[:, None], 3, axis=1)
    return np.round(np.vstack([greys, blends]) * 255.0).astype(np.uint8)


def _write_gif(frames: Iterator[NDArray[np.uint8]], path: Path, fps: float) -> int:
    """A looping GIF, every frame mapped to :func:`gif_palette` (nearest colour, no dither)."""
    from PIL import Image

    palette = Image.new("P", (1, 1))
    palette.putpalette(gif_palette().ravel().tolist())
    images = [
        Image.fromarray(frame).quantize(palette=palette, dither=Image.Dither.NONE)
        for frame in frames
    ]
    images[0].save(
        path,
        save_all=True,
        append_images=images[1:],
        duration=round(1000 / fps),
        loop=0,
        optimize=True,  # pixels equal to the previous frame's stored as transparent
    )
    return len(images)


def _write_mp4(frames: Iterator[NDArray[np.uint8]], path: Path, fps: float) -> int:
    """An H.264 MP4 through matplotlib's ``FFMpegWriter``: each frame shown pixel for pixel by a
    figure image of the frame's size, and written before the next is drawn."""
    from matplotlib.animation import FFMpegWriter
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    first = next(frames)
    height, width = first.shape[:2]
    fig = Figure(figsize=(width / 100, height / 100), dpi=100)
    FigureCanvasAgg(fig)
    image = fig.figimage(first)
    writer = FFMpegWriter(fps=fps)
    count = 0
    with writer.saving(fig, str(path), dpi=100):
        for frame in itertools.chain([first], frames):  # one frame drawn at a time
            image.set_data(frame)
            writer.grab_frame()
            count += 1
    return count
