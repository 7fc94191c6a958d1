"""``decpomdp.solve`` at its boundary: a horizon it cannot finish ends with its budget and returns a valid policy with its
bound; a horizon, problem or keyword it cannot take is refused before any work, naming the argument."""

from __future__ import annotations

import math
import time

import pytest
import torch

from decpomdp import solve
from decpomdp.dpomdp import TabularDecPOSMDP, exact_value
from decpomdp.solver import MAX_HORIZON


def _consistent(s, problem: str) -> None:
    """The solution's value is its controller's exact value, and at most its bound."""
    env = TabularDecPOSMDP.from_problem(problem, gamma=s.gamma, horizon=s.horizon)
    assert s.value == pytest.approx(float(exact_value(env, s.controller)[0]), rel=1e-9, abs=1e-9)
    assert s.value <= s.bound + 1e-9 * max(1.0, abs(s.bound)) and s.gap >= 0


def test_a_long_horizon_ends_with_its_time_budget_and_keeps_a_valid_policy():
    """Horizon 200 ran on for minutes with no end in sight: it now stops within seconds of its budget."""
    start = time.perf_counter()
    s = solve("dectiger", 200, time_budget=6.0)
    wall = time.perf_counter() - start
    assert wall < 6.0 + 5.0, wall
    assert s.budget_ended == "time" and "6 s passed" in s.budget_note and not s.proven
    _consistent(s, "dectiger")


def test_an_endless_horizon_is_refused_naming_the_limit_and_the_infinite_horizon():
    with pytest.raises(
        ValueError, match=rf"horizon: expected a whole number of steps in \[1, {MAX_HORIZON}\].*math.inf"
    ):
        solve("dectiger", 10**9)


@pytest.mark.parametrize(
    "horizon, error",
    [
        ("3", TypeError),
        (True, TypeError),
        (None, TypeError),
        (3.5, ValueError),
        (0, ValueError),
        (-2, ValueError),
        (math.nan, ValueError),
        (-math.inf, ValueError),
    ],
)
def test_a_horizon_of_the_wrong_type_or_value_is_refused_naming_horizon(horizon, error):
    with pytest.raises(error, match="horizon: expected a whole number of steps"):
        solve("dectiger", horizon)


def test_whole_numbers_of_any_kind_are_horizons():
    a = solve("dectiger", 2, exact_seconds=1.0)
    assert solve("dectiger", 2.0, exact_seconds=1.0).value == solve("dectiger", torch.tensor(2)).value == a.value


def test_a_misspelt_planner_keyword_is_refused_naming_the_nearest():
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'ce_alphaa'; did you mean 'ce_alpha'"):
        solve("dectiger", 2, ce_alphaa=0.3)  # horizon 2 is proven at once: the planner never runs, still refused
    with pytest.raises(TypeError, match=r"'time_budgt'; did you mean 'time_budget'"):
        solve("dectiger", 2, time_budgt=3.0)
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'colour' \(solve takes"):
        solve("dectiger", 2, colour="red")
    with pytest.raises(ValueError, match="ce_alpha: expected a finite number in"):
        solve("dectiger", 2, ce_alpha=5.0)  # a planner value is checked even where the planner never runs


def test_an_empty_or_unknown_problem_lists_the_shipped_ones():
    with pytest.raises(ValueError, match="problem: expected a shipped problem's name.*empty name.*dectiger"):
        solve("", 3)
    with pytest.raises(FileNotFoundError, match="the shipped problems are .*broadcastChannel"):
        solve("dectigre", 3)
    with pytest.raises(TypeError, match="problem: expected a shipped problem's name"):
        solve(b"dectiger", 3)


@pytest.mark.parametrize(
    "kwargs, error, name",
    [
        (dict(gamma="0.9"), TypeError, "gamma"),
        (dict(gamma=1.5), ValueError, "gamma"),
        (dict(time_budget="60"), TypeError, "time_budget"),
        (dict(time_budget=0.0), ValueError, "time_budget"),
        (dict(memory_budget=0), ValueError, "memory_budget"),
        (dict(memory_budget=1.5e9), TypeError, "memory_budget"),
        (dict(keep_restarting=1), TypeError, "keep_restarting"),
        (dict(keep_restarting=True, time_budget=None), ValueError, "keep_restarting"),
        (dict(progress="yes"), TypeError, "progress"),
        (dict(threads=0), ValueError, "threads"),
        (dict(loop_horizons=5), TypeError, "loop_horizons"),
        (dict(loop_horizons=(2, "3")), TypeError, "loop_horizons"),
        (dict(seed=True), TypeError, "seed"),
        (dict(exact_seconds=-1.0), ValueError, "exact_seconds"),
    ],
)
def test_every_argument_is_checked_before_any_work(kwargs, error, name):
    with pytest.raises(error, match=name):
        solve("dectiger", 2, **kwargs)


def test_the_infinite_horizon_needs_a_discount_below_one():
    with pytest.raises(ValueError, match=r"an infinite horizon needs gamma < 1.*got gamma 1 \(the file discount\)"):
        solve("dectiger", math.inf)


@pytest.mark.parametrize("index", [5, 1, -2])
def test_indexing_a_joint_controller_out_of_range_names_the_index_and_the_range(index):
    """``greedy_controller(2)[5]`` said "every dimension must be >= 1, got (0, 2, 8, 30)"."""
    from decpomdp.domains.disaster_relief import greedy_controller

    controller = greedy_controller(2)
    with pytest.raises(
        IndexError, match=rf"index: {index} is out of range for 1 joint controller\(s\): expected -1 to 0"
    ):
        controller[index]
    assert torch.equal(controller[0].action, controller[-1].action) and controller[0].num_controllers == 1
