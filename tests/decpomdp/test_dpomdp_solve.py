"""``decpomdp.solve`` and its parts: upper bounds against exhaustive optima and independent
recursions, exact best responses against exhaustive search, solutions at published optima, the
writer's round trip, and errors."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from decpomdp import random_controllers, solve
from decpomdp.dpomdp import (
    controller_text,
    dpomdp_text,
    exact_value,
    load_dpomdp,
    load_problem,
    parse_dpomdp,
    problem_names,
    save_dpomdp,
    upper_bounds,
)
from decpomdp.dpomdp.best_response import _distinct_beliefs, best_response, jesp
from decpomdp.dpomdp.bounds import lookahead_bound, q_fib, q_mdp
from decpomdp.dpomdp.exhaustive import exhaustive_optimum, tree_controllers
from dpomdp_synthetic import synthetic_text
from tiny_problems import problem

SMALL = ["dectiger", "broadcastChannel", "recycling", "GridSmall"]
PUBLISHED = {  # MADP toolbox, src/tests/optimalValueDatabase (undiscounted)
    ("dectiger", 3): 5.190812499999996,
    ("dectiger", 4): 4.802755156249994,
    ("broadcastChannel", 4): 3.89,
    ("recycling", 3): 10.660125,
    ("recycling", 4): 13.38,
    ("GridSmall", 3): 1.550444,
}


@pytest.mark.parametrize("name", SMALL)
def test_bounds_hold_the_exhaustive_optimum_and_are_ordered(name):
    e = problem(name, 2)
    optimum, _ = exhaustive_optimum(e, 2)
    b = upper_bounds(e)
    assert b.depth == 2 and optimum <= b.lookahead + 1e-9  # the belief tree is the whole horizon: exact V_POMDP
    assert b.lookahead <= b.fib + 1e-9 <= b.q_mdp + 2e-9 and b.best == b.lookahead


TABLE = yaml.safe_load((Path(__file__).resolve().parents[2] / "conf/experiment/dpomdp_benchmarks.yaml").read_text())
OPTIMA = {  # every finite-horizon row of the benchmark table with a published optimum
    name: row
    for name, row in TABLE["study"]["rows"].items()
    if row["optimum"] is not None and row["horizon"] is not None
}


PUBLISHED_ROUNDING = 5e-4
"""Relative rounding of a published optimum: oneDoor's h3 optimum is published as -0.000395, 1.6e-4 of it above the
exact -0.00039506 (the other values carry more digits)."""


@pytest.mark.parametrize("name", sorted(OPTIMA))
def test_bounds_hold_every_published_optimum(name):
    row = OPTIMA[name]
    bound = upper_bounds(problem(row["problem"], row["horizon"], row["gamma"])).best
    assert bound >= row["optimum"] - PUBLISHED_ROUNDING * abs(row["optimum"]) - 1e-9


def _dense(e):
    t = e.model.transition.toarray()  # (JA, S, S')
    return t, e.expected_reward.numpy(), e.observation.numpy(), e.start_dist.numpy()


def test_q_mdp_and_fib_against_dense_recursions():
    e = problem("GridSmall", 4, 0.9)
    t, r, o, _ = _dense(e)
    q = r.copy()
    for _ in range(3):
        q = r + 0.9 * np.einsum("ast,t->as", t, q.max(0))
    np.testing.assert_allclose(q_mdp(e), q, rtol=0, atol=1e-12)
    f = r.copy()
    for _ in range(3):  # sum_o max_a' sum_s' T(s'|s,a) O(o|a,s') Q(a', s')
        f = r + 0.9 * np.einsum("asto,bt->asob", t[..., None] * o[:, None], f).max(-1).sum(-1)
    np.testing.assert_allclose(q_fib(e), f, rtol=0, atol=1e-12)


def _pomdp_value(t, r, o, belief, steps, gamma):
    """The centralised POMDP's optimum by plain recursion over normalised beliefs."""
    if steps == 0:
        return 0.0
    best = -math.inf
    for a in range(r.shape[0]):
        value = belief @ r[a]
        pred = belief @ t[a]
        for jo in range(o.shape[2]):
            joint = pred * o[a, :, jo]
            mass = joint.sum()
            if mass > 0:
                value += gamma * mass * _pomdp_value(t, r, o, joint / mass, steps - 1, gamma)
        best = max(best, value)
    return best


@pytest.mark.parametrize("name, horizon", [("dectiger", 3), ("broadcastChannel", 3), ("recycling", 2)])
def test_the_belief_tree_is_the_centralised_pomdp(name, horizon):
    e = problem(name, horizon)
    t, r, o, b0 = _dense(e)
    value, depth = lookahead_bound(e)
    assert depth == horizon
    assert value == pytest.approx(_pomdp_value(t, r, o, b0, horizon, 1.0), abs=1e-10)


