"""Dec-POSMDP planning: a batched event-driven simulator, finite-state controllers and G-DICE.

Perception enters only through :class:`MacroObservationModel`; this package never imports
``classifiers`` or ``hbni_pyro``.
"""

from decpomdp.controller import JointController
from decpomdp.core import DecPOSMDP
from decpomdp.evaluate import Evaluator, MonteCarloEvaluator, evaluate
from decpomdp.simulate import simulate

__all__ = [
    "DecPOSMDP",
    "Evaluator",
    "JointController",
    "MonteCarloEvaluator",
    "evaluate",
    "simulate",
]
