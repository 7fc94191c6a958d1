"""The local-search neighbourhood of a controller: single edits and chain insertions, enumerated or sampled.

For searched controllers (K = 1, A agents, Nn nodes) and their visit counts (A, Nn, O) (mean traversals
per rollout, :meth:`~decpomdp.search.scoring.Scorer.visits`), the moves are

* **action edits**: a visited node ``x`` (or node 0) runs another MA;
* **edge edits**: after observing ``o`` in node ``x``, the agent moves to another visited node;
* **agent copies** (with several agents): agent ``b``'s whole graph becomes a copy of agent ``a``'s, so
  a behaviour one robot has learnt reaches a robot stuck elsewhere in one move;
* **chain insertions** of length ``l <= max_chain``: the edge ``(x, o)`` is redirected into ``l`` free
  (never visited) nodes ``u_1 .. u_l`` with MAs ``b_1 .. b_l``; ``u_j`` moves to ``u_{j+1}`` whatever
  it observes and ``u_l`` moves to an exit node, any visited node. A chain adds a whole behaviour
  ("pick up, go to Dest1, put down, go home") in one move, where single edits would each have to pay
  off alone.

Each move is made either by one agent or, with several agents, by all of them at once (a *team*
move: the same node, edge and MAs in every agent's graph, each agent using its own free nodes):
robots that must act together (open the door together in Dec-Tiger, lift a package together) gain
nothing from a change of one of them alone. A team move's nodes and edges are those visited by any
agent. Only edges traversed at least ``edge_rate`` times per rollout are edited: an edge never taken
cannot change the value.

Moves are indexed ``0 .. size - 1`` (single edits first, then chains site by site) and built on demand
by :meth:`Neighbourhood.build`, so a neighbourhood of millions of chains costs no memory until it is
sampled.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from decpomdp.controller import JointController

_TEAM = -1  # owner of a move made by every agent


class Neighbourhood:
    """All moves around ``controller`` (see the module doc).

    Args:
        controller: the incumbent (K = 1, A, Nn, O).
        visits: float (A, Nn, O), mean traversals per rollout of each edge.
        num_actions: |MA|.
        max_chain: longest chain insertion (0 disables chains).
        edge_rate: least traversals per rollout for an edge to be edited.
        team: include team moves (every agent at once; only with several agents).
        copy: include agent copies (only with several agents).

    Attributes:
        singles: long (S, 5) rows ``(kind, owner, node, obs, value)``: kind 0 sets node's MA to value,
            kind 1 sets edge (node, obs) to value, kind 2 copies agent ``value``'s graph onto agent
            ``owner`` (node and obs -1); owner is an agent or -1 (every agent).
        sites: long (E, 3) rows ``(owner, node, obs)``, the edges chains are inserted on.
        size: number of moves.
    """

    def __init__(
        self,
        controller: JointController,
        visits: Tensor,
        num_actions: int,
        max_chain: int,
        edge_rate: float,
        team: bool = True,
        copy: bool = False,
    ) -> None:
        self.controller, self.m, self.max_chain = controller[0], num_actions, max_chain
        agents = controller.num_agents
        visited = visits.sum(-1) > 0
        visited[:, 0] = True
        edges = (visits >= edge_rate) & visited[..., None]
        owners = list(range(agents)) + ([_TEAM] if agents > 1 and team else [])
        # per owner: visited nodes, edited edges, free nodes of each agent it moves
        self.visited = {o: visited[o] if o != _TEAM else visited.any(0) for o in owners}
        self.edited = {o: edges[o] if o != _TEAM else edges.any(0) for o in owners}
        self.free = [(~visited[a]).nonzero().squeeze(1) for a in range(agents)]
        self.singles = torch.cat([self._singles(o) for o in owners] + ([self._copies()] if copy else []))
        self.sites = torch.cat(
            [torch.cat([torch.full((int(self.edited[o].sum()), 1), o), self.edited[o].nonzero()], 1) for o in owners]
        )
        rate = torch.cat([(visits[o] if o != _TEAM else visits.sum(0))[self.edited[o]] for o in owners])
        self.site_rate = rate.to(torch.float64)
        lengths = torch.arange(1, max_chain + 1)
        per_length = torch.zeros(len(self.sites), max_chain, dtype=torch.long)
        for o in owners:
            free = min(len(self.free[a]) for a in self._agents(o))
            exits = int(self.visited[o].sum())
            per_length[self.sites[:, 0] == o] = num_actions**lengths * exits * (lengths <= free)
        self.per_length = per_length
        self.site_end = per_length.sum(1).cumsum(0)
        self.num_singles = len(self.singles)
        self.size = self.num_singles + (int(self.site_end[-1]) if len(self.sites) else 0)

    def sample_chains(self, count: int, generator: torch.Generator) -> Tensor:
        """``count`` chain moves (indices in [num_singles, size)): a site with probability proportional to how
        often its edge is traversed, a chain length uniform among those the site allows, then a chain of
        that length uniformly (MAs and exit)."""
        if self.size == self.num_singles or count <= 0:
            return torch.zeros(0, dtype=torch.long)
        site = torch.multinomial(
            self.site_rate * (self.per_length.sum(1) > 0), count, replacement=True, generator=generator
        )
        lengths = self.per_length[site]  # (C, L)
        length = torch.multinomial((lengths > 0).to(torch.float64), 1, generator=generator).squeeze(1)
        size = lengths.gather(1, length[:, None]).squeeze(1)
        within = (torch.rand(count, generator=generator, dtype=torch.float64) * size).long().clamp_(max=size - 1)
        starts = torch.cat([torch.zeros(count, 1, dtype=torch.long), lengths.cumsum(1)], 1).gather(1, length[:, None])
        site_start = torch.cat([torch.zeros(1, dtype=torch.long), self.site_end])[site]
        return self.num_singles + site_start + starts.squeeze(1) + within

    @property
    def free_nodes(self) -> int:
        """The fewest free nodes any agent has."""
        return min(len(f) for f in self.free)

    def _agents(self, owner: int) -> list[int]:
        return list(range(self.controller.num_agents)) if owner == _TEAM else [owner]

    def _singles(self, owner: int) -> Tensor:
        """Action and edge edits of ``owner`` that change every one of its agents' graphs (a team edit that
        leaves some agent unchanged is another owner's edit)."""
        agents = self._agents(owner)
        act, nxt = self.controller.action[0, agents], self.controller.next_node[0, agents]  # (a, Nn), (a, Nn, O)
        node, ma = torch.cartesian_prod(self.visited[owner].nonzero().squeeze(1), torch.arange(self.m)).T
        keep = (act[:, node] != ma).all(0)
        acts = torch.stack(
            [torch.zeros_like(node), torch.full_like(node, owner), node, torch.full_like(node, -1), ma], 1
        )
        edge = self.edited[owner].nonzero()  # (E, 2)
        targets = self.visited[owner].nonzero().squeeze(1)
        e, y = torch.cartesian_prod(torch.arange(len(edge)), targets).T
        x, o = edge[e].T
        differs = (nxt[:, x, o] != y).all(0)
        edits = torch.stack([torch.ones_like(x), torch.full_like(x, owner), x, o, y], 1)
        return torch.cat([acts[keep], edits[differs]])

    def _copies(self) -> Tensor:
        """Copy moves ``(2, b, -1, -1, a)`` for every ordered pair of agents whose graphs differ."""
        ctrl = self.controller
        pairs = [
            (b, a)
            for b in range(ctrl.num_agents)
            for a in range(ctrl.num_agents)
            if a != b
            and not (
                torch.equal(ctrl.action[0, a], ctrl.action[0, b])
                and torch.equal(ctrl.next_node[0, a], ctrl.next_node[0, b])
            )
        ]
        return torch.tensor([(2, b, -1, -1, a) for b, a in pairs], dtype=torch.long).view(-1, 5)

    def build(self, index: Tensor) -> JointController:
        """The controllers of moves ``index`` (long (C,), values in [0, size))."""
        c = index.numel()
        # copied by numpy, whose allocator asks for huge pages: 8000 controllers' tables (46 MB) took 21 ms to
        # write through torch's, 5 ms through numpy's
        action = torch.from_numpy(np.repeat(self.controller.action.numpy(), c, 0))
        next_node = torch.from_numpy(np.repeat(self.controller.next_node.numpy(), c, 0))
        single = index < self.num_singles
        if bool(single.any()):
            rows = single.nonzero().squeeze(1)
            kind, owner, x, o, v = self.singles[index[rows]].T
            for a in range(self.controller.num_agents):
                mine = (owner == a) | (owner == _TEAM)
                act, edge = mine & (kind == 0), mine & (kind == 1)
                action[rows[act], a, x[act]] = v[act]
                next_node[rows[edge], a, x[edge], o[edge]] = v[edge]
                copied = (owner == a) & (kind == 2)
                action[rows[copied], a] = self.controller.action[0, v[copied]]
                next_node[rows[copied], a] = self.controller.next_node[0, v[copied]]
        if bool((~single).any()):
            rows = (~single).nonzero().squeeze(1)
            self._chains(action, next_node, rows, index[rows] - self.num_singles)
        return JointController.trusted(action, next_node)

    def _chains(self, action: Tensor, next_node: Tensor, rows: Tensor, flat: Tensor) -> None:
        """Write chain moves ``flat`` (indices among the chains) into candidate rows ``rows``."""
        site = torch.searchsorted(self.site_end, flat, right=True)
        within = flat - torch.cat([torch.zeros(1, dtype=torch.long), self.site_end])[site]
        ends = self.per_length[site].cumsum(1)  # (C, L)
        length = (within[:, None] >= ends).sum(1) + 1
        starts = torch.cat([torch.zeros(len(site), 1, dtype=torch.long), ends], 1)
        within = within - starts.gather(1, (length - 1)[:, None]).squeeze(1)
        owner, x, o = self.sites[site].T
        for who in owner.unique().tolist():
            exits = self.visited[who].nonzero().squeeze(1)
            for size in range(1, self.max_chain + 1):
                pick = (owner == who) & (length == size)
                if not bool(pick.any()):
                    continue
                r, w = rows[pick], within[pick]
                exit_node = exits[w % len(exits)]
                combo = w // len(exits)
                mas = [(combo // self.m**j) % self.m for j in range(size)]
                for a in self._agents(who):
                    free = self.free[a]
                    next_node[r, a, x[pick], o[pick]] = free[0]
                    for j in range(size):
                        action[r, a, free[j]] = mas[j]
                        next_node[r, a, free[j], :] = free[j + 1] if j + 1 < size else exit_node[:, None]


def grow(controller: JointController, extra: int) -> JointController:
    """``controller`` with ``extra`` more nodes per agent, unreachable (MA 0, every edge to node 0)."""
    k, a, nn = controller.action.shape
    o = controller.num_obs
    action = torch.cat([controller.action, torch.zeros(k, a, extra, dtype=torch.long)], 2)
    next_node = torch.cat([controller.next_node, torch.zeros(k, a, extra, o, dtype=torch.long)], 2)
    return JointController(action, next_node)


def free_nodes(visits: Tensor) -> int:
    """The fewest free (never visited, not node 0) nodes any agent has, from visits (A, Nn, O)."""
    return int((visits.sum(-1) == 0)[:, 1:].sum(1).min())


def make_room(
    controller: JointController, visits: Tensor, needed: int, max_nodes: int, extra: int
) -> tuple[JointController, Tensor]:
    """``controller`` (K = 1) and its visits (A, Nn, O) with ``extra`` more unreachable nodes (up to ``max_nodes``)
    if some agent has fewer than ``needed`` free (never visited, not node 0) nodes; else both unchanged."""
    if free_nodes(visits) < needed and controller.num_nodes < max_nodes and extra > 0:
        extra = min(extra, max_nodes - controller.num_nodes)
        controller = grow(controller, extra)
        visits = torch.cat([visits, visits.new_zeros(visits.shape[0], extra, visits.shape[2])], 1)
    return controller, visits