def test_infinite_horizon_bounds_hold_every_controller():
    e = problem("dectiger", math.inf, 0.9)
    b = upper_bounds(e)
    ctrl = random_controllers(
        200, num_agents=2, num_nodes=3, num_actions=3, num_obs=2, generator=torch.Generator().manual_seed(0)
    )
    assert float(exact_value(e, ctrl).max()) <= b.best and b.lookahead <= b.fib + 1e-9 <= b.q_mdp + 2e-9


@pytest.mark.parametrize("name", ["dectiger", "broadcastChannel"])
def test_a_best_response_is_the_best_policy_tree_against_the_other(name):
    """Against a fixed controller of agent 1, the best response's value is the max over every policy tree of agent 0."""
    e = problem(name, 2)
    other = random_controllers(
        1,
        num_agents=2,
        num_nodes=2,
        num_actions=e.num_actions,
        num_obs=e.num_obs,
        generator=torch.Generator().manual_seed(3),
    )
    response, value = best_response(e, other, 0)
    assert float(exact_value(e, response)[0]) == pytest.approx(value, abs=1e-12)
    trees = tree_controllers(2, e.num_actions, e.num_obs, 2)
    mine = trees.action[:, 0].unique(dim=0)  # every tree of agent 0 (3 nodes)
    pad = other.num_nodes - 3 if other.num_nodes > 3 else 0
    a = torch.nn.functional.pad(mine, (0, pad))
    n = torch.nn.functional.pad(trees.next_node[: len(mine), 0], (0, 0, 0, pad))
    nodes = max(3, other.num_nodes)
    k = len(mine)
    act = torch.zeros(k, 2, nodes, dtype=torch.long)
    nxt = torch.zeros(k, 2, nodes, e.num_obs, dtype=torch.long)
    act[:, 0], nxt[:, 0] = a, n
    act[:, 1, : other.num_nodes], nxt[:, 1, : other.num_nodes] = other.action[0, 1], other.next_node[0, 1]
    from decpomdp import JointController

    assert value == pytest.approx(float(exact_value(e, JointController(act, nxt)).max()), abs=1e-12)


@pytest.mark.parametrize(
    "name, nodes, agent", [("dectiger", 3, 0), ("dectiger", 3, 1), ("broadcastChannel", 4, 0), ("GridSmall", 2, 0)]
)
def test_a_best_response_beats_every_depth_3_policy_tree(name, nodes, agent):
    """At horizon 3 (where merged beliefs matter), the response's value is the max over every policy tree of the
    agent (7 nodes: one per observation history) against a fixed random controller of the other."""
    import itertools

    from decpomdp import JointController

    e = problem(name, 3)
    other = random_controllers(
        1,
        num_agents=2,
        num_nodes=nodes,
        num_actions=e.num_actions,
        num_obs=2,
        generator=torch.Generator().manual_seed(5),
    )
    response, value = best_response(e, other, agent)
    assert float(exact_value(e, response)[0]) == pytest.approx(value, abs=1e-12)
    width = max(7, nodes)
    trees = torch.tensor(list(itertools.product(range(e.num_actions), repeat=7)))
    act = torch.zeros(len(trees), 2, width, dtype=torch.long)
    nxt = torch.zeros(len(trees), 2, width, 2, dtype=torch.long)
    act[:, agent, :7] = trees
    nxt[:, agent, :3] = torch.tensor([[1, 2], [3, 4], [5, 6]])
    fixed = 1 - agent
    act[:, fixed, :nodes], nxt[:, fixed, :nodes] = other.action[0, fixed], other.next_node[0, fixed]
    best = float(exact_value(e, JointController(act, nxt)).max())
    assert value == pytest.approx(best, abs=1e-9)


def test_beliefs_merge_when_equal_and_a_projection_collision_is_caught():
    """Rows of one belief (at any mass, or 1e-13 apart) merge; beliefs 1e-6 apart do not; two beliefs whose first
    projection is equal (their difference is orthogonal to its weights) are told apart by the second."""
    rng = np.random.default_rng(1)
    base = rng.dirichlet(np.ones(6))
    w0 = np.random.default_rng(0).uniform(1.0, 2.0, (6, 3))[:, 0]  # the first projection's weights
    hidden = np.zeros(6)
    hidden[:3] = np.cross(w0[:3], np.ones(3)) * 1e-4  # sums to 0 and w0 . hidden = 0
    rows = np.stack([base, 3 * base, base + 1e-13 * np.eye(6)[0], base + 1e-6 * (np.eye(6)[1] - np.eye(6)[2])])
    rows = np.concatenate([rows, (base + hidden)[None]])
    first, inverse = _distinct_beliefs(rows, rows.sum(1))
    assert inverse[0] == inverse[1] == inverse[2] and len({inverse[0], inverse[3], inverse[4]}) == 3
    assert first.size == 3 and (inverse[first] == np.arange(3)).all()


