"""Tabular Dec-POMDPs in the MADP ``.dpomdp`` format: parser, unit-duration Dec-POSMDP, exact evaluation."""

from decpomdp.dpomdp.exact import ExactEvaluator, exact_value
from decpomdp.dpomdp.parser import DPOMDPModel, DPOMDPSyntaxError, load_dpomdp, parse_dpomdp
from decpomdp.dpomdp.tabular import TabularDecPOSMDP

__all__ = [
    "DPOMDPModel",
    "DPOMDPSyntaxError",
    "ExactEvaluator",
    "TabularDecPOSMDP",
    "exact_value",
    "load_dpomdp",
    "parse_dpomdp",
]
