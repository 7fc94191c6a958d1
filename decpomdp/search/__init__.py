"""The cold-start planner: G-DICE's cross-entropy over controller graphs, racing, elite memory and local search.

:func:`plan` finds a controller from scratch (no hand-written seed); :class:`PlannerConfig` holds its
settings; :class:`RolloutScorer` and :class:`ExactScorer` adapt a problem to it.
"""

from decpomdp.search.config import PlannerConfig
from decpomdp.search.planner import PlannerResult, plan
from decpomdp.search.scoring import ExactScorer, RolloutScorer, Scorer

__all__ = ["ExactScorer", "PlannerConfig", "PlannerResult", "RolloutScorer", "Scorer", "plan"]
