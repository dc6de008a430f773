"""The environments' render modes: pictures of a :class:`~imm_gym.sim.core.TrackingCore`'s slots.

The core keeps each slot's whole truth, measurements, detection and outlier flags, and the
current TPM; :class:`CoreRenderer` keeps the rest of a picture's history — the combined estimates'
positions and the mode probabilities of every step so far, and the current position covariance —
and only exists when a render mode is set, so an environment without one records nothing. The
drawing is :class:`imm_gym.sim.render.TrackFigure`'s, one figure per slot drawn: each keeps the
background of its own slot's scene, so a slot's frames after its first only redraw what moves.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.core import TrackingCore
from imm_gym.sim.render import TrackFigure, TrackView, model_labels, scene_extent


def scenario_title(scenario: object) -> str:
    """The pictures' title: the scenario's name (``EnvConfig.scenario``)."""
    return f"{scenario} scenario" if isinstance(scenario, str) else "custom scenario"


class CoreRenderer:
    """Histories and pictures of a core's slots.

    A slot is drawn after :meth:`start` (call it after the core resets the slot) and follows the
    steps given to :meth:`record` (call it after each core step).

    Args:
        core: the simulation drawn.
        window: draw into a window (the ``"human"`` mode) rather than an off-screen canvas.
        title: the pictures' title (``{slot}`` is replaced by the slot's index).
    """

    def __init__(self, core: TrackingCore, window: bool = False, title: str = "") -> None:
        self.core = core
        self.title = title
        N, K, M = core.n_envs, core.horizon, core.M
        self.estimate = np.full((N, K + 1, 2), np.nan)
        self.covariance = np.repeat(np.eye(2)[None], N, axis=0)
        self.mode_probs = np.full((N, K + 1, M), np.nan)
        self.positions = np.zeros((N, K + 1, 2))
        self.extent = [(0.0, 1.0, 0.0, 1.0)] * N
        self.started = np.zeros(N, dtype=bool)
        self.sensor = np.asarray(core.config.sensor.position, dtype=np.float64)
        self.window = window
        self.labels = model_labels(core.models)
        #: each drawn slot's figure, built at its first picture
        self.figures: dict[int, TrackFigure] = {}

    def start(self, indices: NDArray[np.int64]) -> None:
        """Begin the histories of the slots ``indices``, just reset by the core."""
        core = self.core
        if len(indices) == 0:
            return
        sensor = core.config.sensor
        x, P = core.imm.combine(core.mu[indices], core.state_a.x[indices], core.state_a.P[indices])
        self.estimate[indices] = np.nan
        self.estimate[indices, 0] = x[:, :2]
        self.covariance[indices] = P[:, :2, :2]
        self.mode_probs[indices] = np.nan
        self.mode_probs[indices, 0] = core.mu[indices]
        self.positions[indices] = sensor.initial_position(core.z[indices])[0]
        for i in indices:
            self.extent[i] = scene_extent(core.truth[i], self.sensor)
        self.started[indices] = True

    def record(self, info: dict[str, Any], rows: NDArray[np.bool_] | None = None) -> None:
        """Add the step the core just took (its ``StepResult.info``) to the ``rows`` slots (all
        by default)."""
        rows = np.ones(self.core.n_envs, dtype=bool) if rows is None else rows
        slots = np.flatnonzero(rows)
        k = self.core.k[slots]
        self.estimate[slots, k] = info["estimate"][slots, :2]
        self.covariance[slots] = info["covariance"][slots, :2, :2]
        self.mode_probs[slots, k] = info["mode_probs"][slots]

    def view(self, slot: int) -> TrackView:
        """What slot ``slot`` shows now."""
        if not self.started[slot]:
            raise RuntimeError("call reset before render")
        core = self.core
        k = int(core.k[slot])
        return TrackView(
            title=self.title.format(slot=slot),
            step=k,
            horizon=core.horizon,
            truth=core.truth[slot, : k + 1, :2],
            estimate=self.estimate[slot, : k + 1],
            covariance=self.covariance[slot],
            measurements=self.positions[slot, : k + 1],
            detected=core.detected[slot, : k + 1],
            outlier=core.outlier[slot, : k + 1],
            mode_probs=self.mode_probs[slot, : k + 1],
            true_model=np.concatenate([[-1], core.true_model[slot, :k]]),
            tpm=core.tpm[slot],
            sensor=self.sensor,
            extent=self.extent[slot],
        )

    def figure(self, slot: int) -> TrackFigure:
        """Slot ``slot``'s figure (built at its first call): a figure drawing several slots
        would draw its whole background again at every frame, the scenes' extents differing."""
        if slot not in self.figures:
            self.figures[slot] = TrackFigure(self.labels, window=self.window)
        return self.figures[slot]

    def frame(self, slot: int = 0) -> NDArray[np.uint8]:
        """Slot ``slot``'s picture, ``(H, W, 3)`` ``uint8``."""
        return self.figure(slot).frame(self.view(slot))

    def show(self, slot: int = 0) -> None:
        """Show slot ``slot``'s picture in the window (``"human"``)."""
        self.figure(slot).show(self.view(slot))

    def close(self) -> None:
        """Release the figures (a slot drawn again gets a new one)."""
        for figure in self.figures.values():
            figure.close()
        self.figures.clear()
