"""The picture of a hand-made :class:`TrackView`, read from its artists and pixels against values
worked out here: the scene's box, the title and error texts, the zoom's box on the scene, the
sensor, the stays' text colours, the TPM's colours in the frame, the models' legend filled
evenly, an ellipse of a covariance with a rounding-negative eigenvalue, and a needle ellipse
far longer than the panel left out."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imm_gym.sim.render import CHI2_2_95, TrackFigure, TrackView, ellipse_axes, scene_extent

LABELS = ["CV", "CT(+4°/s)", "CT(-4°/s)"]
K = 3
#: the true target moves 10 m a step along x; the estimate is 3 m east and 4 m north of it
TRUTH = np.column_stack([np.arange(K + 1) * 10.0, np.zeros(K + 1)])
SENSOR = np.array([0.0, -500.0])


def _view(tpm: np.ndarray | None = None) -> TrackView:
    if tpm is None:
        tpm = np.full((3, 3), 0.01)
        np.fill_diagonal(tpm, 0.98)
    return TrackView(
        title="policy", step=K, horizon=10, truth=TRUTH, estimate=TRUTH + np.array([3.0, 4.0]),
        covariance=np.diag([400.0, 100.0]), measurements=TRUTH,
        detected=np.ones(K + 1, dtype=bool), outlier=np.zeros(K + 1, dtype=bool),
        mode_probs=np.full((K + 1, 3), 1 / 3), true_model=np.zeros(K + 1, dtype=np.int64),
        tpm=tpm, sensor=SENSOR, extent=scene_extent(TRUTH, SENSOR),
    )


def test_the_scene_extent_holds_the_path_and_the_sensor_with_a_margin() -> None:
    """x from 0 to 30, y from −500 (the sensor) to 0: 8 % of the larger side (500 m) on every
    side; a path and sensor on one point get 8 % of 1 m."""
    assert scene_extent(TRUTH, SENSOR) == pytest.approx((-40.0, 70.0, -540.0, 40.0))
    assert scene_extent(TRUTH, SENSOR, margin=0.1) == pytest.approx((-50.0, 80.0, -550.0, 50.0))
    point = np.array([[5.0, 7.0]])
    assert scene_extent(point, [5.0, 7.0]) == pytest.approx((4.92, 5.08, 6.92, 7.08))


def test_the_figure_draws_the_views_texts_boxes_and_sensor() -> None:
    """The title says the step of the horizon; the error is |(3, 4)| = 5 m; the scene is the
    square around the extent's centre (15, −250) of half-side 290 m (the larger side); the zoom's
    box on the scene is 300 m wide around the true target (30, 0); the sensor sits at (0, −500);
    the 95 % ellipse is around the estimate (3, 4) from the target."""
    figure = TrackFigure(LABELS, zoom=150.0)
    figure.frame(_view())
    assert figure.title.get_text() == "policy   t = 3 / 10"
    assert figure.error.get_text() == "error 5 m"
    assert figure.ax_scene.get_xlim() == pytest.approx((-275.0, 305.0))
    assert figure.ax_scene.get_ylim() == pytest.approx((-540.0, 40.0))
    box = figure.box
    assert (box.get_x(), box.get_y()) == pytest.approx((30.0 - 150.0, -150.0))
    assert (box.get_width(), box.get_height()) == pytest.approx((300.0, 300.0))
    np.testing.assert_array_equal(figure.sensor.get_xydata(), [[0.0, -500.0]])
    assert figure.ellipse.get_center() == pytest.approx((3.0, 4.0))
    assert figure.ellipse.width == pytest.approx(2 * math.sqrt(CHI2_2_95 * 400.0))
    assert figure.ellipse.height == pytest.approx(2 * math.sqrt(CHI2_2_95 * 100.0))


def test_a_stays_text_is_black_on_a_light_cell_and_white_on_a_dark_one() -> None:
    """Viridis on a log scale: a stay of 0.98 is a yellow cell (black text), a stay of 0.05 a
    dark one (white text)."""
    tpm = np.array([[0.98, 0.01, 0.01], [0.5, 0.05, 0.45], [0.01, 0.01, 0.98]])
    figure = TrackFigure(LABELS)
    figure.frame(_view(tpm))
    assert [t.get_text() for t in figure.stays] == ["0.980", "0.050", "0.980"]
    assert [t.get_color() for t in figure.stays] == ["k", "w", "k"]


def test_the_frame_shows_the_tpm_cells_in_their_colours() -> None:
    """The frame is RGB: the 0.98 stays' cells are viridis at ``log(0.98 / 1e-3) / log(1e3)``
    of its range and the 0.01 cells at 1/3 (the log scale from 1e-3 to 1), whole cells of
    pixels of those colours; white around the panels."""
    from matplotlib import colormaps

    frame = TrackFigure(LABELS).frame(_view())
    assert frame.shape == (400, 640, 3) and frame.dtype == np.uint8
    assert np.all(frame[2, 2] == 255)
    pixels = frame.reshape(-1, 3).astype(np.int64)
    for value, cells in ((0.98, 3), (0.01, 6)):
        position = math.log(value / 1e-3) / math.log(1e3)
        colour = np.round(np.array(colormaps["viridis"](position)[:3]) * 255.0)
        near = np.abs(pixels - colour).max(axis=1) <= 1
        assert near.sum() > 20 * cells, value  # a cell is some 10 x 10 pixels or more


@pytest.mark.parametrize(("M", "rows"), [(5, (3, 2)), (9, (3, 3, 3))])
def test_the_models_legend_fills_its_rows_evenly(M: int, rows: tuple[int, ...]) -> None:
    """Where the legend takes more than one row, its rows hold as many models as they can
    evenly (five: 3 + 2, not 4 + 1; nine: 3 + 3 + 3, not 4 + 4 + 1)."""
    from imm_gym.sim.render import model_labels
    from imm_gym.tracking.models import MotionModel

    rates = (2.0, -2.0, 5.0, -5.0, 8.0, -8.0, 1.0, -1.0)[: M - 1]
    labels = model_labels([MotionModel("cv"), *(MotionModel("ct", r) for r in rates)])
    picture = TrackFigure(labels)
    picture.fig.canvas.draw()
    heights = [round(t.get_window_extent().y0) for t in picture.ax_mu.get_legend().get_texts()]
    counts = tuple(heights.count(h) for h in sorted(set(heights), reverse=True))
    assert counts == rows


def test_an_ellipse_of_a_rounding_negative_eigenvalue_is_a_line() -> None:
    """``[[1, 1], [1, 1 − 1e-12]]`` is singular up to rounding (eigenvalues 2 and about
    −5e-13): the ellipse is a segment of length ``2 √(χ² · 2)`` along the diagonal, no error."""
    width, height, angle = ellipse_axes(np.array([[1.0, 1.0], [1.0, 1.0 - 1e-12]]))
    assert np.linalg.eigvalsh(np.array([[1.0, 1.0], [1.0, 1.0 - 1e-12]]))[0] < 0.0
    assert width == pytest.approx(2 * math.sqrt(CHI2_2_95 * 2.0))
    assert height == pytest.approx(0.0, abs=1e-5)
    assert angle % 180.0 == pytest.approx(45.0)


def test_a_needle_ellipse_far_longer_than_the_panel_is_not_drawn() -> None:
    """A 95 % ellipse 1e9 m long and a few metres wide covers the zoom panel's width many times
    over, dash by dash: left out like a large round one (its larger axis decides)."""
    view = _view()
    needle = TrackView(**{**vars(view), "covariance": np.diag([1e17, 1.0])})
    figure = TrackFigure(LABELS, zoom=150.0)
    figure.update(needle)  # only moved: drawing it would take the time it guards against
    assert not figure.ellipse.get_visible()
    figure.update(view)
    assert figure.ellipse.get_visible()
