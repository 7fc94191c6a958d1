"""Package delivery semantics against hand-computed cases, and against an independent per-rollout simulator.

Hand-computed cases switch the duration noise off and fix the package stream by monkeypatching the
constants ``DURATION_NOISE`` and ``ARRIVAL`` of :mod:`decpomdp.domains.package_delivery.rules`.
"""

import math
from pathlib import Path

import pytest
import torch

from decpomdp import JointController, simulate
from decpomdp.domains import PackageDelivery, rollout_counters
from decpomdp.domains import package_delivery as pd

ROOT = Path(__file__).resolve().parents[2]


def g(seed=0):
    return torch.Generator().manual_seed(seed)


def cycle(*per_agent):
    """A K = 1 joint controller where agent a runs per_agent[a] in a loop, whatever it observes."""
    nodes = max(len(seq) for seq in per_agent)
    action = torch.full((1, 2, nodes), pd.WAIT)
    next_node = torch.zeros(1, 2, nodes, pd.PackageDelivery.num_obs, dtype=torch.long)
    for a, seq in enumerate(per_agent):
        action[0, a, : len(seq)] = torch.tensor(seq)
        next_node[0, a, : len(seq)] = (torch.arange(len(seq)) + 1).remainder(len(seq))[:, None]
    return JointController(action, next_node)


@pytest.fixture
def exact(monkeypatch, backend):
    """No duration noise; every new package has code ``code`` (see pd.PACKAGES); on both backends."""
    monkeypatch.setattr(pd.rules, "DURATION_NOISE", 0.0)

    def packages(code):
        monkeypatch.setattr(pd.rules, "ARRIVAL", torch.tensor([code], dtype=torch.int32))

    return packages


def discounted(times, reward, gamma=0.99):
    return sum(reward * gamma**t for t in times)


def test_small_package_cycle_reward_discount_and_horizon(exact):
    # robot 0: pick up (1) at Base1, go to Dest2 (2), put down (1), back to Base1 (2): reward 1 at t = 4 + 6k
    exact(1)
    ctrl = cycle([pd.PICK, pd.GO_D2, pd.PUT, pd.GO_B1], [pd.WAIT])
    value = simulate(PackageDelivery(horizon=46.0), ctrl, 2, g())
    torch.testing.assert_close(value, torch.full((1, 2), discounted(range(4, 47, 6), 1.0), dtype=torch.float64))
    cut = simulate(PackageDelivery(horizon=45.999), ctrl, 1, g())  # the completion at t = 46 is beyond it
    assert cut.item() == pytest.approx(discounted(range(4, 41, 6), 1.0))
    returns, counters = rollout_counters(PackageDelivery(), ctrl, 3, g())
    assert counters["delivered"].tolist() == [[8, 8, 8]] and counters["wrong"].sum() == 0
    assert returns[0, 0].item() == pytest.approx(discounted(range(4, 51, 6), 1.0))


def test_gamma_one_counts_rewards(exact):
    exact(0)  # small -> Dest1: pick 1, go 3, put 1, go Base1 from Dest1 3 -> rewards at t = 5 + 8k
    ctrl = cycle([pd.PICK, pd.GO_D1, pd.PUT, pd.GO_B1], [pd.WAIT])
    assert simulate(PackageDelivery(gamma=1.0, horizon=50.0), ctrl, 1, g()).item() == 6.0


def test_wrong_destination_earns_nothing_and_is_counted(exact):
    exact(0)  # bound for Dest1, carried to Dest2
    ctrl = cycle([pd.PICK, pd.GO_D2, pd.PUT, pd.GO_B1], [pd.WAIT])
    returns, counters = rollout_counters(PackageDelivery(), ctrl, 2, g())
    assert returns.abs().max() == 0
    assert counters["wrong"].tolist() == [[8, 8]] and counters["delivered"].sum() == 0


def test_truck_delivery(exact):
    exact(2)  # small -> Rendezvous: pick 1, go R 3, place 1, back to Base1 from R 4: reward at 5 + 9k
    ctrl = cycle([pd.PICK, pd.GO_R, pd.TRUCK, pd.GO_B1], [pd.WAIT])
    assert simulate(PackageDelivery(), ctrl, 1, g()).item() == pytest.approx(discounted(range(5, 51, 9), 1.0))
    assert simulate(PackageDelivery(truck_reward=0.0), ctrl, 1, g()).item() == 0.0


