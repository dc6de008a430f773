"""The scalar Gymnasium environment: :class:`TPMAdaptEnv` (the core with N = 1)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from imm_gym.envs.render import CoreRenderer, scenario_title
from imm_gym.sim.actions import ActionError
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.features import datasheet_table
from imm_gym.sim.render import RENDER_FPS
from imm_gym.sim.solo import SoloStep


class TPMAdaptEnv(gym.Env[NDArray[np.float32], NDArray[np.float32]]):
    """Learn to adapt the transition probability matrix (TPM) of an IMM tracker.

    ## Description
    A maneuvering target is observed by a sonar at the origin (range and bearing, σ_r = 50 m,
    σ_θ = 0.05°). A bank of model-matched SVD-UKFs — CV, CT(+4°/s), CT(−4°/s) — runs the IMM
    cycle. At every step the agent adjusts the TPM that the next mixing uses; it is rewarded for
    the position accuracy of the combined estimate. TIP-IMM (a rule on the model probabilities)
    and classical IMM (a fixed TPM) act through the same interface (``baselines/``).

    ## Action Space
    ``Box(-1, 1, (M*M,), float32)``, the TPM adjustment, row-major over ``(i, j)``:

    * ``action_mode="scale"`` (default): ``π_ij ← π_ij · max_factor ** a_ij`` on the current TPM.
      TIP-IMM's α/β steps are ``a = log(α) / log(max_factor)``, ``log(β) / log(max_factor)``,
      and the zero action leaves the TPM unchanged (classical IMM).
    * ``action_mode="set"``: ``π_i = softmax(logit_scale · a_i)`` row by row.
    * ``action_mode="stay"`` (``Box(-1, 1, (M,))``): each row's stay probability moved
      ``logit_scale · a_i`` logits from the tracker's own TPM's, the row's switching structure
      kept (the zero action is classical IMM); with ``stay_base="evidence"`` (or
      ``"evidence_best"``) moved from the stay the stay bank's evidence supports
      (:mod:`imm_gym.sim.stay_bank`; ``"uniform"``: from 1/M), and with ``detector_share=v``
      the share ``v`` of its jumps placed by a maneuver detector instead of evenly — the shadow
      IMM's mode probabilities, with ``detector="turn_rate"`` the estimated turn rate between
      the models' (:mod:`imm_gym.sim.detectors`), with ``detector="learned"`` a network's belief
      of the coming turn rate (:mod:`imm_gym.sim.learned_detector`). ``"stay_step"``: from the
      current TPM's stays (:mod:`imm_gym.sim.actions`). In the stay modes a stay is kept at or
      above ``min(1/M, π⁰_ii)`` (the stays below it would make switching likelier than staying,
      ``π⁰`` the tracker's own TPM) and at most ``1 − (M − 1) p_min``: the actions past those
      bounds change nothing.

    Then rows are normalized and every entry kept in ``[p_min, 1 − p_min]``. Out-of-range
    actions are clipped; a wrong shape or a NaN/inf entry raises ``ActionError``. Float64 actions
    are used at full precision.

    ## Observation Space
    ``Box(float32)``; with M = 3 models and no optional features, shape ``(6,)``:

    {observation_table}

    Policies act on the observation only; ground truth is in ``info`` for evaluation. Per-model
    entries (and the action's) follow the bank's order, or with ``model_order="canonical"`` one
    order however the bank lists its models — CV, CA, then CT by turn rate, +ω before −ω
    (:mod:`imm_gym.sim.model_order`); ``info`` keeps the bank's order.

    ## Rewards
    ``reward="advantage"`` (default): ``(e_shadow − e) / reward_scale`` with ``e`` the position
    error of the combined estimate and ``e_shadow`` that of a classical IMM (fixed TPM) run in
    lock-step on the same measurements — a low-variance signal, exactly 0 for classical IMM (the
    shadow's stay probability is ``shadow_stay``, by default ``initial_stay``).
    ``reward="squared_advantage"``: ``(e_shadow² − e²) / reward_scale²``, the per-step terms of
    the mean squared error that the ARMSE's RMSE(t) are made of.
    ``reward="bank_advantage"``: ``(e_bank − e) / reward_scale`` with ``e_bank`` the position
    errors of the stay bank's IMMs weighted by their evidence (``info["stay_bank_position_error"]``;
    it follows the stays the measurements support, as the ``stay`` action's evidence base does,
    so less of the targets' and the noise's randomness stays in the reward; it runs the stay
    bank). ``reward="error"``: ``−e / reward_scale``. Errors are capped at ``divergence_error``.
    All terms the configuration allows are in ``info`` (``reward_error``, ``reward_advantage``,
    ``reward_squared_advantage``, ``reward_bank_advantage``).
    ``tpm_cost > 0`` subtracts ``tpm_cost`` times the mean KL divergence of the TPM's rows from
    the shadow's (:func:`imm_gym.tracking.tpm.row_divergence`, ``info["tpm_divergence"]``).

    ## Starting State
    A scenario is drawn (the randomized family, the paper scenario, or a user ``Scenario``); the
    track starts from the first measurement and the scenario's initial velocity with
    ``P0 = blockdiag(J R Jᵀ, 5² I)``; the TPM starts at ``initial_stay`` (0.995) on the diagonal;
    model probabilities start uniform.

    ## Episode End
    Truncation at the scenario's horizon (150 steps by default). Termination when the tracker
    diverges (non-finite state, position error above ``divergence_error`` or position covariance
    trace above ``divergence_cov``); then ``info["diverged"]`` is True.

    ## Arguments
    | name      | type                    | default  | meaning                                    |
    |-----------|-------------------------|----------|--------------------------------------------|
    | config    | EnvConfig or dict       | None     | a dict updates the preset's fields; an     |
    |           |                         |          | EnvConfig is the whole configuration       |
    | render_mode | str or None           | None     | ``"rgb_array"``, ``"human"`` (see Rendering)|
    | preset    | dict                    | the id's | the registered id's fields (set by make)   |
    | **kwargs  | EnvConfig fields        |          | override single fields, e.g. parallel=True |

    ``gymnasium.make("imm_gym/TPMAdapt-v0", parallel=True, obs_features=("tpm", "loglik"))``.
    Unknown keys and out-of-range values raise ``ConfigError`` naming the field.

    ## Info
    ``true_state``, ``true_model`` (bank index of the true motion, −1 if none), ``estimate``,
    ``covariance``, ``position_error``, ``shadow_position_error``, ``mode_probs``, ``loglik``,
    ``model_nis``, ``nis``, ``detected``, ``tpm``, ``step``, ``diverged``, ``reward_*``.
    Numbers are Python ``float``, ``int`` and ``bool``; arrays are new at every step. ``reset``'s
    info: ``true_state`` (the episode's first true state) and ``tpm`` (the TPM it starts from).

    ## Rendering
    ``render_mode="rgb_array"``: ``render()`` returns the picture of the current step, an
    ``(H, W, 3)`` ``uint8`` array (640 x 400) drawn by matplotlib's Agg canvas into one figure
    reused across steps (:mod:`imm_gym.sim.render`): the sensor, the truth, the combined
    estimates and the measurements so far (outliers and missed detections marked), a zoom on the
    target with the estimate's 95 % covariance ellipse, the TPM the step used and the mode
    probabilities of the recent steps (a 40-step window) under the true model.
    ``render_mode="human"`` draws the same picture in a pyplot window at every ``reset`` and
    ``step`` (``metadata["render_fps"]`` pictures per second) when pyplot's backend is
    interactive; without a display (the Agg backend) the pictures are drawn and not shown.
    Without a render mode nothing is recorded or drawn. ``gymnasium.wrappers.RecordVideo``
    records the ``"rgb_array"`` frames (it needs moviepy).

    ## Seeding
    ``reset(seed=s)`` derives two streams from ``s`` — scenario and sensor noise — so two
    policies reset with the same seed see the same target and the same noise (common random
    numbers). Later resets without a seed continue the streams.

    ## Vectorized environment
    :class:`~imm_gym.envs.vector.TPMAdaptVectorEnv` runs N episodes in one batched core
    (``gymnasium.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")``); sub-env
    ``i`` reproduces this env reset with ``seed + i``. :class:`~imm_gym.envs.sb3.TPMAdaptSB3VecEnv`
    is the stable-baselines3 ``VecEnv`` over the same core. Where the whole step is compiled (no
    observation feature, no stay bank, no render mode, the compiled engine:
    :meth:`imm_gym.sim.solo.SoloStep.fits`) this env runs it as one compiled call on state kept
    between steps (:mod:`imm_gym.sim.solo`), the core's numbers bit for bit.

    ## Version History
    * v0: initial release.
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": RENDER_FPS}

    def __init__(
        self,
        config: EnvConfig | Mapping[str, Any] | None = None,
        render_mode: str | None = None,
        preset: Mapping[str, Any] | None = None,
        **kwargs: Any,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, "
                f"got {render_mode!r}"
            )
        self.config = EnvConfig.build(config, preset, **kwargs)
        core = self.core = TrackingCore(self.config, n_envs=1)
        self.observation_space = spaces.Box(core.obs_low, core.obs_high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (core.action_dim,), dtype=np.float32)
        self.render_mode = render_mode
        self._renderer = (
            None
            if render_mode is None
            else CoreRenderer(
                core, window=render_mode == "human", title=scenario_title(self.config.scenario)
            )
        )
        #: the compiled single-slot step where the whole step is compiled and nothing is drawn
        #: (the core's state attributes are then views of its arrays, current after each step)
        self._solo = SoloStep(core) if render_mode is None and SoloStep.fits(core) else None

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        super().reset(seed=seed)
        core = self.core
        core.reset(np.array([0]), [seed])
        if self._solo is not None:
            self._solo.load(core)
        info = {key: value[0] for key, value in core.reset_info(np.array([0])).items()}
        if self._renderer is not None:
            self._renderer.start(np.array([0]))
            if self.render_mode == "human":
                self._renderer.show()
        return core.observe()[0], info

    def step(
        self, action: NDArray[Any]
    ) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        if self._solo is not None:
            return self._solo.step(action)
        a = np.asarray(action)
        if a.shape != (self.core.action_dim,):
            raise ActionError(f"action must have shape ({self.core.action_dim},), got {a.shape}")
        result = self.core.step(a[None])
        if self._renderer is not None:
            self._renderer.record(result.info)
            if self.render_mode == "human":
                self._renderer.show()
        # row 0 of arrays created fresh by this step (a new object every call), numbers as
        # Python scalars (as the solo step gives them)
        info = {
            key: value[0] if value.ndim > 1 else value[0].item()
            for key, value in result.info.items()
        }
        return (
            result.obs[0],
            float(result.reward[0]),
            bool(result.terminated[0]),
            bool(result.truncated[0]),
            info,
        )

    def render(self) -> NDArray[np.uint8] | None:
        """The current picture (``"rgb_array"``: an ``(H, W, 3)`` ``uint8`` frame; ``"human"``:
        None, the window is drawn by ``reset`` and ``step``); see ``## Rendering``."""
        if self._renderer is None:
            gym.logger.warn(
                "render() called without a render mode: make the env with "
                "render_mode='rgb_array' or 'human'"
            )
            return None
        if self.render_mode == "human":
            return None
        return self._renderer.frame()

    def close(self) -> None:
        """Release the render figure, if any (none if the constructor failed before it)."""
        renderer = getattr(self, "_renderer", None)
        if renderer is not None:
            renderer.close()


# The observation table of the datasheet comes from the feature registry (one declaration each).
TPMAdaptEnv.__doc__ = TPMAdaptEnv.__doc__.replace(  # type: ignore[union-attr]
    "{observation_table}", datasheet_table().replace("\n", "\n    ")
)