def test_jesp_never_loses_value_and_refuses_trees_too_large():
    e = problem("GridSmall", 3)
    start = random_controllers(
        1, num_agents=2, num_nodes=3, num_actions=5, num_obs=2, generator=torch.Generator().manual_seed(1)
    )
    v0 = float(exact_value(e, start)[0])
    ctrl, value, accepted = jesp(e, start, v0)
    assert value >= v0 and accepted >= 1 and float(exact_value(e, ctrl)[0]) == pytest.approx(value, abs=1e-12)
    assert best_response(e, start, 0, max_entries=10) is None


@pytest.mark.parametrize("row", [("dectiger", 3), ("broadcastChannel", 4), ("GridSmall", 3)])
def test_solve_reaches_published_optima_with_a_valid_gap(row):
    s = solve(*row, 1.0, seed=0, restarts=1, layered_restarts=1)
    assert s.value == pytest.approx(PUBLISHED[row], abs=1e-6)
    assert s.value == pytest.approx(float(exact_value(problem(*row), s.controller)[0]), abs=1e-12)
    assert s.bound >= PUBLISHED[row] - 1e-9 and s.gap == pytest.approx((s.bound - s.value) / abs(s.bound))
    assert s.controller.action_names is not None and s.horizon == row[1] and s.seconds > 0


def test_solve_is_seeded_and_takes_files_models_and_the_infinite_horizon(tmp_path):
    a, b = (
        solve("dectiger", 2, seed=4, restarts=1, layered_restarts=1, jesp_restarts=2),
        solve("dectiger", 2, seed=4, restarts=1, layered_restarts=1, jesp_restarts=2),
    )
    assert torch.equal(a.controller.action, b.controller.action) and a.values == b.values
    path = save_dpomdp(load_problem("dectiger"), tmp_path / "tiger.dpomdp")
    assert solve(path, 2, seed=4, restarts=1, layered_restarts=1, jesp_restarts=2).value == a.value
    inf = solve(  # the planner alone: no loop-backs, no coordinate ascent
        load_problem("dectiger"),
        math.inf,
        0.9,
        seed=0,
        restarts=1,
        num_nodes=2,
        ce_iterations=5,
        loop_horizons=(),
        ascent_starts=0,
    )
    assert inf.horizon == math.inf and inf.controller.num_nodes == 2 and inf.value <= inf.bound


def test_without_best_responses_solve_keeps_the_planners_results_alone():
    s = solve("dectiger", 3, seed=0, restarts=1, layered_restarts=1, best_responses=False, exact_seconds=0)
    assert len(s.values) == 2  # one free-graph run and one layered run, no JESP restarts
    with_br = solve("dectiger", 3, seed=0, restarts=1, layered_restarts=1, jesp_restarts=0)
    assert with_br.value >= s.value - 1e-12


def test_free_and_layered_runs_are_counted_apart():
    more_layered = solve(
        "dectiger", 3, seed=0, restarts=1, layered_restarts=3, best_responses=False, ce_iterations=10, exact_seconds=0
    )
    assert more_layered.restarts == 3 and len(more_layered.values) == 1 + 3
    no_layers = solve(
        "dectiger", 3, seed=0, restarts=2, layered_restarts=0, best_responses=False, ce_iterations=10, exact_seconds=0
    )
    assert no_layers.restarts == 2 and len(no_layers.values) == 2
    # the first free run and the first layered run are the same whatever the counts
    assert (
        more_layered.values[:2]
        == solve(
            "dectiger",
            3,
            seed=0,
            restarts=1,
            layered_restarts=1,
            best_responses=False,
            ce_iterations=10,
            exact_seconds=0,
        ).values
    )
    assert no_layers.values[0] == more_layered.values[0]


def test_exact_scores_are_never_raced():
    """Under exact scores every candidate is scored once; the racing stages only cut the ranking, and the
    survivors are those of a scorer that scores them again at every stage."""
    from decpomdp.search import ExactScorer
    from decpomdp.search.racing import race

    tiger = problem("dectiger", 3)
    pool = random_controllers(
        30,
        num_agents=2,
        num_nodes=3,
        num_actions=tiger.num_actions,
        num_obs=tiger.num_obs,
        generator=torch.Generator().manual_seed(0),
    )

    class Counting(ExactScorer):
        def __init__(self, *args, exact):
            super().__init__(*args)
            self.exact, self.scored = exact, 0

        def __call__(self, controller, rollouts, generator):
            self.scored += controller.num_controllers
            return super().__call__(controller, rollouts, generator)

    stages = [(10, 0.5), (100, 0.5), (1000, 3)]
    once, again = Counting(tiger, exact=True), Counting(tiger, exact=False)
    a = race(once, 30, lambda i: pool[i], stages, torch.Generator())
    b = race(again, 30, lambda i: pool[i], stages, torch.Generator())
    assert once.scored == 30 and again.scored == 30 + 15 + 8
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])


