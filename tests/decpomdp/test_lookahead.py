"""Looking through information-gathering insertions: the fill of untraversed edges and the insertions against
brute force, novelty, no worsening under exact values, and the escape from delivering blind on disaster relief."""

import itertools

import pytest
import torch

from decpomdp import JointController, evaluate
from decpomdp.domains import DisasterRelief
from decpomdp.domains.disaster_relief.rules import ACTION_NAMES
from decpomdp.dpomdp import exact_value
from decpomdp.search import ExactScorer, PlannerConfig, RolloutScorer, lookahead
from hbni_infra.streams import torch_stream
from hbni_infra.threads import threads

from tiny_problems import dec_tiger


def look(ctrl, scorer, generator, **changes):
    """A lookahead step with the planner's default settings at a small scale, ``changes`` applied."""
    settings = dict(
        width=3,
        loss=0.15,
        screen_rollouts=256,
        max_chain=3,
        max_nodes=12,
        grow_nodes=4,
        candidates=200,
        stages=((2, 4),),
        duel_rollouts=2000,
        z=2.0,
        edge_rate=0.01,
        visit_rollouts=300,
        team=True,
        compose=True,
        copy=False,
        common=False,
    )
    return lookahead.step(ctrl, scorer, generator, **{**settings, **changes})


def test_fill_routes_untraversed_edges_of_visited_nodes_to_their_main_successor():
    action = torch.zeros(1, 1, 4, dtype=torch.long)
    next_node = torch.tensor([[[[1, 2, 0], [2, 2, 3], [0, 0, 0], [3, 1, 2]]]])
    visits = torch.tensor([[[0.5, 2.0, 0.0], [0.0, 1.0, 0.2], [0.3, 0.0, 0.0], [0.0, 0.0, 0.0]]])
    filled = lookahead.fill_untraversed(JointController(action, next_node), visits)
    expected = torch.tensor([[[[1, 2, 2], [2, 2, 3], [0, 0, 0], [3, 1, 2]]]])
    # node 0: traffic 0.5 to 1, 2.0 to 2 -> its unseen observation 2 goes to 2; node 1: 1.0 to 2 beats 0.2 to 3;
    # node 2 already sends everything to 0; node 3 is never visited and stays as it was
    assert torch.equal(filled.next_node, expected) and torch.equal(filled.action, action)


def test_insertions_are_every_edge_and_ma_once_per_owner():
    g = torch.Generator().manual_seed(0)
    a_count, nodes, o_count, m = 2, 5, 3, 4
    ctrl = JointController(
        torch.randint(0, m, (1, a_count, nodes), generator=g),
        torch.randint(0, 3, (1, a_count, nodes, o_count), generator=g),
    )
    visits = torch.rand(a_count, nodes, o_count, generator=g)
    visits[:, 3:] = 0  # nodes 3, 4 free
    visits[0, 1, 2] = 0.001  # below the edge rate for agent 0, not for the team (agent 1's edge is busy)
    visits[1, 1, 2] = 0.5
    moves = lookahead.insertions(ctrl, visits, m, edge_rate=0.01, team=True)
    got = {
        (tuple(moves.action[k].flatten().tolist()), tuple(moves.next_node[k].flatten().tolist()))
        for k in range(moves.num_controllers)
    }
    assert len(got) == moves.num_controllers
    expected = set()
    for group in ([0], [1], [0, 1]):
        for x, o, b in itertools.product(range(3), range(o_count), range(m)):
            if not any(float(visits[a, x, o]) >= 0.01 for a in group):
                continue
            act, nxt = ctrl.action[0].clone(), ctrl.next_node[0].clone()
            for a in group:
                target = int(nxt[a, x, o])
                nxt[a, x, o] = 3
                act[a, 3] = b
                nxt[a, 3, :] = target
            expected.add((tuple(act.flatten().tolist()), tuple(nxt.flatten().tolist())))
    assert got == expected


