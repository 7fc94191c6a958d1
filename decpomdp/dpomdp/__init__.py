"""Tabular Dec-POMDPs in the MADP ``.dpomdp`` format: parser, shipped problems, unit-duration Dec-POSMDP,
exact evaluation."""

from decpomdp.dpomdp.exact import DEFAULT_EVAL_BUDGET, exact_value
from decpomdp.dpomdp.model import DPOMDPModel, SparseTransitions
from decpomdp.dpomdp.parser import load_dpomdp, parse_dpomdp
from decpomdp.dpomdp.problems import PROBLEM_DIR, load_problem, problem_names, problem_path
from decpomdp.dpomdp.syntax import DEFAULT_MEMORY_BUDGET, DPOMDPSyntaxError
from decpomdp.dpomdp.tabular import TabularDecPOSMDP

__all__ = [
    "DEFAULT_EVAL_BUDGET",
    "DEFAULT_MEMORY_BUDGET",
    "PROBLEM_DIR",
    "DPOMDPModel",
    "DPOMDPSyntaxError",
    "SparseTransitions",
    "TabularDecPOSMDP",
    "exact_value",
    "load_dpomdp",
    "load_problem",
    "parse_dpomdp",
    "problem_names",
    "problem_path",
]