def test_exact_ties_in_the_last_bits_lose_duels():
    """Two equally good controllers whose exact values differ by float64 rounding: the challenger must not win,
    or local search on exact scores accepts such moves forever (GridSmall h3 did, seen at 1.5493439999999996
    against 1.549344)."""
    from decpomdp.search.racing import duel

    class Rounding:
        exact = True

        def __call__(self, controller, rollouts, generator):
            mean = torch.tensor(
                [1.5493439999999996] + [1.549344] * (controller.num_controllers - 1), dtype=torch.float64
            )
            return mean, torch.zeros_like(mean)

    pool = random_controllers(
        3, num_agents=2, num_nodes=2, num_actions=3, num_obs=2, generator=torch.Generator().manual_seed(0)
    )
    assert duel(Rounding(), pool[:1], pool[1:], 1, 2.0, torch.Generator())[0] is None
    s = solve("GridSmall", 3, 1.0, seed=0, restarts=1, layered_restarts=1, jesp_restarts=0)  # ends (it looped before)
    assert s.value == pytest.approx(PUBLISHED[("GridSmall", 3)], abs=1e-6)


def test_solve_errors():
    with pytest.raises(TypeError, match="problem: expected a shipped problem's name"):
        solve(3, 2)
    with pytest.raises(FileNotFoundError, match="no such file"):
        solve("no_such_problem.dpomdp", 2)
    with pytest.raises(FileNotFoundError, match="the shipped problems are .*dectiger"):
        solve("dectigr", 3)  # a misspelt name lists the shipped ones
    with pytest.raises(ValueError, match="restarts: expected an int >= 1"):
        solve("dectiger", 2, restarts=0)
    with pytest.raises(ValueError, match="layered_restarts: expected an int >= 0"):
        solve("dectiger", 2, layered_restarts=-1)
    with pytest.raises(TypeError, match="best_responses: expected True or False"):
        solve("dectiger", 2, best_responses="no")
    with pytest.raises(ValueError, match="time_budget"):
        solve("dectiger", 2, time_budget=-1.0)
    with pytest.raises(ValueError, match="horizon: an infinite horizon needs gamma < 1"):
        solve("dectiger", math.inf, 1.0)


@pytest.mark.parametrize("name", [n for n in problem_names() if n != "example"])
def test_a_written_problem_reads_back_the_same(name, tmp_path):
    m = load_problem(name)
    back = load_dpomdp(save_dpomdp(m, tmp_path / f"{name}.dpomdp.gz"))
    _same(m, back)


@pytest.mark.parametrize("seed", range(6))
def test_a_written_synthetic_problem_reads_back_the_same(seed):
    m = parse_dpomdp(synthetic_text(seed), check_probabilities=False)
    _same(m, parse_dpomdp(dpomdp_text(m), check_probabilities=False))


def _same(m, back):
    for k in ("indptr", "indices", "data"):
        assert np.array_equal(getattr(m.transition, k), getattr(back.transition, k)), k
    for k in ("observation", "reward", "start"):
        assert np.array_equal(getattr(m, k), getattr(back, k)), k
    assert (m.agent_names, m.state_names, m.action_names, m.obs_names, m.discount) == (
        back.agent_names,
        back.state_names,
        back.action_names,
        back.obs_names,
        back.discount,
    )


def test_controller_text_lists_every_node():
    s = solve("dectiger", 2, seed=0, restarts=1, layered_restarts=1, jesp_restarts=1)
    text = controller_text(s.controller)
    assert text.count("\nagent ") + text.startswith("agent ") == 2
    assert "listen" in text and len(text.strip().splitlines()) == 2 + 2 * (1 + s.controller.num_nodes)
    with pytest.raises(TypeError, match="controller: expected a JointController"):
        controller_text("x")
    with pytest.raises(TypeError, match="model: expected a DPOMDPModel"):
        dpomdp_text("x")


def test_infinite_horizon_node_budget_keeps_the_joint_system_small():
    """The default infinite-horizon budget: the most nodes from 4 to 8 with ``nodes ** agents * states <= 256``."""
    from decpomdp.solver import infinite_nodes

    cases = {(2, 2): 8, (2, 4): 8, (2, 5): 7, (2, 16): 4, (2, 2025): 4, (3, 2): 5, (1, 3): 8}
    for (agents, states), nodes in cases.items():
        assert infinite_nodes(agents, states) == nodes, (agents, states)
