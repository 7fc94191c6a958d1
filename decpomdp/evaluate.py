"""Monte Carlo evaluation of joint controllers and the evaluator objects G-DICE plugs in."""

from __future__ import annotations

from typing import Protocol

import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.core import DecPOSMDP
from decpomdp.simulate import simulate


def evaluate(
    env: DecPOSMDP,
    controller: JointController,
    rollouts: int,
    generator: torch.Generator,
    max_batch: int = 200_000,
) -> tuple[Tensor, Tensor]:
    """Mean discounted return of each of the K controllers and its standard error.

    Args:
        rollouts: R >= 2 independent rollouts per controller.
        max_batch: at most this many rollouts are simulated in one batch (controllers are chunked).

    Returns:
        mean float64 (K,), stderr float64 (K,) = sample sd / sqrt(R).
    """
    if not isinstance(rollouts, int) or rollouts < 2:
        raise ValueError(f"rollouts: expected an int >= 2 (a standard error needs two), got {rollouts!r}")
    if not isinstance(max_batch, int) or max_batch < 1:
        raise ValueError(f"max_batch: expected an int >= 1, got {max_batch!r}")
    per_chunk = max(1, max_batch // rollouts)
    returns = torch.cat(
        [
            simulate(env, controller[i : i + per_chunk], rollouts, generator)
            for i in range(0, controller.num_controllers, per_chunk)
        ]
    )
    return returns.mean(dim=1), returns.std(dim=1) / rollouts**0.5


class Evaluator(Protocol):
    """Scores K joint controllers: ``evaluator(controller, generator) -> (mean (K,), stderr (K,))``."""

    def __call__(self, controller: JointController, generator: torch.Generator) -> tuple[Tensor, Tensor]: ...


class MonteCarloEvaluator:
    """An :class:`Evaluator` that runs ``rollouts`` Monte Carlo rollouts of ``env`` per controller."""

    def __init__(self, env: DecPOSMDP, rollouts: int, max_batch: int = 200_000) -> None:
        if not isinstance(env, DecPOSMDP):
            raise TypeError(f"env: expected a DecPOSMDP, got {type(env).__name__}")
        if not isinstance(rollouts, int) or rollouts < 2:
            raise ValueError(f"rollouts: expected an int >= 2, got {rollouts!r}")
        self.env, self.rollouts, self.max_batch = env, rollouts, max_batch
        self.num_agents, self.num_actions, self.num_obs = env.num_agents, env.num_actions, env.num_obs

    def __call__(self, controller: JointController, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        return evaluate(self.env, controller, self.rollouts, generator, self.max_batch)