def test_novelty_counts_traffic_on_new_observations_of_used_nodes():
    env = dec_tiger(3)
    scorer = ExactScorer(env)
    ctrl = JointController(torch.zeros(1, 2, 3, dtype=torch.long), torch.zeros(1, 2, 3, 2, dtype=torch.long))
    g = torch.Generator().manual_seed(0)
    visits = scorer.visits(ctrl, 10, g)
    assert float(lookahead.novelty(scorer, ctrl, visits, 10, g)[0]) == 0.0
    moved = JointController(ctrl.action.clone(), ctrl.next_node.clone())
    moved.next_node[0, :, 0, 1] = 1  # node 1 is now reached: its edges are new traffic out of a node not used
    assert float(lookahead.novelty(scorer, moved, visits, 10, g)[0]) == 0.0  # node 1 was not used: not counted
    part = visits.clone()
    part[:, 0, 1] = 0  # pretend the incumbent never observed 1 in node 0
    assert float(lookahead.novelty(scorer, ctrl, part, 10, g)[0]) == pytest.approx(float(visits[:, 0, 1].sum()))


def test_a_lookahead_step_never_worsens_under_exact_values():
    env = dec_tiger(3)
    scorer = ExactScorer(env)
    g = torch.Generator().manual_seed(3)
    for _ in range(3):
        ctrl = JointController(
            torch.randint(0, 3, (1, 2, 4), generator=g), torch.randint(0, 4, (1, 2, 4, 2), generator=g)
        )
        out = look(ctrl, scorer, g, width=2, loss=0.5, screen_rollouts=2, max_chain=1, max_nodes=6, grow_nodes=1)
        before, after = exact_value(env, ctrl).item(), exact_value(env, out.controller).item()
        assert after >= before - 1e-12 and (after > before) == out.accepted


def test_a_lookahead_step_keeps_within_max_nodes():
    env = dec_tiger(3)
    scorer = ExactScorer(env)
    g = torch.Generator().manual_seed(0)
    ctrl = JointController(torch.tensor([[[0, 1], [0, 1]]]), torch.tensor([[[[1, 0], [0, 1]], [[1, 0], [0, 1]]]]))
    full = look(ctrl, scorer, g, max_nodes=2, screen_rollouts=2, edge_rate=0.0)
    assert full.controller is ctrl and not full.accepted and full.candidates == 0  # no free node, no room to grow
    for max_nodes in (3, 4):
        out = look(ctrl, scorer, g, max_nodes=max_nodes, grow_nodes=4, screen_rollouts=2, edge_rate=0.0)
        assert out.candidates > 0 and out.controller.num_nodes <= max_nodes


def test_a_lookahead_step_escapes_delivering_blind():
    # both robots pick up, drive to the crate zone, put down and return to Base1 without ever inferring: one
    # delivery in three is right, and inferring alone only costs time, so no single move improves much. Looking
    # through the insertion of an infer before the pick-up, a local-search step branches on what it reports.
    env = DisasterRelief()
    names = ["pick_up", "go_crate_zone", "put_down", "go_base1"]
    action = torch.tensor([ACTION_NAMES.index(n) for n in names]).expand(1, 2, 4).clone()
    next_node = torch.tensor([1, 2, 3, 0])[None, None, :, None].expand(1, 2, 4, env.num_obs).clone()
    blind = JointController(action, next_node)
    cfg = PlannerConfig()
    with threads(1):
        scorer = RolloutScorer(env)
        g = torch.Generator().manual_seed(0)
        out = look(blind, scorer, g, candidates=10000, stages=((16, 0.05), (128, 0.1), (1024, 6)), common=True)
        assert out.accepted
        inferring = [ACTION_NAMES.index("infer") in out.controller.action[0, a].tolist() for a in range(2)]
        (before, se0), (after, se1) = (
            (float(x) for x in evaluate(env, c, 4000, torch_stream(9, "reeval"))) for c in (blind, out.controller)
        )
    assert any(inferring)
    assert after - before > 5 * (se0**2 + se1**2) ** 0.5, (before, after)
    assert cfg.ls_lookahead > 0  # the planner's default looks through insertions
