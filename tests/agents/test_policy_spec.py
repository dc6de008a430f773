"""The description of a live network (agents/network.py's policy_spec) is the one it was built
from, and a network that description could not rebuild is refused."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy

from agents.network import build_policy, policy_spec
from agents.schema import check_spec

#: Descriptions with settings away from SB3's defaults: each must come back as written.
SPECS = [
    {"class": "MlpPolicy", "observation_size": 7, "action_size": 3, "net_arch": [5, 4],
     "activation_fn": "relu", "log_std_init": -0.5, "ortho_init": False,
     "share_features_extractor": True, "use_sde": False},
    {"class": "AsymmetricMlpPolicy", "observation_size": 12, "action_size": 3,
     "net_arch": {"pi": [5], "vf": [4, 4]}, "activation_fn": "tanh", "log_std_init": 0.25,
     "ortho_init": False, "share_features_extractor": True, "use_sde": False,
     "critic_dims": 2, "frame_stack": 3},
]


@pytest.mark.parametrize("spec", SPECS)
def test_the_description_of_a_built_network_is_the_one_it_was_built_from(spec: dict) -> None:
    """agent.json records what the network is: ortho_init false and a log_std_init of its own
    come back as written, not as SB3's defaults (true, 0.0)."""
    spec = check_spec("test", spec)
    assert policy_spec(build_policy(spec, "test")) == spec


@pytest.mark.parametrize(("low", "high"), [(0.0, 1.0), (-1.0, 2.0)])
def test_a_network_acting_outside_minus_one_to_one_is_refused(low: float, high: float) -> None:
    """build_policy rebuilds every network with a Box(-1, 1) action: one of another range would
    come back acting in another range, so it cannot be described."""
    policy = ActorCriticPolicy(
        spaces.Box(-np.inf, np.inf, (4,), np.float32),
        spaces.Box(low, high, (2,), np.float32),
        lambda _: 0.0,
    )
    with pytest.raises(ValueError, match="ActorCriticPolicy of this configuration cannot be saved"):
        policy_spec(policy)
