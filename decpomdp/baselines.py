"""Generic baselines over any Dec-POSMDP evaluator: random controllers and Monte Carlo search."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.evaluate import Evaluator


def random_controllers(
    count: int, num_agents: int, num_nodes: int, num_actions: int, num_obs: int, generator: torch.Generator
) -> JointController:
    """``count`` joint controllers with every node action and transition drawn uniformly."""
    for name, value in (("count", count), ("num_agents", num_agents), ("num_nodes", num_nodes),
                        ("num_actions", num_actions), ("num_obs", num_obs)):
        if not isinstance(value, int) or value < 1:
            raise ValueError(f"{name}: expected an int >= 1, got {value!r}")
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
    evaluator: Evaluator,
    num_agents: int,
    num_actions: int,
    num_obs: int,
    num_nodes: int,
    budget: int,
    seed: int = 0,
    batch: int = 100,
    reevaluator: Evaluator | None = None,
) -> SearchResult:
    """Evaluate ``budget`` uniformly random controllers (in batches of ``batch``) and keep the best.

    With ``budget = iterations * samples`` it sees as many controllers as a G-DICE run.
    """
    if not isinstance(budget, int) or budget < 1:
        raise ValueError(f"budget: expected an int >= 1, got {budget!r}")
    if not isinstance(batch, int) or batch < 1:
        raise ValueError(f"batch: expected an int >= 1, got {batch!r}")
    generator = torch.Generator().manual_seed(int(seed))
    best, best_value, all_values = None, -float("inf"), []
    for start in range(0, budget, batch):
        ctrl = random_controllers(min(batch, budget - start), num_agents, num_nodes, num_actions, num_obs, generator)
        values = evaluator(ctrl, generator)[0].to(torch.float64)
        all_values.append(values)
        top = int(values.argmax())
        if float(values[top]) > best_value:
            best, best_value = ctrl[top], float(values[top])
    value = stderr = None
    if reevaluator is not None:
        mean, se = reevaluator(best, generator)
        value, stderr = float(mean[0]), float(se[0])
    return SearchResult(best, best_value, value, stderr, torch.cat(all_values))
