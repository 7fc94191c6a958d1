"""One cross-entropy iteration over controller graphs (G-DICE's update) with racing and elite memory.

The search distribution is G-DICE's: a categorical over each node's MA, ``action_probs`` (A, Nn, |MA|),
and over each (node, observation)'s next node, ``next_probs`` (A, Nn, O, Nn). A phase starts from
``(1 - w) * uniform + w * one_hot(incumbent)`` (``w = 0``: a cold start). Each iteration

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
        action_probs: float64 (A, Nn, |MA|); next_probs: float64 (A, Nn, O, Nn).
        elites: the last iteration's elites, best first (None before the first iteration); the first
            ``memory`` of them are the elite memory.
    """

    action_probs: Tensor
    next_probs: Tensor
    elites: JointController | None = None


def start_state(incumbent: JointController | None, num_agents: int, num_nodes: int, num_actions: int, num_obs: int,
                weight: float) -> CrossEntropyState:
    """Uniform distributions, mixed with ``weight`` of the incumbent's one-hot tables (K = 1, <= Nn nodes)."""
    action = torch.full((num_agents, num_nodes, num_actions), 1.0 / num_actions, dtype=torch.float64)
    nxt = torch.full((num_agents, num_nodes, num_obs, num_nodes), 1.0 / num_nodes, dtype=torch.float64)
    if incumbent is not None and weight > 0:
        n = incumbent.num_nodes
        action[:, :n] = (1 - weight) * action[:, :n] + weight * torch.nn.functional.one_hot(
            incumbent.action[0], num_actions).to(torch.float64)
        nxt[:, :n] = (1 - weight) * nxt[:, :n] + weight * torch.nn.functional.one_hot(
            incumbent.next_node[0], num_nodes).to(torch.float64)
    return CrossEntropyState(action, nxt)


def iterate(state: CrossEntropyState, scorer: Scorer, generator: torch.Generator, *, samples: int, screen_rollouts: int,
            screen_keep: float, rollouts: int, elites: int, memory: int, alpha: float) -> dict[str, float]:
    """One iteration (see the module doc), updating ``state`` in place.

    Returns:
        ``best`` (score of the best elite), ``mean`` (mean last-stage score of the raced samples) and
        ``kept_from_memory`` (elites that came from the memory).
    """
    a, nn, m = state.action_probs.shape
    ctrl = sample_controllers(state.action_probs, state.next_probs, samples, generator)
    stages = [(rollouts, elites)] if screen_rollouts == 0 else [(screen_rollouts, screen_keep), (rollouts, elites)]
    alive, scores = race(scorer, samples, lambda idx: ctrl[idx], stages, generator)
    pool, pool_scores = ctrl[alive], scores
    if memory > 0 and state.elites is not None:
        remembered = state.elites[:memory]
        pool = JointController.cat([pool, remembered])
        pool_scores = torch.cat([pool_scores, scorer(remembered, rollouts, generator)[0]])
    order = torch.sort(pool_scores, descending=True, stable=True).indices[:elites]
    elite = pool[order]
    state.action_probs = alpha * elite_frequencies(elite.action, m) + (1 - alpha) * state.action_probs
    state.next_probs = alpha * elite_frequencies(elite.next_node, nn) + (1 - alpha) * state.next_probs
    state.elites = elite
    return {"best": float(pool_scores[order[0]]), "mean": float(scores.mean()),
            "kept_from_memory": float((order >= alive.numel()).sum())}

