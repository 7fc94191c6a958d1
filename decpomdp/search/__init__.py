"""The planner: G-DICE's cross-entropy over controller graphs, with racing, elite memory and local search.

:func:`plan` finds a controller from scratch (no hand-written seed) or from a warm start; :class:`PlannerConfig`
holds its settings, whose defaults are the cold-start planner and of which :func:`gdice_config` is the paper's
G-DICE; a :class:`Scorer` (:class:`RolloutScorer` for Monte Carlo rollouts, :class:`ExactScorer` for exact
values of a tabular problem) scores controllers for it.
"""

from decpomdp.search.config import PlannerConfig, gdice_config
from decpomdp.search.planner import PlannerResult, plan
from decpomdp.search.scoring import ExactScorer, RolloutScorer, Scorer, mean_stderr

__all__ = [
    "ExactScorer",
    "PlannerConfig",
    "PlannerResult",
    "RolloutScorer",
    "Scorer",
    "gdice_config",
    "mean_stderr",
    "plan",
]
