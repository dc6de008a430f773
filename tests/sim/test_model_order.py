"""The models in a canonical order (``EnvConfig.model_order``): the same tracker listed in any
order gives a policy the same observation, and its action the same effect."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from imm_gym.sim.core import TrackingCore, critic_state_size
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.features import FEATURES
from imm_gym.sim.mixture import MixtureCore
from imm_gym.sim.model_order import (
    action_index,
    block_index,
    canonical_order,
    critic_index,
    model_roles,
    observation_index,
)
from imm_gym.tracking.hetero import HeteroBank
from imm_gym.tracking.models import MotionModel, paper_bank
from imm_gym.validation import ConfigError

CV = MotionModel("cv", noise="continuous", intensity=1.0)
LEFT = MotionModel("ct", 4.0, noise="continuous", intensity=20.0)
RIGHT = MotionModel("ct", -4.0, noise="continuous", intensity=20.0)
#: every feature with a per-model layout the core can compute without bank B
PER_MODEL = ("tpm", "loglik", "nis", "innovation", "shadow_probs", "prob_ema", "tracking_index",
             "detector_belief")
#: and features without one, among them the stay bank's evidence
GLOBAL = ("turn_rate", "speed", "turn_rate_bank", "maneuver_snr", "stay_bank_evidence")


def test_the_presets_banks_are_in_canonical_order() -> None:
    assert canonical_order(paper_bank()).tolist() == [0, 1, 2]
    assert canonical_order((CV, LEFT, RIGHT)).tolist() == [0, 1, 2]
    assert canonical_order(HeteroBank()).tolist() == [0, 1, 2]


@pytest.mark.parametrize("perm", list(itertools.permutations(range(3))))
def test_the_canonical_order_undoes_any_listing(perm) -> None:
    canonical = (CV, LEFT, RIGHT)
    listed = tuple(canonical[p] for p in perm)
    order = canonical_order(listed)
    assert tuple(listed[j] for j in order) == canonical


def test_the_key_ranks_kinds_rates_signs_then_noise() -> None:
    ca = MotionModel("ca", noise="continuous", intensity=0.5)
    quiet, loud = CV, MotionModel("cv", noise="continuous", intensity=5.0)
    fast = MotionModel("ct", -6.0, noise="continuous", intensity=1.0)
    bank = (fast, RIGHT, loud, ca, LEFT, quiet)
    noise = [1.0, 2.0, 5.0, 0.1, 2.0, 1.0]
    assert canonical_order(bank, noise).tolist() == [5, 2, 3, 4, 1, 0]
    twins = (LEFT, CV, LEFT)  # interchangeable: the bank's order among them
    assert canonical_order(twins).tolist() == [1, 0, 2]
    hetero = HeteroBank(models=("ctra", "ncv", "ct"))
    assert canonical_order(hetero).tolist() == [1, 2, 0]
    # q_scale stands for sigma_v, the last key, ascending: the kind first (NCV before CT),
    # then among the NCVs the smaller scale 0.5 (model 2) before 4 (model 1)
    scaled = HeteroBank(models=("ct", "ncv", "ncv"), q_scale=(1.0, 4.0, 0.5))
    assert canonical_order(scaled).tolist() == [2, 1, 0]


def test_the_roles_of_the_models_in_either_order() -> None:
    ca = MotionModel("ca", noise="continuous", intensity=0.5)
    assert model_roles((RIGHT, CV, LEFT)) == ("CT(−)", "CV", "CT(+)")
    assert model_roles((RIGHT, CV, LEFT), "canonical") == ("CV", "CT(+)", "CT(−)")
    assert model_roles((LEFT, ca, CV), "canonical") == ("CV", "CA", "CT(+)")
    assert model_roles(HeteroBank(), "canonical") == ("NCV", "CT", "CTRA")


@settings(max_examples=60, deadline=None)
@given(
    M=st.integers(2, 5),
    seed=st.integers(0, 2**32 - 1),
    dim_z=st.integers(1, 3),
    k=st.integers(1, 3),
)
def test_each_layout_reads_every_entry_once_in_canonical_order(M, seed, dim_z, k) -> None:
    """A block whose entries carry their model's index, read through the index, lists the
    models as ``order`` does; every entry is read exactly once."""
    order = np.random.default_rng(seed).permutation(M).astype(np.intp)
    layouts = {
        "M": np.arange(M),
        "kM": np.tile(np.arange(M), k),
        "Mm": np.repeat(np.arange(M), dim_z),
        "MM": np.repeat(np.arange(M), M),  # the row's model (columns below)
    }
    expected = {
        "M": order,
        "kM": np.tile(order, k),
        "Mm": np.repeat(order, dim_z),
        "MM": np.repeat(order, M),
    }
    for models, labels in layouts.items():
        idx = block_index(models, order, labels.size, dim_z)
        assert sorted(idx.tolist()) == list(range(labels.size))
        np.testing.assert_array_equal(labels[idx], expected[models])
    columns = np.tile(np.arange(M), M)
    np.testing.assert_array_equal(
        columns[block_index("MM", order, M * M, dim_z)], np.tile(order, M)
    )
    assert block_index("", order, 7, dim_z).tolist() == list(range(7))
    # the action: written per canonical model, applied to the bank's
    a = np.arange(M, dtype=float)[None]
    np.testing.assert_array_equal(a[:, action_index(M, order)][0][order], np.arange(M))
    A = np.arange(M * M, dtype=float)[None]
    back = A[:, action_index(M * M, order)].reshape(M, M)[np.ix_(order, order)]
    np.testing.assert_array_equal(back.ravel(), np.arange(M * M))


def test_an_unknown_per_model_layout_is_refused_by_name() -> None:
    """A feature declaring a layout the order does not know (a typo of ``"kM"``) is refused,
    not read in the bank's order: its entries would silently stay unreordered."""
    order = np.array([2, 0, 1], dtype=np.intp)
    for models in ("Mk", "mM", "m"):
        with pytest.raises(ValueError, match=f"unknown per-model layout '{models}'"):
            block_index(models, order, 6, 2)