@pytest.mark.parametrize("per_robot, reward", [(True, 6.0), (False, 3.0)])
def test_large_package_needs_both_robots(exact, per_robot, reward):
    # joint pick-up 1.5, joint go Base1 -> Dest2 3, joint put-down 1.5, back 2: reward at t = 6 + 8k
    exact(4)
    seq = [pd.JPICK, pd.JGO_D2, pd.JPUT, pd.GO_B1]
    env = PackageDelivery(large_reward_per_robot=per_robot)
    returns, counters = rollout_counters(env, cycle(seq, seq), 1, g())
    assert returns.item() == pytest.approx(discounted(range(6, 51, 8), reward))
    assert counters["delivered"].item() == counters["delivered_large"].item() == 6
    # a partner at the same place is drafted into the joint MAs whatever it chose itself; after the
    # first delivery it waits at Dest2 while robot 0 returns alone, so there is one delivery only
    drafted = simulate(env, cycle(seq, [pd.WAIT]), 1, g())
    assert drafted.item() == pytest.approx(reward * 0.99**6)
    # a partner elsewhere (Base2) cannot help: the joint pick-up waits, then fails
    alone, counters = rollout_counters(env, cycle([pd.WAIT, *seq], [pd.GO_B2, pd.WAIT]), 1, g())
    assert alone.item() == 0.0 and counters["delivered"].item() == 0
    solo = simulate(env, cycle([pd.PICK, pd.GO_D2, pd.PUT, pd.GO_B1], [pd.WAIT]), 1, g())
    assert solo.item() == 0.0  # a large package cannot be picked up alone


@pytest.mark.parametrize("per_robot", [True, False])
def test_solo_joint_reference_rule(exact, per_robot):
    # with solo_joint a robot runs the joint MAs alone when its partner is away (at Base2 here)
    exact(4)
    env = PackageDelivery(solo_joint=True, large_reward_per_robot=per_robot)
    ctrl = cycle([pd.WAIT, pd.JPICK, pd.JGO_D2, pd.JPUT, pd.GO_B1], [pd.GO_B2, pd.WAIT])
    returns, counters = rollout_counters(env, ctrl, 1, g())
    assert returns.item() == pytest.approx(discounted(range(7, 51, 9), 3.0))  # 1 + 1.5 + 3 + 1.5 = 7, then every 9
    assert counters["delivered_large"].item() == 5 and counters["delivered"].item() == 5
    assert "solo_joint=True" in repr(env)


def test_joint_rendezvous_partner_arrives_later(exact):
    exact(4)
    env = PackageDelivery(joint_wait=4.0)
    state = env.reset(1, g())
    both = torch.tensor([[True, True]])
    # robot 0 starts the joint pick-up at t = 0 and waits; robot 1 is busy until t = 1
    end = env.start(
        state,
        torch.tensor([[True, False]]),
        torch.tensor([[pd.JPICK, pd.WAIT]]),
        torch.zeros(1),
        torch.tensor([[0.0, 1.0]], dtype=torch.float64),
        g(),
    )
    assert end.tolist() == [[4.0, 1.0]] and state["waiting"].tolist() == [[True, False]]
    reward, obs = env.complete(
        state, torch.tensor([[False, True]]), torch.tensor([[pd.JPICK, pd.WAIT]]), torch.ones(1), g()
    )
    assert pd.OBS_NAMES[obs[0, 1]] == "large_dest2_partner"  # the waiting robot counts as present
    # robot 1 chooses to go to Base2 but is drafted into the joint pick-up
    end = env.start(state, torch.tensor([[False, True]]), torch.tensor([[pd.JPICK, pd.GO_B2]]), torch.ones(1), end, g())
    assert end.tolist() == [[2.5, 2.5]]  # both finish together, 1.5 after the partner joined
    assert state["ma"].tolist() == [[pd.JPICK, pd.JPICK]]
    assert state["load"].tolist() == [[5, 5]] and not state["waiting"].any()
    reward, obs = env.complete(state, both, torch.tensor([[pd.JPICK, pd.JPICK]]), torch.full((1,), 2.5), g())
    assert [pd.OBS_NAMES[o] for o in obs[0]] == ["large_dest2_partner"] * 2 and reward.item() == 0.0


def test_joint_wait_runs_out(exact):
    exact(4)
    env = PackageDelivery(joint_wait=2.5)
    state = env.reset(1, g())
    zero = torch.zeros(1, 2, dtype=torch.float64)
    r0, r1 = torch.tensor([[True, False]]), torch.tensor([[False, True]])
    end = env.start(state, r1, torch.tensor([[pd.WAIT, pd.GO_B2]]), torch.zeros(1), zero, g())  # robot 1 leaves
    end = env.start(state, r0, torch.tensor([[pd.JPICK, pd.GO_B2]]), torch.full((1,), 0.5), end, g())
    assert end.tolist() == [[3.0, 2.0]] and state["waiting"].tolist() == [[True, False]]
    env.complete(state, r1, torch.tensor([[pd.JPICK, pd.GO_B2]]), torch.full((1,), 2.0), g())
    end = env.start(state, r1, torch.tensor([[pd.JPICK, pd.WAIT]]), torch.full((1,), 2.0), end, g())
    assert end.tolist() == [[3.0, 3.0]] and state["ma"][0, 1] == pd.WAIT  # at Base2: not drafted
    _, obs = env.complete(
        state, torch.tensor([[True, True]]), torch.tensor([[pd.JPICK, pd.WAIT]]), torch.full((1,), 3.0), g()
    )
    assert state["load"].tolist() == [[0, 0]] and not state["waiting"].any()
    assert pd.OBS_NAMES[obs[0, 0]] == "large_dest2_alone"


