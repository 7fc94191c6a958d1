"""Looking through an information-gathering move: the two-move step of a stalled local search.

Some improvements take two moves, and the first loses value alone. A robot team that delivers without looking
must first insert a look (an ``infer``) before it can branch on what it sees, and the look alone only costs
time, so single-move local search never accepts it and settles into delivering blind. When a local-search
phase stalls, :func:`step`:

1. routes every edge the incumbent never traverses, out of a node it visits, to where that node's traffic
   mostly goes (:func:`fill_untraversed`): a node then treats an observation it has never had as its usual one,
   and the incumbent's value is unchanged (up to edges too rare to show in ``visit_rollouts`` rollouts);
2. builds every *insertion* (:func:`insertions`): edge ``(x, o)`` redirected into a free node that runs MA ``b``
   and then goes on to the edge's old target whatever it observes, per agent and (with several agents) by all
   of them at once;
3. scores them with the incumbent on ``screen_rollouts`` common rollouts and keeps those that lose at most
   ``loss`` (a fraction of the incumbent's value);
4. ranks those by *novelty* (:func:`novelty`): the traffic per rollout on the (agent, node, observation)
   triples of the incumbent's visited nodes that the incumbent never traverses, that is how much new
   information the insertion brings to the nodes already in use;
5. takes one local-search step (:func:`decpomdp.search.local_search.step`) from each of the ``width`` most
   novel insertions, and duels the results against the incumbent: the best replaces it if it wins by more
   than ``z`` standard errors.
"""

from __future__ import annotations

import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.search import local_search
from decpomdp.search.local_search import StepOutcome
from decpomdp.search.moves import free_nodes, grow, make_room
from decpomdp.search.racing import duel
from decpomdp.search.scoring import Scorer


def fill_untraversed(controller: JointController, visits: Tensor) -> JointController:
    """``controller`` (K = 1) with every never-traversed edge out of a visited node routed to the node's most
    traversed successor. ``visits``: float (A, Nn, O) mean traversals per rollout."""
    next_node = controller.next_node.clone()
    nodes = controller.num_nodes
    for a in range(controller.num_agents):
        traffic = torch.zeros(nodes, nodes, dtype=torch.float64)  # (from, to)
        traffic.index_put_(
            (torch.arange(nodes)[:, None].expand(-1, controller.num_obs), next_node[0, a]),
            visits[a].to(torch.float64),
            accumulate=True,
        )
        used = visits[a].sum(-1) > 0
        unseen = (visits[a] == 0) & used[:, None]
        next_node[0, a] = torch.where(unseen, traffic.argmax(1)[:, None], next_node[0, a])
    return JointController(controller.action.clone(), next_node)


def insertions(
    controller: JointController, visits: Tensor, num_actions: int, edge_rate: float, team: bool
) -> JointController:
    """Every insertion (see the module doc) on an edge traversed at least ``edge_rate`` times per rollout, for
    ``controller`` (K = 1) with a free (never visited, not node 0) node in every agent's graph."""
    agents, o_count = controller.num_agents, controller.num_obs
    visited = visits.sum(-1) > 0
    visited[:, 0] = True
    free = [int((~visited[a]).nonzero()[0]) for a in range(agents)]
    owners = [[a] for a in range(agents)] + ([list(range(agents))] if agents > 1 and team else [])
    actions, next_nodes = [], []
    for group in owners:
        edges = ((visits[group] >= edge_rate) & visited[group][..., None]).any(0).nonzero()  # (E, 2)
        count = len(edges) * num_actions
        if count == 0:
            continue
        x = edges[:, 0].repeat_interleave(num_actions)
        o = edges[:, 1].repeat_interleave(num_actions)
        ma = torch.arange(num_actions).repeat(len(edges))
        action = controller.action.expand(count, -1, -1).clone()
        next_node = controller.next_node.expand(count, -1, -1, -1).clone()
        rows = torch.arange(count)
        for a in group:
            target = controller.next_node[0, a, x, o]
            next_node[rows, a, x, o] = free[a]
            action[rows, a, free[a]] = ma
            next_node[rows, a, free[a]] = target[:, None].expand(-1, o_count)
        actions.append(action)
        next_nodes.append(next_node)
    if not actions:
        return JointController.trusted(controller.action[:0], controller.next_node[:0])
    return JointController.trusted(torch.cat(actions), torch.cat(next_nodes))


def novelty(
    scorer: Scorer, candidates: JointController, visits: Tensor, rollouts: int, generator: torch.Generator
) -> Tensor:
    """float64 (K,): each candidate's traffic per rollout on (agent, node, observation) triples that the
    incumbent (``visits`` (A, Nn, O)) never traverses, out of the nodes it visits."""
    used = visits.sum(-1, keepdim=True) > 0
    new = (visits == 0) & used
    return torch.stack(
        [(scorer.visits(candidates[k], rollouts, generator) * new).sum() for k in range(candidates.num_controllers)]
    ).to(torch.float64)


def step(
    incumbent: JointController,
    scorer: Scorer,
    generator: torch.Generator,
    *,
    width: int,
    loss: float,
    screen_rollouts: int,
    max_nodes: int,
    duel_rollouts: int,
    z: float,
    edge_rate: float,
    visit_rollouts: int,
    team: bool,
    common: bool,
    **local: object,
) -> StepOutcome:
    """Look through the ``width`` most novel insertions that lose at most ``loss`` (see the module doc); none when
    an agent has no free node and the graph has ``max_nodes`` nodes. ``local`` holds the other settings of
    :func:`decpomdp.search.local_search.step`."""
    visits = scorer.visits(incumbent, visit_rollouts, generator)
    base, visits = make_room(fill_untraversed(incumbent, visits), visits, 1, max_nodes, 1)
    room = free_nodes(visits) > 0  # else no free node, and no room to grow one
    moves = insertions(base, visits, scorer.num_actions, edge_rate, team) if room else None
    if moves is None or moves.num_controllers == 0:
        return StepOutcome(incumbent, False, float("nan"), float("nan"), 0, 0)
    pool = JointController.cat([base, moves])
    kwargs = {"common": True} if common else {}
    mean = scorer(pool, screen_rollouts, generator, **kwargs)[0]
    floor = float(mean[0]) - loss * abs(float(mean[0]))
    kept = (mean[1:] >= floor).nonzero().squeeze(1)
    if kept.numel() == 0:
        return StepOutcome(incumbent, False, float(mean[0]), float(mean[1:].max()), moves.num_controllers, 0)
    rank = novelty(scorer, moves[kept], visits, visit_rollouts, generator)
    chosen = kept[torch.sort(rank, descending=True, stable=True).indices[:width]]
    results = []
    for k in chosen.tolist():
        out = local_search.step(
            moves[k],
            scorer,
            generator,
            max_nodes=max_nodes,
            duel_rollouts=duel_rollouts,
            z=z,
            edge_rate=edge_rate,
            visit_rollouts=visit_rollouts,
            team=team,
            common=common,
            **local,
        )
        results.append(out.controller)
    nodes = max(c.num_nodes for c in [base, *results])
    pad = lambda c: grow(c, nodes - c.num_nodes) if c.num_nodes < nodes else c  # noqa: E731
    challengers = JointController.cat([pad(c) for c in results])
    winner, mean, _ = duel(scorer, pad(base), challengers, duel_rollouts, z, generator, common)
    controller = incumbent if winner is None else results[winner]
    return StepOutcome(
        controller, winner is not None, float(mean[0]), float(mean[1:].max()), moves.num_controllers, len(kept)
    )
