"""Dec-POSMDP planning: a batched event-driven simulator, finite-state controllers, G-DICE and the
robot-side executor of a planned controller (:class:`ControllerExecutor`).

Perception enters only through :class:`PerceptionModel`; this package never imports
``classifiers`` or ``hbni_pyro``.

See ``docs/architecture.md`` for the layout and the data's path from pixels to policy.
"""

from decpomdp.baselines import SearchResult, monte_carlo_search, random_controllers
from decpomdp.controller import JointController
from decpomdp.core import DecPOSMDP
from decpomdp.evaluate import Evaluator, MonteCarloEvaluator, evaluate
from decpomdp.executor import ControllerExecutor, MacroAction
from decpomdp.gdice import GDICEConfig, GDICEResult, gdice, sample_controllers
from decpomdp.perception import PerceptionModel, PerfectPerception
from decpomdp.simulate import simulate

__all__ = [
    "ControllerExecutor",
    "DecPOSMDP",
    "Evaluator",
    "GDICEConfig",
    "GDICEResult",
    "JointController",
    "MacroAction",
    "PerceptionModel",
    "MonteCarloEvaluator",
    "PerfectPerception",
    "SearchResult",
    "evaluate",
    "gdice",
    "monte_carlo_search",
    "random_controllers",
    "sample_controllers",
    "simulate",
]
