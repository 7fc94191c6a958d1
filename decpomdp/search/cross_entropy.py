"""One cross-entropy iteration over controller graphs (G-DICE's update), with racing, elite memory, G-DICE's
threshold rule, entropy injection and layered graphs.

The search distribution is G-DICE's: a categorical over each node's MA, ``action_probs`` (A, Nn, |MA|),
and over each (node, observation)'s next node, ``next_probs`` (A, Nn, O, Nn). A phase starts from
``(1 - w) * uniform + w * one_hot(incumbent)`` (``w = 0``: a cold start), the uniform restricted to the
allowed transitions (``mask``: a layered graph for finite horizons). A *reactive* phase ties the edges:
an agent's next node depends on its last observation only, whatever node it is in, so ``next_probs`` is
(A, O, Nn) and a sample's edges out of every node are the same; the graph is then a reactive policy
(observation -> node -> MA), the shape of a hand-written rule set, and each of the O x Nn + Nn x |MA|
entries is learnt from every elite rather than from the few that visit one node. Each iteration

1. samples ``samples`` controllers and races them (:func:`~decpomdp.search.racing.race`): all on
   ``screen_rollouts`` rollouts, the best ``screen_keep`` fraction again on ``rollouts`` fresh ones
   (``screen_rollouts = 0``: every sample on ``rollouts``, as in G-DICE), and records the best sample
   ever seen on its score;
2. re-scores the elite memory (the best ``memory`` controllers of the previous iteration) on
   ``rollouts`` fresh rollouts, so a controller once lucky is not kept on its old score;
3. takes the best ``elites`` of samples and memory that pass the threshold rule: ``"none"`` (all pass),
   ``"paper"`` (G-DICE: at least the previous iteration's worst elite) or ``"capped"`` (that, but never
   above this iteration's ``elites``-th best, so that a lucky iteration cannot freeze the search), and
   sets each distribution to ``alpha * frequency in the elites + (1 - alpha) * old`` (no change when
   none passes); the first ``memory`` elites (best first) are the next iteration's memory;
4. with entropy injection, mixes ``injection_weight`` of the uniform into every row whose normalised
   entropy fell below ``injection_threshold``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.search.racing import race
from decpomdp.search.scoring import Scorer


def sample_controllers(
    action_probs: Tensor, next_probs: Tensor, count: int, generator: torch.Generator
) -> JointController:
    """Draw ``count`` joint controllers from the node distributions (A, Nn, |MA|) and (A, Nn, O, Nn)."""
    a, nn, m = action_probs.shape
    o = next_probs.shape[2]
    act = torch.multinomial(action_probs.reshape(-1, m), count, replacement=True, generator=generator)
    nxt = torch.multinomial(next_probs.reshape(-1, nn), count, replacement=True, generator=generator)
    return JointController.trusted(
        act.T.reshape(count, a, nn).contiguous(), nxt.T.reshape(count, a, nn, o).contiguous()
    )


def elite_frequencies(values: Tensor, categories: int) -> Tensor:
    """values (N, ...) -> (..., categories) empirical frequencies over the N samples (G-DICE's update target)."""
    return torch.nn.functional.one_hot(values, categories).to(torch.float64).mean(0)


def layered_mask(num_nodes: int, layer_width: int | None) -> Tensor:
    """bool (Nn, Nn): the next nodes each node may move to. ``None``: a free graph; ``W``: node 0 is layer 0,
    then layers of ``W`` nodes; a node moves to the next layer only, and the last layer within itself."""
    if layer_width is None:
        return torch.ones(num_nodes, num_nodes, dtype=torch.bool)
    layer = torch.cat([torch.zeros(1, dtype=torch.long), torch.arange(num_nodes - 1) // layer_width + 1])
    target = torch.clamp(layer + 1, max=int(layer[-1]))
    return layer[None, :] == target[:, None]


def normalised_entropy(p: Tensor, allowed: Tensor | None = None) -> Tensor:
    """Entropy of each categorical row over the log of its number of allowed categories (1 for a single one)."""
    count = torch.full(p.shape[:-1], p.shape[-1], dtype=torch.long) if allowed is None else (allowed > 0).sum(-1)
    h = -(p * torch.log(p.clamp_min(1e-300))).sum(-1)
    return torch.where(count > 1, h / torch.log(count.clamp_min(2).to(p.dtype)), torch.ones_like(h))


@dataclass(frozen=True)
class Injection:
    """Entropy injection: rows whose normalised entropy is below ``threshold`` get ``weight`` of the uniform mixed in."""

    weight: float
    threshold: float


@dataclass
class CrossEntropyState:
    """The distributions, elite memory and records of a cross-entropy phase.

    Attributes:
        action_probs: float64 (A, Nn, |MA|); next_probs: float64 (A, Nn, O, Nn), or (A, O, Nn) when the
            edges are tied (a reactive phase).
        action_uniform, next_uniform: the uniform distributions over allowed categories (injection's target).
        elites: the last iteration's elites, best first (None before the first iteration); the first
            ``memory`` of them are the elite memory.
        threshold: the worst elite score of the last iteration that kept any (-inf before).
        best, best_value: the best controller sampled so far and its score when it was sampled.
    """

    action_probs: Tensor
    next_probs: Tensor
    action_uniform: Tensor
    next_uniform: Tensor
    elites: JointController | None = None
    threshold: float = -math.inf
    best: JointController | None = None
    best_value: float = -math.inf

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

    def inject(self, injection: Injection) -> None:
        """Mix the uniform into collapsed rows (see :class:`Injection`)."""
        for name, uniform in (("action_probs", self.action_uniform), ("next_probs", self.next_uniform)):
            p = getattr(self, name)
            collapsed = ((normalised_entropy(p, uniform) < injection.threshold) & ((uniform > 0).sum(-1) > 1))[
                ..., None
            ]
            setattr(self, name, torch.where(collapsed, (1 - injection.weight) * p + injection.weight * uniform, p))

    def entropy(self) -> float:
        """Mean normalised entropy of every row of both distributions."""
        return float(
            torch.cat(
                [
                    normalised_entropy(self.action_probs, self.action_uniform).ravel(),
                    normalised_entropy(self.next_probs, self.next_uniform).ravel(),
                ]
            ).mean()
        )


def start_state(
    incumbent: JointController | None,
    num_agents: int,
    num_nodes: int,
    num_actions: int,
    num_obs: int,
    weight: float,
    reactive: bool = False,
    mask: Tensor | None = None,
) -> CrossEntropyState:
    """Uniform distributions (next nodes restricted to ``mask``, bool (Nn, Nn)), mixed with ``weight`` of the
    incumbent's one-hot tables (K = 1, <= Nn nodes); ``reactive``: tied edges (no incumbent, or a reactive one,
    :func:`is_reactive`)."""
    action = torch.full((num_agents, num_nodes, num_actions), 1.0 / num_actions, dtype=torch.float64)
    if reactive:
        if mask is not None and not bool(mask.all()):
            raise ValueError("reactive: a reactive phase needs a free graph (no layer_width)")
        if incumbent is not None and not is_reactive(incumbent):
            raise ValueError("reactive: a reactive phase starts cold or from a reactive incumbent")
        uniform_next = torch.full((num_agents, num_obs, num_nodes), 1.0 / num_nodes, dtype=torch.float64)
        nxt = uniform_next
        if incumbent is not None and weight > 0:
            nxt = (1 - weight) * nxt + weight * torch.nn.functional.one_hot(incumbent.next_node[0, :, 0], num_nodes).to(
                torch.float64
            )
    else:
        allowed = torch.ones(num_nodes, num_nodes, dtype=torch.float64) if mask is None else mask.to(torch.float64)
        uniform_next = (allowed / allowed.sum(-1, keepdim=True))[None, :, None, :].expand(
            num_agents, num_nodes, num_obs, num_nodes
        )
        nxt = uniform_next.clone()
        if incumbent is not None and weight > 0:
            nxt[:, : incumbent.num_nodes] = (1 - weight) * nxt[:, : incumbent.num_nodes] + weight * (
                torch.nn.functional.one_hot(incumbent.next_node[0], num_nodes).to(torch.float64)
            )
    uniform_action = action.clone()
    if incumbent is not None and weight > 0:
        n = incumbent.num_nodes
        action[:, :n] = (1 - weight) * action[:, :n] + weight * torch.nn.functional.one_hot(
            incumbent.action[0], num_actions
        ).to(torch.float64)
    return CrossEntropyState(action, nxt, uniform_action, uniform_next.clone())


def is_reactive(controller: JointController) -> bool:
    """Whether every agent's edges out of all nodes agree (the next node depends on the observation only)."""
    return bool((controller.next_node == controller.next_node[:, :, :1]).all())


def iterate(
    state: CrossEntropyState,
    scorer: Scorer,
    generator: torch.Generator,
    *,
    samples: int,
    screen_rollouts: int,
    screen_keep: float,
    rollouts: int,
    elites: int,
    memory: int,
    alpha: float,
    threshold_rule: str = "none",
    injection: Injection | None = None,
    common: bool = False,
) -> dict[str, float]:
    """One iteration (see the module doc), updating ``state`` in place; ``common``: race the samples on common
    random numbers (:func:`~decpomdp.search.racing.race`).

    Returns:
        ``best`` (score of the best pool member), ``mean`` (mean first-stage score of all samples),
        ``kept`` (elites used for the update), ``kept_from_memory``, ``threshold`` and ``entropy`` (after).
    """
    ctrl = state.sample(samples, generator)
    stages = [(rollouts, elites)] if screen_rollouts == 0 else [(screen_rollouts, screen_keep), (rollouts, elites)]
    alive, scores, sample_mean = race(scorer, samples, lambda idx: ctrl[idx], stages, generator, common=common)
    if float(scores[0]) > state.best_value:
        state.best, state.best_value = ctrl[int(alive[0])], float(scores[0])
    pool, pool_scores = ctrl[alive], scores
    if memory > 0 and state.elites is not None:
        remembered = state.elites[:memory]
        pool = JointController.cat([pool, remembered])
        pool_scores = torch.cat([pool_scores, scorer(remembered, rollouts, generator)[0]])
    order = torch.sort(pool_scores, descending=True, stable=True).indices[:elites]
    threshold = state.threshold if threshold_rule != "none" else -math.inf
    if threshold_rule == "capped" and order.numel() == elites:
        threshold = min(threshold, float(pool_scores[order[-1]]))
    kept = order[pool_scores[order] >= threshold]
    if kept.numel():
        state.threshold = float(pool_scores[kept[-1]])
        state.update(pool[kept], alpha)
        state.elites = pool[kept]
    if injection is not None:
        state.inject(injection)
    return {
        "best": float(pool_scores[order[0]]),
        "mean": sample_mean,
        "kept": float(kept.numel()),
        "kept_from_memory": float((kept >= alive.numel()).sum()),
        "threshold": state.threshold,
        "entropy": state.entropy(),
    }
