"""The render's limits: tick labels that tell the models apart, and a 95 % ellipse too large to
draw (it covers the zoom panel whole) left out rather than drawn dash by dash."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym.sim.render import ELLIPSE_LIMIT, TrackFigure, TrackView, short_labels


def test_tick_labels_keep_the_turn_rate_where_two_models_would_share_one() -> None:
    assert short_labels(["CV", "CT(+4°/s)", "CT(-4°/s)"]) == ["CV", "CT+", "CT−"]
    five = ["CV", "CT(+2°/s)", "CT(+6°/s)", "CT(-2.5°/s)", "CT(-6°/s)"]
    assert short_labels(five) == ["CV", "CT+2", "CT+6", "CT−2.5", "CT−6"]


def _view(sigma: float) -> TrackView:
    K = 3
    truth = np.column_stack([np.arange(K + 1) * 10.0, np.zeros(K + 1)])
    return TrackView(
        title="policy", step=K, horizon=10, truth=truth, estimate=truth + 5.0,
        covariance=np.diag([sigma**2, (sigma / 3) ** 2]), measurements=truth,
        detected=np.ones(K + 1, dtype=bool), outlier=np.zeros(K + 1, dtype=bool),
        mode_probs=np.full((K + 1, 3), 1 / 3), true_model=np.zeros(K + 1, dtype=np.int64),
        tpm=np.full((3, 3), 1 / 3), sensor=np.array([0.0, -500.0]),
        extent=(-100.0, 100.0, -600.0, 100.0),
    )


@pytest.mark.parametrize(("sigma", "drawn"), [(20.0, True), (1e4, True), (1e12, False)])
def test_an_ellipse_far_larger_than_the_panel_is_not_drawn(sigma: float, drawn: bool) -> None:
    figure = TrackFigure(["CV", "CT(+4°/s)", "CT(-4°/s)"], zoom=150.0)
    frame = figure.frame(_view(sigma))  # sigma 1e12 m drawn dash by dash: out of memory
    assert frame.dtype == np.uint8 and figure.ellipse.get_visible() == drawn
    if drawn:
        assert figure.ellipse.get_width() <= ELLIPSE_LIMIT * 150.0
