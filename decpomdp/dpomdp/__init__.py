"""Tabular Dec-POMDPs in the MADP ``.dpomdp`` format: parser and writer, shipped problems, unit-duration
Dec-POSMDP, exact evaluation and upper bounds (:func:`decpomdp.solve` plans on them)."""

from decpomdp.dpomdp.exact import DEFAULT_EVAL_BUDGET, exact_value
from decpomdp.dpomdp.model import DPOMDPModel, SparseTransitions
from decpomdp.dpomdp.parser import load_dpomdp, parse_dpomdp
from decpomdp.dpomdp.problems import PROBLEM_DIR, load_problem, problem_names, problem_path
from decpomdp.dpomdp.syntax import DEFAULT_MEMORY_BUDGET, DPOMDPSyntaxError
from decpomdp.dpomdp.tabular import TabularDecPOSMDP
from decpomdp.dpomdp.bounds import Bounds, upper_bounds
from decpomdp.dpomdp.writer import controller_text, dpomdp_text, save_dpomdp

__all__ = [
    "Bounds",
    "DEFAULT_EVAL_BUDGET",
    "DEFAULT_MEMORY_BUDGET",
    "PROBLEM_DIR",
    "DPOMDPModel",
    "DPOMDPSyntaxError",
    "SparseTransitions",
    "TabularDecPOSMDP",
    "controller_text",
    "dpomdp_text",
    "exact_value",
    "load_dpomdp",
    "load_problem",
    "parse_dpomdp",
    "problem_names",
    "problem_path",
    "save_dpomdp",
    "upper_bounds",
]
