"""Training across trackers (:mod:`imm_gym.sim.mixture`): the slots split among several
configurations, each part's slots exactly its own core's, the parts held to one policy
interface."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import EnvConfig, TrackingCore
from imm_gym.sim.actions import ActionError
from imm_gym.sim.mixture import MixtureCore, check_mixture, slot_counts
from imm_gym.sim.presets import CONTINUOUS_BANK
from imm_gym.validation import ConfigError

POLICY = {"action_mode": "stay", "obs_features": ("loglik", "shadow_probs", "stay_bank_evidence"),
          "stay_base": "evidence", "shadow_stay": None}
#: two trackers: the paper's at T = 1 s, and a physically scaled bank at drawn sampling periods
PAPER = EnvConfig(**POLICY, family={"horizon": 30, "n_segments": (2, 3)})
SCALED = EnvConfig(
    **POLICY, bank=CONTINUOUS_BANK, sojourn=(60.0, 20.0, 20.0),
    family={"horizon": 40, "n_segments": (2, 4)},
    vary={"T": (0.5, 5.0), "sigma_r": (10.0, 100.0)},
)


@pytest.mark.parametrize(
    ("shares", "n", "counts"),
    [([0.5, 0.5], 64, [32, 32]), ([1, 2], 9, [3, 6]), ([0.3, 0.3, 0.4], 10, [3, 3, 4]),
     ([1, 1, 1], 8, [3, 3, 2]), ([0.25, 0.75], 2, [1, 1]),
     # ties to the earlier part whatever the float rounding of the main part's 1 - sum(shares)
     ([1.0 - 0.55, 0.55], 30, [14, 16]), ([1.0 - 0.9, 0.9], 15, [2, 13]),
     ([1.0 - 0.3, 0.3], 45, [32, 13]), ([9, 11], 30, [14, 16])],
)
def test_slots_are_split_by_largest_remainders(shares, n, counts) -> None:
    assert slot_counts(shares, n) == counts


@pytest.mark.parametrize(
    ("shares", "n", "message"),
    [([0.1, 0.9], 4, "without a slot"), ([0.5, 0.0], 4, "positive"), ([1, np.nan], 4, "positive")],
)
def test_bad_shares_are_refused(shares, n, message) -> None:
    with pytest.raises(ConfigError, match=message):
        slot_counts(shares, n)


def test_each_part_s_slots_are_its_own_core_s_episodes() -> None:
    mixture = MixtureCore([PAPER, SCALED], [0.4, 0.6], 5)
    alone = [TrackingCore(PAPER, 2), TrackingCore(SCALED, 3)]
    seeds = [11, 12, 13, 14, 15]
    mixture.reset(np.arange(5), seeds)
    alone[0].reset(np.arange(2), seeds[:2])
    alone[1].reset(np.arange(3), seeds[2:])
    np.testing.assert_array_equal(mixture.observe(), np.concatenate([c.observe() for c in alone]))
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(90):
        action = rng.uniform(-1, 1, (5, 3))
        got = mixture.step(action)
        parts = [alone[0].step(action[:2]), alone[1].step(action[2:])]
        for field in ("obs", "reward", "terminated", "truncated"):
            np.testing.assert_array_equal(
                getattr(got, field), np.concatenate([getattr(p, field) for p in parts])
            )
        np.testing.assert_array_equal(
            got.info["tpm"], np.concatenate([p.info["tpm"] for p in parts])
        )
        done = np.flatnonzero(got.terminated | got.truncated)
        ends += done.size
        mixture.reset(done, [None] * done.size)  # each slot continues its own streams
        for core, lo in zip(alone, (0, 2), strict=True):
            mine = done[(done >= lo) & (done < lo + core.n_envs)] - lo
            core.reset(mine, [None] * mine.size)
    assert ends >= 5  # both parts ran whole episodes and started new ones
    np.testing.assert_array_equal(
        mixture.critic_state(), np.concatenate([c.critic_state() for c in alone])
    )



def test_a_bank_with_a_ca_model_beside_one_without_gives_position_and_velocity() -> None:
    # CA's common state is 6-d (x, y, vx, vy, ax, ay): the mixture's estimate and covariance are
    # the 4-d leading block every part has; the critic's state is alike in size
    ca = PAPER.replace(bank=(
        {"kind": "cv", "noise": "continuous", "intensity": 0.1},
        {"kind": "ca", "noise": "continuous", "intensity": 0.05},
        {"kind": "ct", "turn_rate_deg": 4.0, "noise": "continuous", "intensity": 0.05},
    ))
    mixture = MixtureCore([PAPER, ca], [0.5, 0.5], 4)
    alone = [TrackingCore(PAPER, 2), TrackingCore(ca, 2)]
    mixture.reset(np.arange(4), [1, 2, 3, 4])
    alone[0].reset(np.arange(2), [1, 2])
    alone[1].reset(np.arange(2), [3, 4])
    action = np.zeros((4, 3))
    got = mixture.step(action)
    parts = [alone[0].step(action[:2]), alone[1].step(action[2:])]
    assert parts[1].info["estimate"].shape == (2, 6)
    np.testing.assert_array_equal(
        got.info["estimate"], np.concatenate([p.info["estimate"][:, :4] for p in parts])
    )
    np.testing.assert_array_equal(
        got.info["covariance"], np.concatenate([p.info["covariance"][:, :4, :4] for p in parts])
    )
    np.testing.assert_array_equal(
        mixture.critic_state(), np.concatenate([c.critic_state() for c in alone])
    )

def test_the_step_s_info_has_the_keys_every_part_gives() -> None:
    # parts rewarded for different things give different info keys: a key one part lacks
    # (the mode score and the TPM's divergence of a part rewarded for them) is left out
    rewarded = PAPER.replace(mode_reward=0.1, tpm_cost=0.1)
    mixture = MixtureCore([rewarded, PAPER], [0.5, 0.5], 4)
    alone = [TrackingCore(rewarded, 2), TrackingCore(PAPER, 2)]
    mixture.reset(np.arange(4), [1, 2, 3, 4])
    alone[0].reset(np.arange(2), [1, 2])
    alone[1].reset(np.arange(2), [3, 4])
    got = mixture.step(np.zeros((4, 3)))
    parts = [alone[0].step(np.zeros((2, 3))), alone[1].step(np.zeros((2, 3)))]
    assert {"mode_score", "tpm_divergence"} <= set(parts[0].info) - set(parts[1].info)
    assert set(got.info) == set(parts[0].info) & set(parts[1].info)
    np.testing.assert_array_equal(got.reward, np.concatenate([p.reward for p in parts]))
    np.testing.assert_array_equal(
        got.info["reward_error"], np.concatenate([p.info["reward_error"] for p in parts])
    )


def test_the_parts_share_what_the_policy_reads_and_writes() -> None:
    with pytest.raises(ConfigError, match=r"part 1 differs from part 0 in \['obs_features'"):
        MixtureCore([PAPER, SCALED.replace(obs_features=("loglik",))], [0.5, 0.5], 4)
    with pytest.raises(ConfigError, match="action_mode"):
        MixtureCore([PAPER, SCALED.replace(action_mode="set", stay_base="tracker")], [1, 1], 4)
    two = EnvConfig(**POLICY, bank=CONTINUOUS_BANK[:2])
    with pytest.raises(ConfigError, match="bank size"):
        MixtureCore([PAPER, two], [0.5, 0.5], 4)


@pytest.mark.parametrize(
    ("field", "value"),
    [("loglik_clip", 10.0), ("p_min", 1e-2), ("logit_scale", 2.0),
     ("detector_weights", "other.safetensors")],
)
def test_parts_that_scale_what_the_policy_reads_or_writes_otherwise_are_refused(
    field, value
) -> None:
    # the loglik block divided by 10 in one part and by 20 (the default) in the other, or an
    # action bounded or scaled otherwise, or another detector network's beliefs, would not
    # mean one thing to one network
    with pytest.raises(ConfigError, match=rf"part 1 differs from part 0 in \['{field}'\]"):
        MixtureCore([PAPER, SCALED.replace(**{field: value})], [0.5, 0.5], 4)


def test_the_parts_give_each_entry_the_same_kind_of_model() -> None:
    """model_order bank: entry j is model j of each part's bank, so a part listing CT(-4), CV,
    CT(+4) would read and write CV's entry as CT(-4)'s; the canonical order reorders it. Banks
    whose entries stand for the same models at other turn rates are one order (a ranking by
    |omega| called them different); in the canonical order, banks turning faster one way than
    the other would give entry 1 opposite turns in the two parts."""
    permuted = PAPER.bank[2], PAPER.bank[0], PAPER.bank[1]
    with pytest.raises(ConfigError, match=r"part 1 gives its models the entries \['CT\(−\)'"):
        MixtureCore([PAPER, PAPER.replace(bank=permuted)], [0.5, 0.5], 4)
    canonical = PAPER.replace(model_order="canonical")
    MixtureCore([canonical, canonical.replace(bank=permuted)], [0.5, 0.5], 4)
    a = PAPER.replace(bank=({"kind": "cv"}, {"kind": "ct", "turn_rate_deg": 4.0},
                            {"kind": "ct", "turn_rate_deg": -2.0}))
    b = PAPER.replace(bank=({"kind": "cv"}, {"kind": "ct", "turn_rate_deg": 2.0},
                            {"kind": "ct", "turn_rate_deg": -4.0}))
    MixtureCore([a, b], [0.5, 0.5], 4)
    a, b = (c.replace(model_order="canonical") for c in (a, b))
    with pytest.raises(ConfigError, match=r"model_order canonical"):
        MixtureCore([a, b], [0.5, 0.5], 4)


def test_the_reset_info_is_each_slot_s_by_its_part() -> None:
    # what the vector env's reset and autoreset give (a runner's env may hold a mixture)
    mixture = MixtureCore([PAPER, SCALED], [0.4, 0.6], 5)
    alone = [TrackingCore(PAPER, 2), TrackingCore(SCALED, 3)]
    mixture.reset(np.arange(5), [11, 12, 13, 14, 15])
    alone[0].reset(np.arange(2), [11, 12])
    alone[1].reset(np.arange(3), [13, 14, 15])
    indices = np.array([4, 0, 2])
    got = mixture.reset_info(indices)
    expected = [alone[1].reset_info([2]), alone[0].reset_info([0]), alone[1].reset_info([0])]
    assert set(got) == {"true_state", "tpm"}
    for key in got:
        np.testing.assert_array_equal(got[key], np.concatenate([e[key] for e in expected]))


@pytest.mark.parametrize("index", [5, -1, 9])
def test_slots_outside_the_mixture_are_refused(index) -> None:
    # an index no part holds was left out silently (no episode started, no info row)
    mixture = MixtureCore([PAPER, SCALED], [0.4, 0.6], 5)
    mixture.reset(np.arange(5), [11, 12, 13, 14, 15])
    mixture.step(np.zeros((5, 3)))
    steps = [core.k.copy() for core in mixture.cores]
    with pytest.raises(ValueError, match=rf"slot indices \[{index}\] outside \[0, 5\)"):
        mixture.reset(np.array([0, index]), [1, 2])
    with pytest.raises(ValueError, match=rf"slot indices \[{index}\] outside \[0, 5\)"):
        mixture.reset_info(np.array([index]))
    for core, k in zip(mixture.cores, steps, strict=True):
        np.testing.assert_array_equal(core.k, k)  # slot 0 not reset either


def test_a_reset_takes_one_seed_per_slot() -> None:
    mixture = MixtureCore([PAPER, SCALED], [0.4, 0.6], 5)
    with pytest.raises(ValueError, match="4 seeds for 5 slots"):
        mixture.reset(np.arange(5), [1, 2, 3, 4])


def test_a_rejected_step_leaves_every_part_as_it_was() -> None:
    # the whole step is checked before the first part steps: a NaN in the last part's slots,
    # a row too many, an ended episode in the last part
    mixture = MixtureCore([PAPER, SCALED], [0.5, 0.5], 4)
    mixture.reset(np.arange(4), [1, 2, 3, 4])
    mixture.step(np.zeros((4, 3)))

    def state() -> list[np.ndarray]:
        return [a.copy() for core in mixture.cores for a in (core.k, core.mu, core.state_a.x)]

    before = state()
    nan = np.zeros((4, 3))
    nan[3, 0] = np.nan
    ended = mixture.cores[1].done.copy()
    ended[1] = True  # slot 3's episode ended
    for action, done, error, message in [
        (nan, None, ActionError, "finite"),
        (np.zeros((5, 3)), None, ActionError, "shape"),
        (np.zeros((4, 3)), ended, RuntimeError, r"slots \[3\] have ended"),
    ]:
        if done is not None:
            mixture.cores[1].done = done
        with pytest.raises(error, match=message):
            mixture.step(action)
        for got, want in zip(state(), before, strict=True):
            np.testing.assert_array_equal(got, want)
    mixture.step(np.zeros((4, 3)), active=np.array([True, True, True, False]))  # 3 not active


@pytest.mark.parametrize(
    ("parts", "message"),
    [
        ([], "non-empty list"),
        ([{"env_kwargs": {}}], "keys env_kwargs and share"),
        ([{"env_kwargs": [], "share": 0.5}], "must be a mapping"),
        ([{"env_kwargs": {}, "share": 1.0}], r"share must be a number in \(0, 1\)"),
        # a share of 0 (no slot) and a part with a key besides the two (a misspelled one)
        ([{"env_kwargs": {}, "share": 0.2}, {"env_kwargs": {}, "share": 0}],
         r"env_mixture\[1\].share must be a number in \(0, 1\), got 0"),
        ([{"env_kwargs": {}, "share": 0.5, "shares": 0.2}],
         r"env_mixture\[0\] must be a mapping with the keys env_kwargs and share"),
        ([{"env_kwargs": {}, "share": 0.6}, {"env_kwargs": {}, "share": 0.4}], "sum to 1"),
    ],
)
def test_bad_mixture_entries_name_the_part(parts, message) -> None:
    with pytest.raises(ConfigError, match=message):
        check_mixture("env_mixture", parts)


def test_the_sb3_adapter_gives_each_slot_its_part_s_config() -> None:
    # get_attr("config") gave part 0's configuration for every slot
    from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv

    scaled = {**POLICY, "bank": CONTINUOUS_BANK, "sojourn": (60.0, 20.0, 20.0)}
    mixture = [{"env_kwargs": {**scaled, "vary": {"T": [0.5, 5.0]}}, "share": 0.5}]
    env = TPMAdaptSB3VecEnv(4, config=POLICY, mixture=mixture)
    configs = env.get_attr("config")
    parts = [env.core.cores[p].config for p in (0, 0, 1, 1)]
    assert all(c is part for c, part in zip(configs, parts, strict=True))
    assert not configs[1].vary.active and configs[3].vary.active
    assert env.get_attr("config", indices=3)[0] is env.core.cores[1].config
    assert env.get_attr("num_envs", indices=[0, 3]) == [4, 4]
    with pytest.raises(IndexError, match=r"outside \[0, 4\)"):
        env.get_attr("config", indices=[4])


def test_a_further_part_gets_its_own_share_and_the_last_slots() -> None:
    """``MixtureCore.of``: the configuration keeps ``1 - 0.25`` of 8 slots, 6, and the first
    ones; the further part (sensor outliers) its 0.25, 2, after them (equal shares could not
    tell the parts' shares apart)."""
    from imm_gym.envs.sb3 import TPMAdaptSB3VecEnv

    mixture = [{"env_kwargs": {**POLICY, "sensor": {"outlier_prob": 0.1}}, "share": 0.25}]
    core = MixtureCore.of(EnvConfig(**POLICY), mixture, {}, 8)
    assert np.diff(core.starts).tolist() == [6, 2]
    assert [c.config.sensor.outlier_prob for c in core.cores] == [0.0, 0.1]
    env = TPMAdaptSB3VecEnv(8, config=POLICY, mixture=mixture)
    assert [c.sensor.outlier_prob for c in env.get_attr("config")] == [0.0] * 6 + [0.1] * 2


def test_each_further_part_gets_its_own_share_in_order() -> None:
    """Two further parts of shares 0.25 and 0.125 of 8 slots: the configuration keeps
    ``(1 - 0.375) 8 = 5``, then 2 and 1 slots, in the order listed (outliers 0.1, then 0.2)."""
    mixture = [
        {"env_kwargs": {**POLICY, "sensor": {"outlier_prob": 0.1}}, "share": 0.25},
        {"env_kwargs": {**POLICY, "sensor": {"outlier_prob": 0.2}}, "share": 0.125},
    ]
    core = MixtureCore.of(EnvConfig(**POLICY), mixture, {}, 8)
    assert np.diff(core.starts).tolist() == [5, 2, 1]
    assert [c.config.sensor.outlier_prob for c in core.cores] == [0.0, 0.1, 0.2]


@pytest.mark.parametrize("n", [4, 6])
def test_the_streams_are_one_pair_per_slot(n) -> None:
    # one pair too many was dropped silently, one too few blamed on the last part's 3 slots
    mixture = MixtureCore([PAPER, SCALED], [0.4, 0.6], 5)
    pairs = [(np.random.default_rng(s), np.random.default_rng(s + 100)) for s in range(n)]
    with pytest.raises(ValueError, match=f"{n} stream pairs for 5 slots"):
        mixture.set_streams(pairs)


def test_the_mixture_is_its_first_part_s_configuration() -> None:
    # what an agent trained on the mixture records as its settings
    assert MixtureCore([PAPER, SCALED], [0.5, 0.5], 4).config is PAPER
    assert MixtureCore([SCALED, PAPER], [0.5, 0.5], 4).config is SCALED


def test_one_share_per_configuration() -> None:
    with pytest.raises(ConfigError, match="2 mixture configurations for 1 shares"):
        MixtureCore([PAPER, SCALED], [1.0], 4)
    with pytest.raises(ConfigError, match="1 mixture configurations for 2 shares"):
        MixtureCore([PAPER], [0.5, 0.5], 4)


def test_a_config_file_s_reward_reaches_every_part() -> None:
    """What an agent is trained as (its reward and reward scale, costs) given by a ``--config``
    file applies to every part of the entry's mixture; each part's tracker (its sensor) stays
    its own."""
    from agents.train_setup import with_config

    params = {"env_kwargs": {"scenario": "random"},
              "env_mixture": [{"env_kwargs": {"sensor": {"sigma_r": 30.0}}, "share": 0.5}]}
    extra = {"env_kwargs": {"reward": "error", "reward_scale": 5.0, "tpm_cost": 0.1,
                            "sensor": {"sigma_r": 80.0}}}
    part = with_config(params, extra)["env_mixture"][0]
    assert part == {"share": 0.5, "env_kwargs": {"sensor": {"sigma_r": 30.0}, "reward": "error",
                                                 "reward_scale": 5.0, "tpm_cost": 0.1}}
