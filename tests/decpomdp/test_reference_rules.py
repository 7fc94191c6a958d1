"""Package delivery under the reference simulator's successor rule, against hand-computed returns.

Duration noise is off and every new package is small and bound for Dest1 (the ``exact`` fixture), so
each MA lasts its mean: pick-up 1, Base1 -> Dest1 3, put-down 1, Dest1 -> Base1 3, wait 1, and a failed
MA lasts ``FAIL_DURATION`` = 1.
"""

import pytest
import torch

from decpomdp import simulate
from decpomdp.domains import PackageDelivery, rollout_counters
from decpomdp.domains import package_delivery as pd
from decpomdp.domains.package_delivery import domain

from test_package_delivery import cycle, discounted, exact  # noqa: F401 (exact is a fixture)


def run(ctrl, **kw):
    returns, counters = rollout_counters(PackageDelivery(**kw), ctrl, 2, torch.Generator().manual_seed(0))
    return returns[0, 0].item(), counters["delivered"][0, 0].item()


def test_a_put_down_failing_by_the_rule_alone_still_pays(exact):
    exact(0)
    # go to Dest1 (t = 4), wait (not a successor of go-to-Dest1: fails, 1 unit), put down (not a successor
    # of wait: fails, 1 unit, but the robot holds the right small package at its destination: pays at
    # t = 6), back to Base1 (t = 9): a delivery every 9 units, with or without the rule
    ctrl = cycle([pd.PICK, pd.GO_D1, pd.WAIT, pd.PUT, pd.GO_B1], [pd.WAIT])
    expected = discounted(range(6, 51, 9), 1.0)
    assert run(ctrl, successor_rule=True) == (pytest.approx(expected), 5)
    assert run(ctrl) == (pytest.approx(expected), 5)


def test_an_ma_that_may_not_follow_fails(exact):
    exact(0)
    # without the rule: pick up, wait, go to Dest1, put down at t = 6, back at t = 9 (every 9 units);
    # with it, go-to-Dest1 after a wait fails, the robot stays at Base1, its put-down there fails and
    # does not pay (its own preconditions do not hold), and from then on it carries the package forever
    ctrl = cycle([pd.PICK, pd.WAIT, pd.GO_D1, pd.PUT, pd.GO_B1], [pd.WAIT])
    assert run(ctrl) == (pytest.approx(discounted(range(6, 51, 9), 1.0)), 5)
    assert run(ctrl, successor_rule=True) == (0.0, 0)


def test_the_first_ma_follows_go_to_base1(exact):
    exact(0)
    # the reference's robots start as if they had just gone to Base1: going to Dest1 straight away fails
    # (1 unit, no move), going to Base2 (a successor of go-to-Base1) takes its 2 units
    g = torch.Generator()
    for rule, dest1_end in ((True, pd.FAIL_DURATION), (False, 3.0)):
        env = PackageDelivery(successor_rule=rule)
        state = env.reset(1, g)
        end = env.start(
            state,
            torch.ones(1, 2, dtype=torch.bool),
            torch.tensor([[pd.GO_D1, pd.GO_B2]]),
            torch.zeros(1, dtype=torch.float64),
            torch.zeros(1, 2, dtype=torch.float64),
            g,
        )
        assert end.tolist() == [[dest1_end, 2.0]]
    state = PackageDelivery(successor_rule=True).reset(3, g)
    assert state["ma"].tolist() == [[pd.GO_B1, pd.GO_B1]] * 3 and not state["pays"].any()


def test_successor_table_matches_the_reference():
    allowed = domain._SUCCESSOR.view(13, 13).bool()
    assert allowed.sum().item() == sum(len(v) for v in pd.REFERENCE_SUCCESSORS.values()) == 31
    assert allowed[pd.WAIT].nonzero().squeeze(1).tolist() == [pd.WAIT]
    assert allowed[pd.PICK].nonzero().squeeze(1).tolist() == [pd.GO_R, pd.GO_D1, pd.GO_D2]
    assert "successor_rule=True" in repr(PackageDelivery(successor_rule=True))
    # the rule only restricts: the hand-written greedy controller (which waits at the base) loses value
    g = torch.Generator().manual_seed(0)
    free = simulate(PackageDelivery(), pd.greedy_controller(), 500, g).mean().item()
    ruled = simulate(PackageDelivery(successor_rule=True), pd.greedy_controller(), 500, g).mean().item()
    assert ruled < free


def test_reference_pickup_lets_one_robot_deliver_a_large_package(exact):
    exact(3)  # every package large, bound for Dest1
    # pick up (a large package: taken, 1 unit), go to Dest1 carrying it (3), joint put-down (not a successor
    # of go-to-Dest1: fails, 1 unit, but pays 3 to the robot holding the large package at its destination),
    # back to Base1 (3): 3 every 8 units for robot 0 alone
    ctrl = cycle([pd.PICK, pd.GO_D1, pd.JPUT, pd.GO_B1], [pd.WAIT])
    preset = dict(successor_rule=True, solo_joint=True, truck_reward=0.0)
    assert run(ctrl, reference_pickup=True, **preset) == (pytest.approx(discounted(range(5, 51, 8), 3.0)), 6)
    assert run(ctrl, **preset) == (0.0, 0)  # a solo pick-up of a large package fails without the rule
    assert pd.preconditions_hold(pd.BASE1, 0, 3, pd.PICK, reference_pickup=True)
    assert not pd.preconditions_hold(pd.BASE1, 0, 3, pd.PICK)
    assert pd.preconditions_hold(pd.BASE1, 4, 0, pd.GO_D1, reference_pickup=True)  # moving with a large load
    assert pd.preconditions_hold(pd.BASE1, 1, 3, pd.PICK, reference_pickup=True)  # a loaded robot picks up anew
    assert not pd.preconditions_hold(pd.BASE1, 1, 0, pd.PICK)
    assert "reference_pickup=True" in repr(PackageDelivery(reference_pickup=True))
