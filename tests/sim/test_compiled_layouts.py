"""The compiled kernels are cached for C-contiguous, writeable arrays, and numba compiles a new
variant of a kernel for every other layout it is handed (minutes for an IMM cycle on a cold
cache). Whatever layout a caller's action has, and however a step's measurements are sliced out
of the episode's, the core hands its kernels the one layout: no variant is added."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from imm_gym.scenarios.segments import RandomFamily
from imm_gym.sim import kernels as sim_kernels
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.episodes import draw_batch
from imm_gym.sim.imm_batch import IMMBatch
from imm_gym.tracking.imm import IMM
from imm_gym.tracking.kernels import imm as imm_kernels
from imm_gym.tracking.models import paper_bank
from imm_gym.tracking.sensors import Sonar
from imm_gym.tracking.tpm import stay_tpm

SHORT = {"scenario": "random", "family": {"horizon": 8, "n_segments": (1, 1), "min_duration": 8}}

#: actions as a caller may hold them: each would be a new variant of the step kernel
LAYOUTS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "fortran": np.asfortranarray,
    "read-only, stride 0": lambda a: np.broadcast_to(a[:1], a.shape),
    "negative stride": lambda a: a[:, ::-1].copy()[:, ::-1],
    "strided columns": lambda a: np.stack([a, a], axis=-1)[..., 0],
}


def _signatures() -> dict[str, int]:
    """How many variants of each step kernel this process has compiled or loaded."""
    dispatchers = {
        "env_step": sim_kernels.env_step,
        "env_step_one": sim_kernels.env_step_one,
        "tpm_from_action": sim_kernels.tpm_from_action,
        "imm_step": imm_kernels.imm_step,
    }
    return {name: len(kernel.signatures) for name, kernel in dispatchers.items()}


@pytest.mark.parametrize("n_envs", [1, 2])
@pytest.mark.parametrize("listing", ["bank", "reordered"])
def test_an_action_of_any_layout_steps_the_kernel_already_compiled(
    n_envs: int, listing: str
) -> None:
    """Each layout gives the step a C-contiguous action, and so does a tracker whose models the
    policy reads in another order (its action's columns are indexed into the bank's order)."""
    rng = np.random.default_rng(3)
    first = TrackingCore(EnvConfig(**SHORT), n_envs)
    first.reset(np.arange(n_envs), list(range(n_envs)))
    first.step(rng.uniform(-1.0, 1.0, (n_envs, first.action_dim)))  # the C-contiguous variant
    compiled = _signatures()
    cv, ct_plus, ct_minus = paper_bank()
    config = (
        EnvConfig(**SHORT)
        if listing == "bank"
        else EnvConfig(**SHORT, bank=(ct_plus, cv, ct_minus), model_order="canonical")
    )
    core = TrackingCore(config, n_envs)
    assert (core.model_order is None) == (listing == "bank")
    core.reset(np.arange(n_envs), list(range(n_envs)))
    for shape_it in [np.ascontiguousarray, *LAYOUTS.values()]:
        core.step(shape_it(rng.uniform(-1.0, 1.0, (n_envs, core.action_dim))))
    assert _signatures() == compiled


@pytest.mark.parametrize("per_slot", [1, 2])
def test_a_batch_of_imms_steps_on_a_column_of_the_measurements_as_imm_step_does(
    per_slot: int,
) -> None:
    """The detectors' batches of IMMs (:class:`~imm_gym.sim.imm_batch.IMMBatch`; one per slot
    for the learned detector) are handed a step's measurements as a column of the episode's
    ``(N, K, m)`` array: they reach the cycle C-contiguous, the variant :meth:`IMM.step` runs
    (and ``python -m imm_gym.precompile`` caches)."""
    batch = draw_batch(RandomFamily(), Sonar(), 2, 0)
    imm = IMM(paper_bank(), Sonar())
    init = imm.init(batch.x0, batch.P0)
    imm.step(init, stay_tpm(3, 0.95), batch.measurements.z[:, 1])
    compiled = _signatures()
    imms = IMMBatch(imm, 2, per_slot, imm.kernel_args, nis=True)
    imms.start(np.arange(2), init, imm.kernel_args)
    tpm_rows = np.repeat(stay_tpm(3, 0.95)[None], 2 * per_slot, axis=0)
    for k in range(1, 4):
        z, detected = batch.measurements.z[:, k], batch.measurements.detected[:, k]
        assert not z.flags.c_contiguous
        imms.step(tpm_rows, z, detected, init)
    assert _signatures() == compiled
