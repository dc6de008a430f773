"""Pictures of one tracking episode: what the environments' ``render()`` and the side-by-side
animation of ``python -m imm_gym.evaluate --animate`` draw (no Gymnasium here).

A :class:`TrackView` is the data of one picture at step ``k``; :class:`TrackFigure` draws views
into one matplotlib figure that is built once and reused: every call only moves the data of a
fixed set of artists, so the cost of a frame is bounded (it grows with the ``k + 1`` points of the
tracks drawn so far, never with the number of frames drawn before). Frames are ``(H, W, 3)``
``uint8`` arrays rendered by the non-interactive Agg canvas; a figure made for a window
(``window=True``, the ``"human"`` render mode) is drawn by pyplot's backend and shown when that
backend is interactive.

The picture:

* left, around the true target (its position at the origin): the truth so far, the combined
  estimates so far, the measurements (outliers marked), the missed detections (on the truth),
  the current estimate and its 95 % position covariance ellipse
  ``{p : (p - x̂)ᵀ P⁻¹ (p - x̂) ≤ χ²₂(0.95)}``, half-axes ``√(χ²₂(0.95) λ_i)`` along the
  eigenvectors of the position block ``P``;
* top middle, the whole scene: the same tracks, the sensor and the window of the left panel, in
  a square around the scene's extent (the panel's size the same in every episode) with at most
  four ticks on an axis (their labels apart, whatever the scene's size);
* top right, the TPM the step used, a heatmap on a log scale, ``tpm[i, j] = P(model j at k |
  model i at k−1)``;
* bottom right, the mode probabilities ``μ_j(t)`` of the recent steps, with a bar on top
  coloured by the true model of each step: a window of ``window_steps`` steps that moves on by
  half its width when ``t`` reaches its right end (so at least the last ``window_steps / 2``
  steps are shown).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.tracking.hetero import HeteroBank
from imm_gym.tracking.models import MotionModel

if TYPE_CHECKING:
    from matplotlib.figure import Figure

Array = NDArray[np.float64]

#: ``χ²₂(0.95)``: the 95 % quantile of the chi-square law with 2 degrees of freedom, ``−2 ln 0.05``.
CHI2_2_95 = -2.0 * math.log(0.05)
#: The 95 % ellipse is not drawn once its larger axis passes this many zoom half-widths: it then
#: covers the zoom panel whole, and Agg draws every dash of it (a frame took 0.8 s at a standard
#: deviation of 1e7 m, ran out of memory at 1e15 m).
ELLIPSE_LIMIT = 1000.0
#: The figure's size in inches (640 x 400 pixels at scale 1, 100 dots per inch).
FIGURE_SIZE = (6.4, 4.0)
#: Frames per second of the render modes and of the animations (ten simulated seconds per second
#: of video at the default sampling period T = 1 s).
RENDER_FPS = 10


@dataclass(frozen=True)
class TrackView:
    """What one picture shows at step ``k``: arrays over ``t = 0..k`` (``t = 0`` is the track's
    initiation).

    Attributes:
        title: the panel's title (a policy's name, say).
        step: ``k``; horizon: ``K``, the episode's last step.
        truth: ``(k+1, 2)`` true positions.
        estimate: ``(k+1, 2)`` combined estimates' positions; a NaN row is not drawn (no
            estimate: a diverged run's).
        covariance: ``(2, 2)`` position block of the current combined covariance; no ellipse
            where it or the current estimate is NaN.
        measurements: ``(k+1, 2)`` measured positions (the sensor's inverse, e.g. polar to
            Cartesian); a missed detection's entry is not drawn.
        detected: ``(k+1,)`` False for a missed detection; outlier: ``(k+1,)`` True for an outlier.
        mode_probs: ``(k+1, M)`` mode probabilities (a NaN row is not drawn).
        true_model: ``(k+1,)`` bank index of the true motion of each step, −1 if none (entry 0,
            the initiation, is not drawn).
        tpm: ``(M, M)`` the TPM the last step used.
        sensor: ``(2,)`` the sensor's position.
        extent: ``(x_min, x_max, y_min, y_max)`` of the whole scene (fixed over an episode).
    """

    title: str
    step: int
    horizon: int
    truth: Array
    estimate: Array
    covariance: Array
    measurements: Array
    detected: NDArray[np.bool_]
    outlier: NDArray[np.bool_]
    mode_probs: Array
    true_model: NDArray[np.int64]
    tpm: Array
    sensor: Array
    extent: tuple[float, float, float, float]


def model_labels(bank: Sequence[MotionModel] | HeteroBank) -> list[str]:
    """Short names of a bank's models: ``CV``, ``CT(+4°/s)``, ... or ``NCV``, ``CT``, ``CTRA``.

    A name two models share is followed by each one's process noise, after a space: the
    continuous noise's density (``CV q=0.05``, ``CV q=5``), the discrete noise's distinct
    diagonal entries (``CV q=0.1/0.12``) or a heterogeneous bank's ``Q`` factor (``NCV Q×2``);
    where that is shared too, by the model's index in the bank (``CV [0]``, ``CV [1]``). Names
    no other model has are left as they are.
    """
    if isinstance(bank, HeteroBank):
        names = [kind.upper() for kind in bank.models]
        noises = [f"Q×{scale:g}" for scale in bank.q_scale]
    else:
        names = [model.label for model in bank]
        noises = [_noise_tag(model) for model in bank]
    labels = list(names)
    for name in dict.fromkeys(names):
        group = [j for j, other in enumerate(names) if other == name]
        if len(group) == 1:
            continue
        tags = [noises[j] for j in group]
        if len(set(tags)) < len(tags):
            tags = [f"[{j}]" for j in group]
        for j, tag in zip(group, tags, strict=True):
            labels[j] = f"{name} {tag}"
    return labels


def _noise_tag(model: MotionModel) -> str:
    """``q=`` a model's continuous noise density, or its discrete noise's distinct diagonal
    entries joined by ``/``."""
    if model.noise == "continuous":
        return f"q={model.intensity:g}"
    assert model.q is not None  # a discrete model's q is filled in by its validation
    return "q=" + "/".join(f"{v:g}" for v in dict.fromkeys(model.q))


def scene_extent(truth: Array, sensor: Sequence[float], margin: float = 0.08) -> tuple[
    float, float, float, float
]:
    """The box holding the whole true path ``(K+1, 2+)`` and the sensor, widened by ``margin``
    of its larger side on every side."""
    xs = np.append(truth[:, 0], sensor[0])
    ys = np.append(truth[:, 1], sensor[1])
    pad = margin * max(float(np.ptp(xs)), float(np.ptp(ys)), 1.0)
    return (
        float(xs.min()) - pad,
        float(xs.max()) + pad,
        float(ys.min()) - pad,
        float(ys.max()) + pad,
    )


def ellipse_axes(covariance: Array, quantile: float = CHI2_2_95) -> tuple[float, float, float]:
    """Full width, full height and angle (degrees) of ``{d : dᵀ P⁻¹ d ≤ quantile}`` for a 2x2
    covariance ``P``: half-axes ``√(quantile λ_i)`` along ``P``'s eigenvectors."""
    lam, vec = np.linalg.eigh(covariance)
    lam = np.maximum(lam, 0.0)
    angle = math.degrees(math.atan2(vec[1, 1], vec[0, 1]))  # direction of the larger axis
    return (
        2.0 * math.sqrt(quantile * lam[1]),
        2.0 * math.sqrt(quantile * lam[0]),
        angle,
    )


