"""Racing: screen many candidates on few rollouts, spend more rollouts on the contenders, then a duel.

:func:`race` runs successive stages ``(rollouts, keep)``: every surviving candidate is scored on
``rollouts`` fresh rollouts and the best ``keep`` of them (a fraction in (0, 1), at least ``minimum``,
or a count >= 1) go on. Scores of different stages are independent, so a candidate that was lucky in
one stage is scored afresh in the next; the survivors of the last stage are returned best first. An exact
scorer (``scorer.exact``) scores every candidate once: its later stages only cut the ranking.

:func:`duel` then scores the incumbent and the survivors on the same number of fresh rollouts and
names the best survivor if it beats the incumbent by more than ``z`` standard errors of the
difference (for exact scores, standard error 0, any strict improvement beyond rounding wins).

With ``common=True`` (common random numbers, Glasserman and Yao 1992; PEGASUS, Ng and Jordan 2000) the candidates of
a stage, and the incumbent and challengers of a duel, run on the same random streams, and the duel's standard
error is that of the rollout-by-rollout difference: two controllers that act alike until some event share their
returns' luck up to it, so a race ranks them by what they do differently.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.search.scoring import Scorer, mean_stderr
from hbni_infra.streams import torch_generator

ROUNDING = 1e-9
"""Least relative win of a duel: far above float64 rounding of a value, far below any Monte Carlo error."""


def race(
    scorer: Scorer,
    count: int,
    build: Callable[[Tensor], JointController],
    stages: Sequence[tuple[int, float]],
    generator: torch.Generator,
    minimum: int = 4,
    common: bool = False,
) -> tuple[Tensor, Tensor]:
    """Race candidates ``0 .. count - 1`` (built on demand by ``build(indices)``) through ``stages``.

    Returns:
        the surviving indices, long (S,), best first, their last-stage scores, float64 (S,), and the mean score
        of all ``count`` candidates in the first stage.
    """
    alive = torch.arange(count)
    scores = torch.zeros(count, dtype=torch.float64)
    first_mean = math.nan
    exact = getattr(scorer, "exact", False)
    for stage, (rollouts, keep) in enumerate(stages):
        if stage == 0 or not exact:  # an exact score needs no second look: later stages only cut
            per = max(1, 200_000 // rollouts)  # candidates per batched call
            streams = _stage_streams(generator) if common else (lambda: generator)
            kwargs = {"common": True} if common else {}
            scores = torch.cat(
                [
                    scorer(build(alive[i : i + per]), rollouts, streams(), **kwargs)[0]
                    for i in range(0, alive.numel(), per)
                ]
            )
        first_mean = float(scores.mean()) if math.isnan(first_mean) else first_mean
        kept = int(keep) if keep >= 1 else max(minimum, math.ceil(keep * alive.numel()))
        order = torch.sort(scores, descending=True, stable=True).indices[:kept]
        alive, scores = alive[order], scores[order]
    return alive, scores, first_mean


def duel(
    scorer: Scorer,
    incumbent: JointController,
    challengers: JointController,
    rollouts: int,
    z: float,
    generator: torch.Generator,
    common: bool = False,
) -> tuple[int | None, Tensor, Tensor]:
    """Score ``incumbent`` (K = 1) and ``challengers`` on ``rollouts`` fresh rollouts each.

    Returns:
        the index of the best challenger if it beats the incumbent by more than ``z`` standard errors
        of the difference and by more than the rounding error of a float64 value (``ROUNDING`` relative), else
        None; the means and standard errors (1 + C,), incumbent first. Without the rounding margin, exact
        scores (zero standard errors) of equally good controllers that differ in their last bits would win duels
        forever.
    """
    pool = JointController.cat([incumbent, challengers])
    if common:
        returns = scorer.returns(pool, rollouts, generator, True)
        mean, se = mean_stderr(returns)
        best = int(mean[1:].argmax()) + 1
        sd = float(mean_stderr(returns[best] - returns[0])[1])
    else:
        mean, se = scorer(pool, rollouts, generator)
        best = int(mean[1:].argmax()) + 1
        sd = float((se[best] ** 2 + se[0] ** 2) ** 0.5)
    gap = float(mean[best] - mean[0])
    margin = max(z * sd, ROUNDING * max(1.0, abs(float(mean[0]))))
    return (best - 1 if gap > margin else None), mean, se


def _stage_streams(generator: torch.Generator) -> Callable[[], torch.Generator]:
    """Generators all in one state, drawn from ``generator``: every batched call of a racing stage gets one, so
    that its candidates run on common random numbers."""
    state = torch_generator(int(torch.randint(0, 2**62, (1,), generator=generator))).get_state()
    return lambda: torch.Generator().set_state(state)
