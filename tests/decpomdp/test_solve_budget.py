"""``solve``'s time and memory budgets (:mod:`decpomdp.budget`): a budget that ends returns the best controller found
so far with a valid bound and says which budget ended; memory is estimated before tables are allocated, and a
process that solves within a small memory budget grows by about that much; the progress bar; budgets outside
``solve``."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap

import pytest
import torch

from decpomdp import ExactScorer, PlannerConfig, plan, solve
from decpomdp.budget import Budget, BudgetSpent, check, memory_limit, reserve, time_left
from decpomdp.dpomdp import TabularDecPOSMDP, exact_value

MIB = 2**20


def _consistent(s, problem: str) -> None:
    env = TabularDecPOSMDP.from_problem(problem, gamma=s.gamma, horizon=s.horizon)
    assert s.value == pytest.approx(float(exact_value(env, s.controller)[0]), rel=1e-9, abs=1e-9)
    assert s.value <= s.bound + 1e-9 * max(1.0, abs(s.bound))


def test_a_time_budget_keeps_what_the_search_found_before_it_ended():
    """GridSmall's infinite horizon needs about 80 s: after 6 s the solution is a searched controller, better than
    every one-node controller, with the bound of the relaxations."""
    s = solve("GridSmall", math.inf, 0.9, time_budget=6.0)
    assert s.budget_ended == "time" and s.seconds < 6.0 + 4.0
    env = TabularDecPOSMDP.from_problem("GridSmall", gamma=0.9, horizon=math.inf)
    one_node = torch.cartesian_prod(torch.arange(5), torch.arange(5)).reshape(-1, 2, 1)
    from decpomdp import JointController

    repeaters = JointController(one_node, torch.zeros(25, 2, 1, 2, dtype=torch.long))
    assert s.controller.num_nodes > 1 and s.value > float(exact_value(env, repeaters).max()) + 0.1
    _consistent(s, "GridSmall")


def test_a_small_memory_budget_ends_a_real_search_before_its_table_is_allocated():
    """GridSmall at horizon 8: the exact search's open list grows past 64 MiB within seconds (the whole solve holds
    about 500 MiB at its peak); the budget ends the solve there, naming the table, with a valid solution."""
    s = solve("GridSmall", 8, 1.0, memory_budget=64 * MIB, time_budget=300.0, exact_seconds=1e4)
    assert s.budget_ended == "memory" and "open list" in s.budget_note and "64 MiB" in s.budget_note
    _consistent(s, "GridSmall")


def test_a_process_solving_within_a_memory_budget_grows_by_about_that_much():
    """The estimates are of real memory: the process's peak resident size grows by at most the budget and a margin
    for what is not a search table (Python objects, allocator slack); without the budget it grows by hundreds of MiB
    more."""
    code = textwrap.dedent(
        """
        import resource
        from decpomdp import solve
        solve("dectiger", 2)  # imports and compiled kernels first
        base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        s = solve("GridSmall", 8, 1.0, memory_budget=64 * 2**20, time_budget=300.0, exact_seconds=1e4)
        print(s.budget_ended, (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) // 1024)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    ended, grown = out.stdout.split()
    assert ended == "memory" and int(grown) <= 64 + 64, out.stdout


def test_an_exact_evaluation_too_large_for_the_budget_ends_it_before_allocating():
    env = TabularDecPOSMDP.from_problem("fireFighting_2_4_3", gamma=1.0, horizon=10)
    from decpomdp import random_controllers

    big = random_controllers(1, num_agents=2, num_nodes=30, num_actions=3, num_obs=2, generator=torch.Generator())
    with Budget(None, 10 * MIB) as budget, pytest.raises(BudgetSpent, match="exact evaluation of one controller"):
        exact_value(env, big)
    assert budget.spent.resource == "memory"
    with pytest.raises(BudgetSpent):  # spent stays spent
        budget.check()
    assert float(exact_value(env, big)[0]) < 0  # outside the budget: evaluated


def test_keep_restarting_runs_rounds_until_the_budget_ends():
    s = solve(
        "dectiger", 3, 1.0, exact_seconds=0, keep_restarting=True, time_budget=10.0, jesp_restarts=0, ce_iterations=2
    )
    assert s.budget_ended == "time" and s.restarts >= 1
    _consistent(s, "dectiger")


def test_a_finished_solve_says_no_budget_ended():
    s = solve("dectiger", 3, 1.0)
    assert s.budget_ended is None and s.budget_note == "" and s.proven


def test_progress_is_shown_on_a_long_solve(capsys):
    solve("dectiger", 200, time_budget=3.0, progress=True)
    err = capsys.readouterr().err
    assert "/3 s" in err and "value=" in err, err[-500:]


def test_the_planner_returns_its_incumbent_when_a_budget_ends_it():
    env = TabularDecPOSMDP.from_problem("dectiger", gamma=1.0, horizon=6)
    with Budget(2.0, None):
        result = plan(ExactScorer(env), PlannerConfig(num_nodes=12), seed=0)
    assert result.best is not None and result.best.num_nodes >= 1


def test_budget_calls_outside_a_budget_do_nothing():
    check()
    reserve(10**15, "a table")
    assert time_left() == math.inf and memory_limit(123) == 123
    with Budget(100.0, 1000, progress=False):
        assert memory_limit(10**6) == 1000 and 0 < time_left() <= 100.0
        with pytest.raises(BudgetSpent, match="a table needs 1.95 KiB, more than the memory budget of 1000 bytes"):
            reserve(2000, "a table")
