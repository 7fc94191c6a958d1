"""GMAA*-ICE and its heuristics against exhaustive search and published optima; cyclic controllers."""

import itertools
import math

import numpy as np
import pytest
import torch

from decpomdp import solve
from decpomdp.controller import JointController
from decpomdp.dpomdp import exact_value, upper_bounds
from decpomdp.dpomdp.bounds import lookahead_bound
from decpomdp.dpomdp import cyclic
from decpomdp.dpomdp.cyclic import ascend, count_controllers, every_controller, loop_back, neighbours, with_agent
from decpomdp.dpomdp.exhaustive import exhaustive_optimum
from decpomdp.dpomdp.gmaa import GMAA, cluster, gmaa_ice, stage_bound
from decpomdp.dpomdp.heuristics import Heuristic, joint_rules
from tiny_problems import problem

PUBLISHED = {  # MADP toolbox, src/tests/optimalValueDatabase (problem, discount, horizon, value)
    ("dectiger", 1.0, 3): 5.190812499999996,
    ("dectiger", 1.0, 4): 4.802755156249994,
    ("dectiger", 0.9, 4): 2.455208016555325,
    ("broadcastChannel", 1.0, 5): 4.790000000000001,
    ("broadcastChannel", 0.9, 5): 3.948489818959241,
    ("recycling", 1.0, 4): 13.38,
    ("recycling", 0.9, 3): 9.764701250000002,
    ("GridSmall", 1.0, 3): 1.550444,
}


@pytest.mark.parametrize("name", ["dectiger", "broadcastChannel", "recycling"])
@pytest.mark.parametrize("gamma", [1.0, 0.9])
def test_gmaa_finds_the_exhaustive_optimum_at_horizon_2(name, gamma):
    e = problem(name, 2, gamma)
    optimum, _ = exhaustive_optimum(e, 2)
    found = gmaa_ice(e)
    assert found.finished and found.value == pytest.approx(optimum, abs=1e-9) and found.bound == found.value
    assert exact_value(e, found.controller).item() == pytest.approx(optimum, abs=1e-9)


@pytest.mark.parametrize("row", sorted(PUBLISHED))
def test_gmaa_proves_published_optima_and_its_controller_is_worth_its_value(row):
    name, gamma, h = row
    e = problem(name, h, gamma)
    found = gmaa_ice(e, heuristic="bg")
    assert found.finished and found.value == pytest.approx(PUBLISHED[row], rel=1e-6)
    assert exact_value(e, found.controller).item() == pytest.approx(found.value, abs=1e-9)
    pomdp = gmaa_ice(e, heuristic="pomdp")  # a looser heuristic, the same optimum
    assert pomdp.finished and pomdp.value == pytest.approx(found.value, abs=1e-9) and pomdp.expanded >= found.expanded


def test_an_interrupted_search_bounds_the_optimum_and_a_lower_bound_prunes():
    e = problem("dectiger", 6)
    cut = GMAA(e).run(time_budget=0.0)
    assert not cut.finished and cut.controller is None and cut.bound >= 10.381625 - 1e-9
    pruned = GMAA(e).run(lower_bound=10.381625)  # the optimum given: nothing beats it, and that is proven
    assert pruned.finished and pruned.controller is None and pruned.bound == pytest.approx(10.381625)


@pytest.mark.parametrize("name", ["dectiger", "broadcastChannel", "recycling", "GridSmall"])
def test_heuristics_are_ordered_and_q_pomdp_is_the_centralised_bound(name):
    e = problem(name, 3)
    bg, pomdp = Heuristic(e, "bg"), Heuristic(e, "pomdp")
    look, depth = lookahead_bound(e)
    assert depth == 3 and pomdp.root == pytest.approx(look, abs=1e-9)
    assert exhaustive_or_published(name) <= bg.root + 1e-9 <= pomdp.root + 2e-9
    beliefs = np.random.default_rng(0).dirichlet(np.ones(e.num_states), 5)  # beliefs off the tree: one backup
    assert np.all(bg.q(1, beliefs) <= pomdp.q(1, beliefs) + 1e-9)


def exhaustive_or_published(name):
    return {"dectiger": 5.1908125, "broadcastChannel": 2.99, "recycling": 10.660125, "GridSmall": 1.550444}[name]


def test_joint_rules_list_every_pair_of_own_rules():
    e = problem("broadcastChannel", 2)
    rules = joint_rules(e)
    assert rules.shape == ((e.num_actions**e.num_obs) ** 2, e.num_obs**2) and len({tuple(r) for r in rules}) == 16


def test_stage_bound_is_exact_once_the_first_agent_is_fixed_and_bounds_otherwise():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(3, 2, 2, 3))  # (types of 2 agents, their actions)

    def brute(fixed0, fixed1):
        best = -math.inf
        for r0 in itertools.product(*[[a] if a >= 0 else range(2) for a in fixed0]):
            for r1 in itertools.product(*[[a] if a >= 0 else range(3) for a in fixed1]):
                best = max(best, sum(q[i, j, r0[i], r1[j]] for i in range(3) for j in range(2)))
        return best

    full = [np.array([1, 0, 1]), np.array([-1, 2])]
    assert stage_bound(q, full) == pytest.approx(brute(*full))
    part = [np.array([1, -1, -1]), np.array([-1, -1])]
    assert stage_bound(q, part) >= brute(*part) - 1e-12


