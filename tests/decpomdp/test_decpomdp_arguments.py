"""decpomdp's public boundary: numpy and torch scalars count as numbers; errors name the argument."""

import numpy as np
import pytest
import torch

from decpomdp import PerfectPerception, RolloutScorer, monte_carlo_search, simulate
from decpomdp.domains import DisasterRelief, PackageDelivery, shared
from decpomdp.domains import package_delivery as pd


def test_numpy_and_torch_scalars_are_accepted():
    env = DisasterRelief(
        PerfectPerception(np.int64(6), frames=torch.tensor(10)),
        num_agents=np.int32(2),
        gamma=np.float32(0.99),
        degrade_prob=torch.tensor(0.1),
    )
    assert env.num_agents == 2 and type(env.num_agents) is int and env.gamma == pytest.approx(0.99)
    env = PackageDelivery(gamma=np.float64(0.95), horizon=np.int64(20), joint_wait=torch.tensor(2.0))
    assert (env.gamma, env.horizon, env.joint_wait) == (0.95, 20.0, 2.0)
    returns = simulate(env, pd.greedy_controller(), np.int64(3), torch.Generator().manual_seed(0))
    assert returns.shape == (1, 3)
    assert RolloutScorer(env, shared=True)(pd.greedy_controller()[0], np.int64(4), torch.Generator())[0].shape == (1,)
    assert shared(pd.greedy_controller()[0], np.int64(2)).num_agents == 2


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        ({"gamma": "0.9"}, TypeError, "gamma: expected a number"),
        ({"gamma": 0.0}, ValueError, r"gamma: expected a finite number in \(0, 1\]"),
        ({"num_agents": 1.0}, TypeError, "num_agents: expected an int"),
        ({"sensor_accuracy": np.float64(1.2)}, ValueError, r"sensor_accuracy: expected a finite number in \[0, 1\]"),
        ({"frame_period": float("nan")}, ValueError, "frame_period: expected a finite number"),
    ],
)
def test_bad_domain_settings_name_the_argument(kwargs, error, message):
    with pytest.raises(error, match=message):
        DisasterRelief(**kwargs)


def test_bad_counts_name_the_argument():
    with pytest.raises(TypeError, match="frames: expected an int"):
        PerfectPerception(6, frames=2.5)
    with pytest.raises(ValueError, match="rollouts_per_controller: expected an int >= 1, got 0"):
        simulate(PackageDelivery(), pd.greedy_controller(), 0, torch.Generator())
    with pytest.raises(ValueError, match="rollouts: expected an int >= 2, got 1"):
        monte_carlo_search(RolloutScorer(PackageDelivery(), shared=True), num_nodes=2, budget=1, rollouts=1)
