"""Generic baselines over any scorer: uniformly random controllers and Monte Carlo search."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.search.scoring import Scorer
from hbni_infra.checks import as_generator, as_int
from hbni_infra.streams import torch_generator


def random_controllers(
    count: int, *, num_agents: int, num_nodes: int, num_actions: int, num_obs: int, generator: torch.Generator
) -> JointController:
    """``count`` joint controllers with every node action and transition drawn uniformly."""
    for name, value in (
        ("count", count),
        ("num_agents", num_agents),
        ("num_nodes", num_nodes),
        ("num_actions", num_actions),
        ("num_obs", num_obs),
    ):
        as_int(name, value, 1)
    generator = as_generator("generator", generator)
    action = torch.randint(0, num_actions, (count, num_agents, num_nodes), generator=generator)
    next_node = torch.randint(0, num_nodes, (count, num_agents, num_nodes, num_obs), generator=generator)
    return JointController(action, next_node)


@dataclass
class SearchResult:
    """Best of a set of controllers: the controller (K = 1), its sampled score, its re-evaluated value."""

    best: JointController
    best_value: float
    value: float | None
    stderr: float | None
    values: Tensor  # (N,) the score of every controller tried


def monte_carlo_search(
    scorer: Scorer,
    *,
    num_nodes: int,
    budget: int,
    rollouts: int,
    seed: int = 0,
    batch: int = 100,
    reeval_rollouts: int | None = None,
) -> SearchResult:
    """Score ``budget`` uniformly random controllers of ``scorer``'s agents (in batches of ``batch``, each on
    ``rollouts`` rollouts) and keep the best; with ``reeval_rollouts`` the best is scored again on that many.

    With ``budget = iterations * samples`` it sees as many controllers as a G-DICE run.
    """
    budget, batch, rollouts = as_int("budget", budget, 1), as_int("batch", batch, 1), as_int("rollouts", rollouts, 2)
    generator = torch_generator(seed)
    best, best_value, all_values = None, -float("inf"), []
    for start in range(0, budget, batch):
        ctrl = random_controllers(
            min(batch, budget - start),
            num_agents=scorer.num_agents,
            num_nodes=num_nodes,
            num_actions=scorer.num_actions,
            num_obs=scorer.num_obs,
            generator=generator,
        )
        values = scorer(ctrl, rollouts, generator)[0].to(torch.float64)
        all_values.append(values)
        top = int(values.argmax())
        if float(values[top]) > best_value:
            best, best_value = ctrl[top], float(values[top])
    value = stderr = None
    if reeval_rollouts is not None:
        mean, se = scorer(best, reeval_rollouts, generator)
        value, stderr = float(mean[0]), float(se[0])
    return SearchResult(best, best_value, value, stderr, torch.cat(all_values))