def test_cluster_merges_equal_conditionals_and_drops_impossible_types():
    prob = np.zeros((3, 2, 2))
    prob[0] = [[0.1, 0.2], [0.05, 0.05]]
    prob[1] = 2 * prob[0]  # the same conditional as type 0
    out, maps = cluster(prob, 2)  # type 2 has probability zero
    assert out.shape == (1, 2, 2) and out.sum() == pytest.approx(prob.sum())
    assert maps[0].tolist() == [0, 0, -1] and maps[1].tolist() == [0, 1]


def test_cyclic_building_blocks():
    action, nxt = every_controller(2, 3, 2)
    assert action.shape[0] == count_controllers(2, 3, 2) == 9 * 16
    assert len({(tuple(a.tolist()), tuple(x.flatten().tolist())) for a, x in zip(action, nxt)}) == 144
    one_action, one_next = neighbours(action[5], nxt[5], 3)
    assert one_action.shape[0] == 2 * 2 + 2 * 2 * 1  # two other actions per node, one other target per edge
    layered = JointController(torch.tensor([[[0, 1, 2]]]), torch.tensor([[[[1, 2], [2, 2], [2, 2]]]]))
    assert loop_back(layered).next_node[0, 0].tolist() == [[1, 2], [2, 2], [0, 0]]
    base = JointController(torch.zeros(1, 2, 2, dtype=torch.long), torch.zeros(1, 2, 2, 2, dtype=torch.long))
    joint = with_agent(base, 1, action[:4], nxt[:4])
    assert joint.num_controllers == 4 and torch.equal(joint.action[:, 1], action[:4])


def test_values_in_chunks_are_the_whole_batchs(monkeypatch):
    e = problem("recycling", gamma=0.9)
    base = JointController(torch.zeros(1, 2, 2, dtype=torch.long), torch.zeros(1, 2, 2, 2, dtype=torch.long))
    joint = with_agent(base, 0, *every_controller(2, e.num_actions, e.num_obs))  # 144 controllers
    whole = exact_value(e, joint, horizon=math.inf)
    monkeypatch.setattr(cyclic, "CHUNK", 25)  # 5 full chunks and a part
    assert torch.equal(cyclic._values(e, joint), whole)


def test_ascent_never_loses_value_and_reaches_a_best_response_among_small_controllers():
    e = problem("broadcastChannel", gamma=0.9)
    start = JointController(torch.zeros(1, 2, 2, dtype=torch.long), torch.zeros(1, 2, 2, 2, dtype=torch.long))
    v0 = exact_value(e, start).item()
    c, v, rounds = ascend(e, start, v0, num_nodes=2)
    assert v >= v0 and exact_value(e, c).item() == pytest.approx(v, abs=1e-9)
    action, nxt = every_controller(2, e.num_actions, e.num_obs)
    for agent in range(2):  # no 2-node controller of either agent does better against the other's
        assert exact_value(e, with_agent(c, agent, action, nxt), horizon=math.inf).max().item() <= v + 1e-9


def test_solve_proves_small_rows_and_its_infinite_horizon_is_seeded():
    s = solve("recycling", 3, 0.9, seed=0)
    assert (
        s.proven and s.value == pytest.approx(PUBLISHED[("recycling", 0.9, 3)], rel=1e-6) and s.restarts == 0
    )  # proven at once: no planner run
    kwargs = dict(seed=3, loop_horizons=(2, 3), ascent_starts=1, ascent_nodes=2)
    a, b = solve("broadcastChannel", math.inf, 0.9, **kwargs), solve("broadcastChannel", math.inf, 0.9, **kwargs)
    assert (
        a.value == b.value
        and a.values == b.values
        and a.value <= upper_bounds(problem("broadcastChannel", math.inf, 0.9)).best
    )
    assert not a.proven and a.value > 5.0


def test_errors_name_the_argument():
    with pytest.raises(ValueError, match="an infinite horizon needs at least one start"):
        solve("dectiger", math.inf, 0.9, loop_horizons=(), ascent_starts=0)
    with pytest.raises(ValueError, match="loop_horizons"):
        solve("dectiger", math.inf, 0.9, loop_horizons=(0,))
    with pytest.raises(ValueError, match="exact_seconds"):
        solve("dectiger", 2, exact_seconds=-1.0)
    with pytest.raises(ValueError, match="env: GMAA\\* needs a finite horizon"):
        GMAA(problem("dectiger", gamma=0.9))
    with pytest.raises(TypeError, match="env: expected a TabularDecPOSMDP"):
        GMAA("dectiger")
    with pytest.raises(ValueError, match="kind: expected 'bg' or 'pomdp'"):
        Heuristic(problem("dectiger", 2), "mdp")
