"""Common random numbers whatever bank a policy brings: a designed family
(``family.designed_share > 0``) draws its turns for the CT models' noise, so a policy with its own
bank (bbsca's tuned ``Q``) is rolled out on the targets drawn for the evaluated bank
(:class:`imm_gym.sim.core.PairedConfig`); :func:`check_paired` refuses roll-outs of other
targets or other measurements before their errors are paired."""

from __future__ import annotations

import pickle
from dataclasses import fields, replace

import numpy as np
import pytest

from baselines import FixedTPM
from baselines.bbsca import BBSCATunedIMM, scaled_bank
from imm_gym.evaluation.rollout import check_paired, evaluation_config, rollout
from imm_gym.sim.core import PairedConfig, TrackingCore, design_bank
from imm_gym.sim.env_config import EnvConfig
from imm_gym.tracking.models import MotionModel
from imm_gym.validation import ConfigError

DESIGNED = EnvConfig.build({"scenario": "random", "family": {"designed_share": 1.0}})


def test_a_policy_with_its_own_bank_meets_the_evaluated_banks_targets() -> None:
    fixed = FixedTPM(3)
    tuned = BBSCATunedIMM(DESIGNED.bank, [3.0, 3.0, 3.0])  # what bbsca's tuner returns
    a = rollout(fixed, evaluation_config(DESIGNED, fixed.env_overrides), 6, 0)
    config = evaluation_config(DESIGNED, tuned.env_overrides)
    assert config.bank == tuned.env_overrides["bank"]  # it tracks with its own bank
    b = rollout(tuned, config, 6, 0)
    np.testing.assert_array_equal(a.truth, b.truth)
    np.testing.assert_array_equal(a.true_model, b.true_model)
    assert not np.array_equal(a.estimate, b.estimate)
    check_paired({"fixed": a, "bbsca": b})


def test_the_core_draws_for_the_design_bank_and_tracks_with_its_own() -> None:
    scaled = scaled_bank(DESIGNED.bank, [3.0, 0.2, 5.0])
    own = DESIGNED.replace(bank=scaled)
    paired = PairedConfig(**{f.name: getattr(own, f.name) for f in fields(EnvConfig)},
                          design_bank=DESIGNED.bank)
    assert design_bank(paired) == DESIGNED.bank and design_bank(own) == scaled
    cores = {}
    for name, config in (("base", DESIGNED), ("own", own), ("paired", paired)):
        cores[name] = TrackingCore(config, 5)
        cores[name].reset(np.arange(5), list(range(5)))
    np.testing.assert_array_equal(cores["paired"].truth, cores["base"].truth)
    np.testing.assert_array_equal(cores["paired"].z, cores["base"].z)
    assert not np.array_equal(cores["own"].truth, cores["base"].truth)  # drawn for its own Q
    assert cores["paired"].models == scaled
    # what a Ray shard is sent, and what a replace keeps
    again = pickle.loads(pickle.dumps(paired))
    assert again == paired and again.replace(p_min=1e-4).design_bank == DESIGNED.bank


def test_a_policy_of_the_evaluated_bank_gets_a_plain_configuration() -> None:
    config = evaluation_config(DESIGNED, FixedTPM(3).env_overrides)
    assert type(config) is EnvConfig


def test_the_design_bank_is_checked() -> None:
    with pytest.raises(ConfigError, match="design_bank must hold MotionModel"):
        PairedConfig(design_bank=(1, 2))
    with pytest.raises(ConfigError, match="design_bank with a CT model"):
        PairedConfig(scenario="random", family={"designed_share": 0.5},
                     design_bank=(MotionModel("cv"), MotionModel("cv")))


def test_check_paired_refuses_other_targets_and_other_runs() -> None:
    fixed = FixedTPM(3)
    config = evaluation_config(EnvConfig(scenario="random"), fixed.env_overrides)
    a, b = rollout(fixed, config, 3, 0), rollout(fixed, config, 3, 1)
    check_paired({"a": a, "a again": replace(a, estimate=a.estimate + 1.0)})
    check_paired({})
    with pytest.raises(ValueError, match=r"'b' was rolled out on other targets than 'a' \(runs "
                                         r"\[0, 1, 2\] differ\)"):
        check_paired({"a": a, "b": b})
    shorter = rollout(fixed, config, 2, 0)
    with pytest.raises(ValueError, match="'c' ran 2 runs of 150 steps and 'a' 3 of 150"):
        check_paired({"a": a, "c": shorter})


def test_check_paired_refuses_other_measurements_of_the_same_targets() -> None:
    """A policy whose overrides touch the sensor meets the same targets through other noise (or
    other detections): its errors are not paired with the others' either."""
    fixed = FixedTPM(3)
    base = EnvConfig.build({"scenario": "random", "sensor": {"detection_prob": 0.8}})
    a = rollout(fixed, evaluation_config(base, fixed.env_overrides), 4, 11)
    assert np.isnan(a.measurements).any() and not np.isnan(a.measurements).all()  # missed ones
    check_paired({"a": a, "a again": rollout(fixed, evaluation_config(base, {}), 4, 11)})
    noisier = {**fixed.env_overrides, "sensor": {"detection_prob": 0.8, "sigma_r": 20.0}}
    b = rollout(fixed, evaluation_config(base, noisier), 4, 11)
    np.testing.assert_array_equal(a.truth, b.truth)
    with pytest.raises(ValueError, match=r"'b' was given other measurements than 'a' \(runs "
                                         r"\[0, 1, 2, 3\] differ: other sensor noise"):
        check_paired({"a": a, "b": b})
    missed = a.measurements.copy()
    missed[2, 5] = np.nan  # one more missed detection, in run 2
    with pytest.raises(ValueError, match=r"\(runs \[2\] differ"):
        check_paired({"a": a, "c": replace(a, measurements=missed)})
