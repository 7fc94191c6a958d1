"""Simulator semantics against hand-computed returns on the toy Dec-POSMDP of conftest.py."""

import math

import pytest
import torch

from decpomdp import JointController, evaluate, simulate


def fixed(actions_per_agent, nodes=1, obs=2, next_node=None):
    """One joint controller where agent a runs actions_per_agent[a][n] in node n."""
    action = torch.tensor([actions_per_agent], dtype=torch.long)
    if next_node is None:
        next_node = torch.zeros(1, len(actions_per_agent), nodes, obs, dtype=torch.long)
    return JointController(action, next_node)


def g(seed=0):
    return torch.Generator().manual_seed(seed)


def test_durations_and_simultaneous_completion(toy_env):
    # agent 0 runs MA 0 (1 unit), agent 1 MA 1 (2 units): events at t = 1 (r 1), 2 (both, r 1 + 2), 3 (r 1), 4 (r 3)
    env = toy_env(gamma=0.5, horizon=4.0)
    ret = simulate(env, fixed([[0], [1]]), 3, g())
    expected = 0.5 * 1 + 0.25 * 3 + 0.125 * 1 + 0.0625 * 3
    assert ret.shape == (1, 3)
    torch.testing.assert_close(ret, torch.full((1, 3), expected, dtype=torch.float64))


def test_horizon_cut_off_is_inclusive(toy_env):
    ctrl = fixed([[0], [1]])
    just_before = simulate(toy_env(gamma=0.5, horizon=3.999), ctrl, 2, g())
    torch.testing.assert_close(just_before[0, 0].item(), 0.5 + 0.75 + 0.125)
    assert simulate(toy_env(gamma=0.5, horizon=0.5), ctrl, 2, g()).abs().max() == 0


def test_observation_drives_node_transition(toy_env):
    # agent 0: node 0 runs MA 0, node 1 runs MA 1; it moves to node 1 on observing "together" (obs 1).
    # t=1: a0 alone (r 1) stays in node 0; t=2: both complete (r 1 + 2), a0 -> node 1 (MA 1, ends 4);
    # t=4: both complete MA 1 (r 2 + 2); t=6 likewise (beyond horizon 5).
    action = torch.tensor([[[0, 1], [1, 1]]])
    next_node = torch.tensor([[[[0, 1], [1, 1]], [[0, 0], [0, 0]]]])
    ret = simulate(toy_env(gamma=0.5, horizon=5.0), JointController(action, next_node), 1, g())
    assert ret.item() == pytest.approx(0.5 * 1 + 0.25 * 3 + 0.0625 * 4)


def test_joint_macro_action_synchronises_partner(toy_env):
    # both run the joint MA 2 (3 units): they finish together at t = 3, 6, ... earning 3 + 3 each time.
    ret = simulate(toy_env(gamma=0.9, horizon=7.0), fixed([[2], [2]]), 1, g())
    assert ret.item() == pytest.approx(6 * (0.9**3 + 0.9**6))


def test_controllers_map_to_their_rows_with_compaction(toy_env):
    # K = 3 controllers with different event counts so rollouts stop at different iterations.
    ctrl = JointController.cat([fixed([[0], [0]]), fixed([[1], [1]]), fixed([[0], [1]])])
    env = toy_env(gamma=0.5, horizon=4.0)
    ret = simulate(env, ctrl, 5, g())
    v0 = sum(2 * 0.5**t for t in (1, 2, 3, 4))
    v1 = sum(4 * 0.5**t for t in (2, 4))
    v2 = 0.5 * 1 + 0.25 * 3 + 0.125 * 1 + 0.0625 * 3
    torch.testing.assert_close(ret, torch.tensor([[v0], [v1], [v2]], dtype=torch.float64).expand(3, 5))


def test_discounting_at_random_event_time(toy_env):
    # agent 0 runs an Exp(rate) MA once in effect: E[gamma ** T] = rate / (rate - log gamma) per completion.
    # Agent 1 never completes before the horizon (200, where 0.8 ** 200 < 1e-19); the value is a geometric sum.
    rate, gamma = 2.0, 0.8
    env = toy_env(durations=(1.0, 1e9, 3.0), gamma=gamma, horizon=200.0, exponential=(0,), rate=rate)
    mean, se = evaluate(env, fixed([[0], [1]]), 20000, g(1))
    q = rate / (rate - math.log(gamma))
    exact = q / (1 - q)  # sum_{n>=1} q ** n, reward 1 per completion
    assert abs(mean.item() - exact) < 3 * se.item()


def test_seeded_determinism(toy_env):
    env = toy_env(durations=(1.0, 2.0, 3.0), gamma=0.9, horizon=20.0, exponential=(0, 1), rate=1.5)
    ctrl = JointController(
        torch.randint(0, 3, (4, 2, 3), generator=g(3)), torch.randint(0, 3, (4, 2, 3, 2), generator=g(4))
    )
    a, b = simulate(env, ctrl, 50, g(7)), simulate(env, ctrl, 50, g(7))
    assert torch.equal(a, b)
    assert not torch.equal(a, simulate(env, ctrl, 50, g(8)))


def test_bad_arguments(toy_env):
    env = toy_env()
    with pytest.raises(ValueError, match="rollouts_per_controller"):
        simulate(env, fixed([[0], [0]]), 0, g())
    with pytest.raises(ValueError, match="agents"):
        simulate(
            env,
            JointController(torch.zeros(1, 3, 1, dtype=torch.long), torch.zeros(1, 3, 1, 2, dtype=torch.long)),
            1,
            g(),
        )
    with pytest.raises(ValueError, match="action entries"):
        simulate(env, fixed([[5], [0]]), 1, g())
    with pytest.raises(TypeError, match="env"):
        simulate(object(), fixed([[0], [0]]), 1, g())
    with pytest.raises(ValueError, match="finite horizon"):
        simulate(toy_env(horizon=math.inf), fixed([[0], [0]]), 1, g())
    with pytest.raises(ValueError, match="rollouts"):
        evaluate(env, fixed([[0], [0]]), 1, g())
