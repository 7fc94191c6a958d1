"""Monte Carlo evaluation of joint controllers: :func:`evaluate`, the mean return of each and its standard error."""

from __future__ import annotations

import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.core import DecPOSMDP
from decpomdp.search.scoring import RolloutScorer


def evaluate(
    env: DecPOSMDP, controller: JointController, rollouts: int, generator: torch.Generator, backend: str | None = None
) -> tuple[Tensor, Tensor]:
    """Mean discounted return of each of the K controllers over ``rollouts`` rollouts, and its standard error.

    Args:
        rollouts: R >= 2 independent rollouts per controller.
        backend: as in :func:`decpomdp.simulate` (the compiled engine where ``env`` is written for it).

    Returns:
        mean float64 (K,), stderr float64 (K,) = sample sd / sqrt(R).
    """
    return RolloutScorer(env, backend=backend)(controller, rollouts, generator)