def test_the_observation_index_covers_the_declared_features() -> None:
    features = PER_MODEL + GLOBAL
    order = np.array([2, 0, 1], dtype=np.intp)
    idx = observation_index(features, order, 2)
    size = 6 + sum(FEATURES[f].size(3, 2) for f in features)
    assert sorted(idx.tolist()) == list(range(size))
    assert critic_index(critic_state_size(3), order).tolist()[-3:] == [10, 8, 9]


def _config(bank: tuple[MotionModel, ...], **changes) -> EnvConfig:
    return EnvConfig(
        scenario="random",
        family={"horizon": 40, "min_duration": 5},
        bank=bank,
        initial_stay=0.975,
        action_mode="stay",
        stay_base="evidence",
        detector_share=0.5,
        logit_scale=6.0,
        obs_features=PER_MODEL + GLOBAL,
        model_order="canonical",
        mode_reward=0.05,
        tpm_change_cost=0.05,
    ).replace(**changes)


@pytest.mark.parametrize("perm", [(1, 0, 2), (2, 1, 0), (0, 2, 1), (2, 0, 1)])
@pytest.mark.parametrize("mode", ["stay", "set"])
def test_a_listing_of_the_same_tracker_changes_nothing_the_policy_sees(perm, mode) -> None:
    """The bank listed in another order, with ``model_order="canonical"``: under the same
    actions (per canonical model) the observation, the critic's state, the reward and the
    estimate are the canonical listing's; ``info`` keeps each bank's own order."""
    canonical = (CV, LEFT, RIGHT)
    listed = tuple(canonical[p] for p in perm)
    changes = {} if mode == "stay" else {"action_mode": "set", "stay_base": "tracker",
                                         "detector_share": 0.0,
                                         "obs_features": ("tpm", "loglik", "innovation")}
    N = 6
    cores = [TrackingCore(_config(bank, **changes), N) for bank in (canonical, listed)]
    for core in cores:
        core.reset(np.arange(N), list(range(100, 100 + N)))
    assert cores[0].model_order is None
    np.testing.assert_array_equal(cores[1].model_order, np.argsort(perm))
    rng = np.random.default_rng(7)
    obs = [core.observe() for core in cores]
    np.testing.assert_allclose(obs[1], obs[0], atol=1e-6)
    for _ in range(25):
        action = rng.uniform(-1.0, 1.0, (N, cores[0].action_dim))
        results = [core.step(action) for core in cores]
        np.testing.assert_allclose(results[1].obs, results[0].obs, atol=1e-5)
        np.testing.assert_allclose(results[1].reward, results[0].reward, rtol=1e-8, atol=1e-9)
        np.testing.assert_allclose(
            cores[1].critic_state(), cores[0].critic_state(), atol=1e-6
        )
        info = [r.info for r in results]
        np.testing.assert_allclose(info[1]["estimate"], info[0]["estimate"], rtol=1e-9)
        # info in each bank's own order: listed model j is canonical model perm[j]
        np.testing.assert_allclose(
            info[1]["mode_probs"], info[0]["mode_probs"][:, list(perm)], atol=1e-9
        )
        np.testing.assert_allclose(
            info[1]["tpm"], info[0]["tpm"][:, list(perm)][:, :, list(perm)], atol=1e-12
        )


def test_the_bank_order_is_the_default_and_reads_the_bank_as_listed() -> None:
    listed = (LEFT, CV, RIGHT)
    core = TrackingCore(_config(listed, model_order="bank"), 2)
    core.reset(np.arange(2), [0, 1])
    assert EnvConfig().model_order == "bank"
    assert core.model_order is None
    np.testing.assert_array_equal(core.observe()[:, :3], core.mu.astype(np.float32))


def test_a_wrong_order_is_refused_by_name() -> None:
    with pytest.raises(ConfigError, match="model_order must be one of"):
        EnvConfig(model_order="sorted")


def test_a_mixture_shares_the_order() -> None:
    """The policy's order is part of what every part of a mixture must share."""
    base = _config((CV, LEFT, RIGHT))
    with pytest.raises(ConfigError, match="model_order"):
        MixtureCore([base, base.replace(model_order="bank")], [0.5, 0.5], 4)
