"""Dec-POSMDP planning: a compiled rollout engine and a batched torch simulator, finite-state controllers, the
planner (the cold-start planner and the paper's G-DICE as its preset), the mission domains and the robot-side
executor of a planned controller (:class:`ControllerExecutor`).

Perception enters only through :class:`PerceptionModel`; this package never imports ``classifiers`` or
``hbni_pyro``.

See ``docs/architecture.md`` for the layout and the data's path from pixels to policy.
"""

from hbni_infra.version import __version__

from decpomdp.baselines import SearchResult, monte_carlo_search, random_controllers
from decpomdp.controller import JointController
from decpomdp.core import DecPOSMDP
from decpomdp.domains import DisasterRelief, PackageDelivery, rollout_counters, shared
from decpomdp.evaluate import evaluate
from decpomdp.executor import ControllerExecutor, MacroAction
from decpomdp.perception import PerceptionModel, PerfectPerception
from decpomdp.search import ExactScorer, PlannerConfig, PlannerResult, RolloutScorer, Scorer, gdice_config, plan
from decpomdp.simulate import simulate
from decpomdp.solver import Solution, solve

__all__ = [
    "__version__",
    "ControllerExecutor",
    "DecPOSMDP",
    "DisasterRelief",
    "ExactScorer",
    "JointController",
    "MacroAction",
    "PackageDelivery",
    "PerceptionModel",
    "PerfectPerception",
    "PlannerConfig",
    "PlannerResult",
    "RolloutScorer",
    "Scorer",
    "SearchResult",
    "Solution",
    "evaluate",
    "gdice_config",
    "monte_carlo_search",
    "plan",
    "random_controllers",
    "rollout_counters",
    "shared",
    "simulate",
    "solve",
]