class TrackFigure:
    """One figure, built once, that draws :class:`TrackView` s (see the module docstring).

    The axis limits stay fixed for many frames (the zoom is centred on the true target, the
    scene is the episode's, the mode probabilities' window moves every ``window_steps / 2``
    steps), so the axes, ticks, legends and titles are drawn into a background when a limit
    changes and a frame restores it and draws only the artists that move (blitting). The mode
    probabilities and the true-model bar only grow between two moves of their window, which also
    keeps consecutive frames alike (a small GIF).

    Args:
        labels: the M models' names.
        scale: the frame is ``640·scale`` x ``400·scale`` pixels, text and lines scaled alike.
        window_steps: width of the mode probabilities' window (an even number of steps).
        zoom: the half-width (m) of the zoom on the target.
        window: draw into a pyplot figure that is shown when pyplot's backend is interactive
            (``"human"``) instead of an off-screen Agg canvas.
    """

    def __init__(
        self,
        labels: Sequence[str],
        scale: float = 1.0,
        window_steps: int = 40,
        zoom: float = 150.0,
        window: bool = False,
    ) -> None:
        from matplotlib import colors
        from matplotlib.patches import Ellipse, Rectangle
        from matplotlib.ticker import MaxNLocator

        #: what builds this figure again in a copy (:meth:`__getstate__`)
        self._arguments = (list(labels), scale, window_steps, zoom, window)
        self.labels = list(labels)
        self.window_steps = window_steps
        self.zoom = zoom
        self.fig = fig = _new_figure(FIGURE_SIZE, 100.0 * scale, window)
        M = len(self.labels)
        grid = fig.add_gridspec(
            2, 3, width_ratios=(1.5, 0.85, 0.85), height_ratios=(1.0, 0.8),
            left=0.065, right=0.95, bottom=0.1, top=0.84, wspace=0.45, hspace=0.5,
        )
        self.title = fig.text(0.5, 0.985, "", ha="center", va="top", fontsize=9)
        near = self.ax_near = fig.add_subplot(grid[:, 0])
        scene = self.ax_scene = fig.add_subplot(grid[0, 1])
        heat = self.ax_tpm = fig.add_subplot(grid[0, 2])
        mu = self.ax_mu = fig.add_subplot(grid[1, 1:])
        for ax in (scene, near, heat, mu):
            ax.tick_params(labelsize=6, length=2, pad=1)
        scene.set_aspect("equal", adjustable="box")
        for axis in (scene.xaxis, scene.yaxis):  # labels of at most 6 characters, 4 to an axis
            axis.set_major_locator(MaxNLocator(nbins=3))
            axis.get_offset_text().set_fontsize(6)
        scene.ticklabel_format(style="sci", scilimits=(-4, 5))  # 100 km and beyond: x 1e5
        scene.set_title("scene (m)", fontsize=7, pad=2)
        near.set(xlim=(-zoom, zoom), ylim=(-zoom, zoom), aspect="equal")
        near.set_title("around the true target (m)", fontsize=7, pad=2)
        self.tracks = []  # (truth, estimate, measurements, outliers, misses) in both views
        for ax, size in ((near, 2.0), (scene, 1.0)):
            self.tracks.append(
                (
                    ax.plot([], [], "-", color="k", lw=1.0, label="truth")[0],
                    ax.plot([], [], "-", color="C0", lw=0.9, label="estimate")[0],
                    ax.plot([], [], ".", color="0.5", ms=size, label="measurement")[0],
                    ax.plot([], [], "x", color="C1", ms=2 * size + 1, label="outlier")[0],
                    ax.plot([], [], "o", mfc="none", mec="C3", ms=2 * size + 1, mew=0.7,
                            label="missed")[0],
                )
            )
        self.sensor = scene.plot([], [], "^", color="k", ms=5, label="sensor")[0]
        self.box = scene.add_patch(Rectangle((0, 0), 1, 1, fill=False, ec="C2", lw=0.8))
        near.plot([0.0], [0.0], "o", color="k", ms=3)
        self.now = near.plot([], [], "+", color="C0", ms=8, mew=1.2)[0]
        self.ellipse = near.add_patch(
            Ellipse((0, 0), 1, 1, fill=False, ec="C0", lw=1.0, ls="--", label="95 % ellipse")
        )
        self.error = near.text(0.03, 0.03, "", transform=near.transAxes, fontsize=7)
        fig.legend(
            handles=[*self.tracks[0], self.ellipse, self.sensor], loc="upper center",
            bbox_to_anchor=(0.5, 0.94), ncol=7, fontsize=6, frameon=False, handlelength=1.5,
            markerscale=1.2, columnspacing=1.2,
        )

        self.heat = heat.imshow(
            np.eye(M), cmap="viridis", norm=colors.LogNorm(1e-3, 1.0), interpolation="nearest"
        )
        # the stay probabilities written out (text is the costly part of a frame), smaller
        # where more models make the cells narrower than "0.980" at 6 points
        self.stays = [
            heat.text(i, i, "", ha="center", va="center", fontsize=6 * min(1.0, 3 / M))
            for i in range(M)
        ]
        short = short_labels(self.labels)
        # the column labels upright where side by side they would run together
        heat.set_xticks(range(M), short, rotation=90 if M * max(map(len, short)) > 12 else 0)
        heat.set_yticks(range(M), short)
        heat.set_title("TPM used (row: from)", fontsize=7, pad=2)
        bar = fig.colorbar(self.heat, ax=heat, fraction=0.08, pad=0.04)
        bar.ax.tick_params(labelsize=5, length=2, pad=1)

        self.mu_lines = [
            mu.plot([], [], "-", color=f"C{j + 4}", lw=1.0, label=self.labels[j])[0]
            for j in range(M)
        ]
        self.true_bars = [
            mu.plot([], [], "-", color=f"C{j + 4}", lw=4.0, solid_capstyle="butt")[0]
            for j in range(M)
        ]
        mu.set(ylim=(-0.03, 1.14), yticks=[0.0, 0.5, 1.0])
        mu.set_xlabel("step; mode probabilities, bar: the true model", fontsize=6, labelpad=1)
        self._mode_legend(M)

        self.moving = [
            self.title, *(line for lines in self.tracks for line in lines), self.sensor,
            self.box, self.now, self.ellipse, self.error, self.heat,
            *self.stays, *self.mu_lines, *self.true_bars,
        ]
        for artist in self.moving:
            artist.set_animated(True)
        self._extent: tuple[float, float, float, float] | None = None
        self._first = -1  # first step of the mode probabilities' window
        self._background: Any = None
        self._shown = False
        fig.canvas.mpl_connect("draw_event", self._on_draw)

    def _mode_legend(self, M: int) -> None:
        """The models' legend above the mode probabilities: one row, or where that would be
        wider than the axes (five models and more at the default size), the fewest rows that
        keep it within their width, filled evenly."""
        mu = self.ax_mu

        def legend(columns: int) -> Any:  # replaces the axes' legend
            return mu.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=columns,
                             fontsize=6, frameon=False, handlelength=1.5, borderaxespad=0.1)

        width = mu.get_window_extent().width
        columns = next((c for c in range(M, 1, -1) if legend(c).get_window_extent().width
                        <= width), 1)
        legend(math.ceil(M / math.ceil(M / columns)))

    def __getstate__(self) -> dict[str, Any]:
        """The constructor's arguments only: a copy (pickle, deepcopy) builds its own figure (a
        live canvas and its blitting background do not survive pickling)."""
        return {"arguments": self._arguments}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(*state["arguments"])  # type: ignore[misc]

    # -------------------------------------------------------------------- drawing
    def update(self, view: TrackView) -> None:
        """Move the figure's artists to ``view``."""
        k = view.step
        p, x = view.truth[k], view.estimate[k]
        measured = np.where(view.detected[:, None], view.measurements, np.nan)
        outliers = np.where((view.detected & view.outlier)[:, None], view.measurements, np.nan)
        missed = np.where(view.detected[:, None], np.nan, view.truth)
        for origin, lines in zip((p, np.zeros(2)), self.tracks, strict=True):
            for line, xy in zip(
                lines, (view.truth, view.estimate, measured, outliers, missed), strict=True
            ):
                line.set_data(xy[:, 0] - origin[0], xy[:, 1] - origin[1])
        if view.extent != self._extent:  # a new scene: the background is drawn again
            self._extent = view.extent
            x_min, x_max, y_min, y_max = view.extent
            half = max(x_max - x_min, y_max - y_min) / 2.0
            centre_x, centre_y = (x_min + x_max) / 2.0, (y_min + y_max) / 2.0
            self.ax_scene.set_xlim(centre_x - half, centre_x + half)
            self.ax_scene.set_ylim(centre_y - half, centre_y + half)
            self._background = None
        self.sensor.set_data([view.sensor[0]], [view.sensor[1]])
        half = self.zoom
        self.box.set_bounds(p[0] - half, p[1] - half, 2 * half, 2 * half)

        estimated = bool(np.isfinite(x).all())
        self.now.set_data([x[0] - p[0]], [x[1] - p[1]])
        shown = estimated and bool(np.isfinite(view.covariance).all())
        width, height, angle = ellipse_axes(view.covariance) if shown else (0.0, 0.0, 0.0)
        self.ellipse.set_visible(shown and max(width, height) <= ELLIPSE_LIMIT * self.zoom)
        if self.ellipse.get_visible():
            self.ellipse.set_center((x[0] - p[0], x[1] - p[1]))
            self.ellipse.set_width(width)
            self.ellipse.set_height(height)
            self.ellipse.set_angle(angle)
        self.error.set_text(f"error {np.hypot(*(x - p)):.0f} m" if estimated else "")

        self.heat.set_data(view.tpm)
        for i, stay in enumerate(self.stays):
            value = view.tpm[i, i]
            stay.set_text(f"{value:.3f}")
            stay.set_color("k" if value > 0.1 else "w")

        shift = self.window_steps // 2
        first = max(0, (k // shift - 1) * shift)  # the window [first, first + window_steps)
        if first != self._first:
            self._first = first
            self.ax_mu.set_xlim(first, first + self.window_steps)
            self._background = None
        for j, line in enumerate(self.mu_lines):
            line.set_data(np.arange(first, k + 1), view.mode_probs[first:, j])
        # the true model of step t is a bar over (t - 1/2, t + 1/2), from step max(first, 1)
        start = max(first, 1)
        centres = np.arange(start, k + 1, dtype=np.float64)
        edges = np.column_stack([centres - 0.5, centres + 0.5]).ravel()
        for j, bar in enumerate(self.true_bars):
            bar.set_data(edges, np.repeat(np.where(view.true_model[start:] == j, 1.08, np.nan), 2))
        self.title.set_text(f"{view.title}   t = {k} / {view.horizon}")

    def frame(self, view: TrackView) -> NDArray[np.uint8]:
        """The picture of ``view``, an ``(H, W, 3)`` ``uint8`` RGB array (a fresh array)."""
        self._draw(view)
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()

    def show(self, view: TrackView, fps: float = RENDER_FPS) -> None:
        """Draw ``view`` in the window and let it display for ``1 / fps`` s (only a figure made
        with ``window=True`` on an interactive backend has a window; elsewhere this only
        draws)."""
        canvas = self.fig.canvas
        if canvas.required_interactive_framework is None:  # an off-screen canvas
            self._draw(view)
            return
        if not self._shown:
            self.fig.show()
            self._shown = True
        self._draw(view)
        if canvas.supports_blit:
            canvas.blit(self.fig.bbox)
        canvas.flush_events()
        canvas.start_event_loop(1.0 / fps)

    def _draw(self, view: TrackView) -> None:
        """Move the artists to ``view`` and draw them over the background (drawn first if
        needed)."""
        self.update(view)
        canvas = self.fig.canvas
        if self._background is None:
            canvas.draw()  # the draw event saves the background and draws the moving artists
        else:
            canvas.restore_region(self._background)
            self._draw_moving()

    def _on_draw(self, event: Any) -> None:
        """After a full draw (the first frame, a new scene, a window resized): keep the
        background (where the canvas can restore it) and draw the moving artists over it."""
        if self.fig.canvas.supports_blit:
            self._background = self.fig.canvas.copy_from_bbox(self.fig.bbox)
        self._draw_moving()

    def _draw_moving(self) -> None:
        for artist in self.moving:
            self.fig.draw_artist(artist)

    def close(self) -> None:
        """Release the figure (and close its window)."""
        if self.fig.canvas.manager is not None:
            import matplotlib.pyplot as plt

            plt.close(self.fig)


def _new_figure(size: tuple[float, float], dpi: float, window: bool) -> Figure:
    """A pyplot figure (``window`` and pyplot's backend is interactive) or a stand-alone figure
    on an Agg canvas (pyplot's list of figures is left as it was)."""
    if window:
        import matplotlib.pyplot as plt

        fig = plt.figure(figsize=size, dpi=dpi)
        if fig.canvas.required_interactive_framework is not None:
            return fig
        plt.close(fig)  # no display
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def short_labels(labels: Sequence[str]) -> list[str]:
    """The models' tick labels: ``CT(+4°/s)`` -> ``CT+``, ``CV`` -> ``CV``; with the turn rate
    (``CT+4``, ``CT−2.5``) where two names would otherwise share one (two CT models turning the
    same way). The noise or index :func:`model_labels` puts after a name two models share is
    kept (``CV q=0.05``, ``CT+4 [0]``)."""
    tagged = [label.partition(" ") for label in labels]
    split = [name.partition("(") for name, _, _ in tagged]
    tags = [space + tag for _, space, tag in tagged]
    signs = [("+" if r.startswith("+") else "−" if r.startswith("-") else "") for _, _, r in split]
    short = [name + sign for (name, _, _), sign in zip(split, signs, strict=True)]
    if len(set(short)) == len({name for name, _, _ in tagged}):
        return [name + tag for name, tag in zip(short, tags, strict=True)]
    return [
        name + sign + rest.lstrip("+-").removesuffix(")").removesuffix("°/s") + tag
        for (name, _, rest), sign, tag in zip(split, signs, tags, strict=True)
    ]
