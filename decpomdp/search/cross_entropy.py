"""One cross-entropy iteration over controller graphs (G-DICE's update) with racing and elite memory.

The search distribution is G-DICE's: a categorical over each node's MA, ``action_probs`` (A, Nn, |MA|),
and over each (node, observation)'s next node, ``next_probs`` (A, Nn, O, Nn). A phase starts from
``(1 - w) * uniform + w * one_hot(incumbent)`` (``w = 0``: a cold start). A *reactive* phase ties the
edges: an agent's next node depends on its last observation only, whatever node it is in, so
``next_probs`` is (A, O, Nn) and a sample's edges out of every node are the same; the graph is then a
reactive policy (observation -> node -> MA), the shape of a hand-written rule set, and each of the
O x Nn + Nn x |MA| entries is learnt from every elite rather than from the few that visit one node.
Each iteration

1. samples ``samples`` controllers and races them (:func:`~decpomdp.search.racing.race`): all on
   ``screen_rollouts`` rollouts, the best ``screen_keep`` fraction again on ``rollouts`` fresh ones
   (``screen_rollouts = 0``: every sample on ``rollouts``, as in G-DICE);
2. re-scores the elite memory (the best ``memory`` controllers of the previous iteration) on
   ``rollouts`` fresh rollouts, so a controller once lucky is not kept on its old score;
3. takes the best ``elites`` of samples and memory, and sets each distribution to
   ``alpha * frequency in the elites + (1 - alpha) * old``; the first ``memory`` elites (best first)
   are the next iteration's memory.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.gdice import elite_frequencies, sample_controllers
from decpomdp.search.racing import race
from decpomdp.search.scoring import Scorer


@dataclass
class CrossEntropyState:
    """The distributions and elite memory of a cross-entropy phase.

    Attributes:
        action_probs: float64 (A, Nn, |MA|); next_probs: float64 (A, Nn, O, Nn), or (A, O, Nn) when the
            edges are tied (a reactive phase).
        elites: the last iteration's elites, best first (None before the first iteration); the first
            ``memory`` of them are the elite memory.
    """

    action_probs: Tensor
    next_probs: Tensor
    elites: JointController | None = None

    @property
    def reactive(self) -> bool:
        """Whether the edges are tied across nodes (next node a function of the observation only)."""
        return self.next_probs.dim() == 3

    def sample(self, count: int, generator: torch.Generator) -> JointController:
        """``count`` controllers from the distributions."""
        if not self.reactive:
            return sample_controllers(self.action_probs, self.next_probs, count, generator)
        a, nn, m = self.action_probs.shape
        o = self.next_probs.shape[1]
        act = torch.multinomial(self.action_probs.reshape(-1, m), count, replacement=True, generator=generator)
        nxt = torch.multinomial(self.next_probs.reshape(-1, nn), count, replacement=True, generator=generator)
        nxt = nxt.T.reshape(count, a, 1, o).expand(-1, -1, nn, -1)
        return JointController.trusted(act.T.reshape(count, a, nn).contiguous(), nxt.contiguous())

    def update(self, elite: JointController, alpha: float) -> None:
        """Move the distributions ``alpha`` of the way to the elites' frequencies."""
        m, nn = self.action_probs.shape[-1], self.action_probs.shape[1]
        edges = elite.next_node[:, :, 0] if self.reactive else elite.next_node
        self.action_probs = alpha * elite_frequencies(elite.action, m) + (1 - alpha) * self.action_probs
        self.next_probs = alpha * elite_frequencies(edges, nn) + (1 - alpha) * self.next_probs
        self.elites = elite


def start_state(incumbent: JointController | None, num_agents: int, num_nodes: int, num_actions: int, num_obs: int,
                weight: float, reactive: bool = False) -> CrossEntropyState:
    """Uniform distributions, mixed with ``weight`` of the incumbent's one-hot tables (K = 1, <= Nn nodes);
    ``reactive``: tied edges (no incumbent, or a reactive one, :func:`is_reactive`)."""
    action = torch.full((num_agents, num_nodes, num_actions), 1.0 / num_actions, dtype=torch.float64)
    if reactive:
        nxt = torch.full((num_agents, num_obs, num_nodes), 1.0 / num_nodes, dtype=torch.float64)
        if incumbent is not None and not is_reactive(incumbent):
            raise ValueError("reactive: a reactive phase starts cold or from a reactive incumbent")
        if incumbent is not None and weight > 0:
            nxt = (1 - weight) * nxt + weight * torch.nn.functional.one_hot(incumbent.next_node[0, :, 0],
                                                                           num_nodes).to(torch.float64)
    else:
        nxt = torch.full((num_agents, num_nodes, num_obs, num_nodes), 1.0 / num_nodes, dtype=torch.float64)
        if incumbent is not None and weight > 0:
            nxt[:, :incumbent.num_nodes] = (1 - weight) * nxt[:, :incumbent.num_nodes] + weight * (
                torch.nn.functional.one_hot(incumbent.next_node[0], num_nodes).to(torch.float64))
    if incumbent is not None and weight > 0:
        n = incumbent.num_nodes
        action[:, :n] = (1 - weight) * action[:, :n] + weight * torch.nn.functional.one_hot(
            incumbent.action[0], num_actions).to(torch.float64)
    return CrossEntropyState(action, nxt)


def is_reactive(controller: JointController) -> bool:
    """Whether every agent's edges out of all nodes agree (the next node depends on the observation only)."""
    return bool((controller.next_node == controller.next_node[:, :, :1]).all())


def iterate(state: CrossEntropyState, scorer: Scorer, generator: torch.Generator, *, samples: int, screen_rollouts: int,
            screen_keep: float, rollouts: int, elites: int, memory: int, alpha: float) -> dict[str, float]:
    """One iteration (see the module doc), updating ``state`` in place.

    Returns:
        ``best`` (score of the best elite), ``mean`` (mean last-stage score of the raced samples) and
        ``kept_from_memory`` (elites that came from the memory).
    """
    ctrl = state.sample(samples, generator)
    stages = [(rollouts, elites)] if screen_rollouts == 0 else [(screen_rollouts, screen_keep), (rollouts, elites)]
    alive, scores = race(scorer, samples, lambda idx: ctrl[idx], stages, generator)
    pool, pool_scores = ctrl[alive], scores
    if memory > 0 and state.elites is not None:
        remembered = state.elites[:memory]
        pool = JointController.cat([pool, remembered])
        pool_scores = torch.cat([pool_scores, scorer(remembered, rollouts, generator)[0]])
    order = torch.sort(pool_scores, descending=True, stable=True).indices[:elites]
    state.update(pool[order], alpha)
    return {"best": float(pool_scores[order[0]]), "mean": float(scores.mean()),
            "kept_from_memory": float((order >= alive.numel()).sum())}