def test_simultaneous_pick_up_clash(exact):
    exact(1)
    env = PackageDelivery()
    state = env.reset(1, g())
    end = env.start(
        state,
        torch.tensor([[True, True]]),
        torch.full((1, 2), pd.PICK),
        torch.zeros(1),
        torch.zeros(1, 2, dtype=torch.float64),
        g(),
    )
    assert state["load"].tolist() == [[2, 0]] and state["ok"].tolist() == [[True, False]]
    assert end.tolist() == [[1.0, pd.FAIL_DURATION]]


def test_observations(exact):
    exact(1)
    env = PackageDelivery()
    ctrl_obs = {}
    state = env.reset(1, g())
    env.start(
        state,
        torch.tensor([[True, True]]),
        torch.tensor([[pd.PICK, pd.GO_R]]),
        torch.zeros(1),
        torch.zeros(1, 2, dtype=torch.float64),
        g(),
    )
    _, obs = env.complete(state, torch.tensor([[True, False]]), torch.tensor([[pd.PICK, pd.GO_R]]), torch.ones(1), g())
    ctrl_obs["after pick, partner travelling"] = pd.OBS_NAMES[obs[0, 0]]
    _, obs = env.complete(
        state, torch.tensor([[False, True]]), torch.tensor([[pd.PICK, pd.GO_R]]), torch.full((1,), 3.0), g()
    )
    ctrl_obs["at the rendezvous"] = pd.OBS_NAMES[obs[0, 1]]
    assert ctrl_obs == {"after pick, partner travelling": "small_dest2_alone", "at the rendezvous": "none"}
    assert state["loc"].tolist() == [[pd.BASE1, pd.RENDEZVOUS]]


def test_preconditions_table():
    assert pd.preconditions_hold(pd.BASE1, 0, 0, pd.PICK)
    assert not pd.preconditions_hold(pd.BASE1, 0, 3, pd.PICK)  # large needs the joint pick-up
    assert pd.preconditions_hold(pd.BASE1, 0, 3, pd.JPICK)
    assert not pd.preconditions_hold(pd.BASE1, 1, 0, pd.PICK)  # already carrying
    assert not pd.preconditions_hold(pd.DEST1, 0, 0, pd.GO_R)  # no path Dest1 -> Rendezvous
    assert not pd.preconditions_hold(pd.BASE1, 4, 0, pd.GO_D1)  # a large load moves only jointly
    assert pd.preconditions_hold(pd.BASE1, 4, 0, pd.JGO_D1)
    assert pd.preconditions_hold(pd.RENDEZVOUS, 3, 0, pd.TRUCK)
    assert not pd.preconditions_hold(pd.DEST1, 4, 0, pd.PUT)
    assert all(pd.preconditions_hold(loc, load, 0, pd.WAIT) for loc in range(5) for load in range(6))


def test_duration_noise_statistics():
    # tau = 3 (go to Dest1 from Base1): mean 3, sd 0.9 (the clamp at 0.1 tau is 3 sd away: negligible)
    env, n = PackageDelivery(), 20000
    state = env.reset(n, g(1))
    end = env.start(
        state,
        torch.ones(n, 2, dtype=torch.bool),
        torch.full((n, 2), pd.GO_D1),
        torch.zeros(n),
        torch.zeros(n, 2, dtype=torch.float64),
        g(2),
    )
    d = end.flatten()
    se = 0.9 / math.sqrt(d.numel())
    assert abs(d.mean().item() - 3.0) < 4 * se
    assert abs(d.std().item() - 0.9) < 4 * 0.9 / math.sqrt(2 * d.numel())
    assert d.min() >= 3.0 * pd.MIN_NOISE_FACTOR


def test_greedy_controller_and_seeded_determinism():
    env, ctrl = PackageDelivery(), pd.greedy_controller()
    a, b = simulate(env, ctrl, 200, g(7)), simulate(env, ctrl, 200, g(7))
    assert torch.equal(a, b) and not torch.equal(a, simulate(env, ctrl, 200, g(8)))
    assert a.mean() > 10.0  # delivers steadily (about 14 in expectation)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"gamma": 0.0}, "gamma"),
        ({"gamma": 1.5}, "gamma"),
        ({"horizon": 0.0}, "horizon"),
        ({"horizon": math.inf}, "horizon"),
        ({"joint_wait": -1.0}, "joint_wait"),
        ({"small_reward": math.nan}, "small_reward"),
    ],
)
def test_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        PackageDelivery(**kwargs)


def test_rollout_counters_bad_key():
    with pytest.raises(ValueError, match="keys"):
        rollout_counters(PackageDelivery(), pd.greedy_controller(), 2, g(), keys=("nope",))
