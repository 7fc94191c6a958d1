"""One call from a ``.dpomdp`` problem to a policy, its exact value and a certified gap.

:func:`solve` plans joint finite-state controllers with the cold-start planner on exact scores
(:class:`~decpomdp.search.ExactScorer`), restarting it on independent random streams, and bounds the
optimum from above (:mod:`decpomdp.dpomdp.bounds`): ``gap = (bound - value) / |bound|`` is how far,
at most, the value is from the optimum.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from decpomdp.baselines import random_controllers
from decpomdp.controller import JointController
from decpomdp.dpomdp.best_response import jesp
from decpomdp.dpomdp.bounds import Bounds, upper_bounds
from decpomdp.dpomdp.cyclic import ascend, count_controllers, loop_back
from decpomdp.dpomdp.exact import exact_value
from decpomdp.dpomdp.model import DPOMDPModel
from decpomdp.dpomdp.parser import load_dpomdp
from decpomdp.dpomdp.problems import load_problem, problem_names
from decpomdp.dpomdp.tabular import TabularDecPOSMDP
from hbni_infra.checks import as_float, as_int
from hbni_infra.streams import stream_seed, torch_stream
from hbni_infra.threads import torch_threads
from decpomdp.search import ExactScorer, PlannerConfig, plan

MAX_FINITE_NODES = 32
"""Largest default controller for a finite horizon (``min(max(8, 3 h), 32)`` nodes)."""
INFINITE_UNKNOWNS = 256
"""Size of the linear system (joint nodes x states) that sets an infinite-horizon controller's default node budget:
the most nodes per agent, from 4 to 8, whose joint system has at most this many unknowns (each exact score solves
it, so larger controllers cost much more). GridSmall (16 states) gets 4; Dec-Tiger (2 states) gets 8, where 4
nodes stop at -3.8 and 8 reach 0.22 (seeds 0-2)."""


def infinite_nodes(num_agents: int, num_states: int) -> int:
    """The default node budget of an infinite-horizon controller (see :data:`INFINITE_UNKNOWNS`)."""
    n = 8
    while n > 4 and n**num_agents * num_states > INFINITE_UNKNOWNS:
        n -= 1
    return n


EXACT_DEFAULTS = {"ls_candidates": 500, "ls_lookahead": 0}
"""Planner settings :func:`solve` changes from the cold-start defaults: with exact scores, a local-search
step needs no tens of thousands of candidates to see past noise (each costs an exact evaluation), and the
exact best responses (JESP) take the place of looking through insertions."""


@dataclass
class Solution:
    """What :func:`solve` found.

    Attributes:
        controller: the joint controller (K = 1; node 0 starts), named with the problem's actions and observations.
        value: its exact value from the start belief.
        bound: an upper bound on the optimal value (the smallest of ``bounds``).
        gap: ``(bound - value) / |bound|`` (a zero bound: 0 if met, else inf): the value is within this fraction of the optimum.
        seconds: wall-clock time of the search and the bounds.
        horizon, gamma: the problem solved (``math.inf``: the discounted infinite horizon).
        bounds: the relaxations behind ``bound`` (:class:`~decpomdp.dpomdp.bounds.Bounds`).
        restarts: planner rounds made (round ``r`` plans a free graph while ``r < restarts`` and, at a finite
            horizon, a layered one while ``r < layered_restarts``); ``values`` the exact value every start reached
            (planner runs in order, then JESP's random starts).
    """

    controller: JointController
    value: float
    bound: float
    gap: float
    seconds: float
    horizon: float
    gamma: float
    bounds: Bounds
    restarts: int
    values: list[float] = field(default_factory=list)

    def __repr__(self) -> str:
        h = "inf" if math.isinf(self.horizon) else f"{self.horizon:g}"
        return (
            f"Solution(value={self.value:.6g}, bound={self.bound:.6g}, gap={self.gap:.3%}, horizon={h}, "
            f"gamma={self.gamma:g}, nodes={self.controller.num_nodes}, restarts={self.restarts}, "
            f"seconds={self.seconds:.1f})"
        )


def _problem(problem: Any) -> DPOMDPModel:
    if isinstance(problem, DPOMDPModel):
        return problem
    if isinstance(problem, TabularDecPOSMDP):
        return problem.model
    if isinstance(problem, str) and problem in problem_names():
        return load_problem(problem)
    if isinstance(problem, (str, os.PathLike)):
        path = Path(problem)
        if not path.exists():
            raise FileNotFoundError(
                f"problem: no such file {str(problem)!r} and no shipped problem of that name; "
                f"the shipped problems are {', '.join(problem_names())}"
            )
        return load_dpomdp(path)
    raise TypeError(
        f"problem: expected a shipped problem's name, a .dpomdp path, a DPOMDPModel or a TabularDecPOSMDP, "
        f"got {type(problem).__name__}"
    )


def solve(
    problem: str | os.PathLike | DPOMDPModel | TabularDecPOSMDP,
    horizon: float,
    gamma: float | None = None,
    *,
    seed: int = 0,
    restarts: int = 1,
    layered_restarts: int = 1,
    layer_width: int = 3,
    max_layered_horizon: int = 20,
    jesp_restarts: int = 20,
    best_responses: bool = True,
    time_budget: float | None = None,
    num_nodes: int | None = None,
    threads: int | None = 1,
    **planner: Any,
) -> Solution:
    """Plan a joint controller for ``problem`` and certify how far its value is from the optimum.

    Args:
        problem: a shipped problem's name (:func:`~decpomdp.dpomdp.problem_names`), a ``.dpomdp`` path, a
            parsed :class:`~decpomdp.dpomdp.DPOMDPModel` or a :class:`~decpomdp.dpomdp.TabularDecPOSMDP`.
        horizon: steps ``h >= 1``, or ``math.inf`` for the discounted infinite horizon.
        gamma: discount (``None``: the file's; an infinite horizon needs ``gamma < 1``).
        seed: restart ``r`` plans on the stream ``(seed, "solve", r)``: the same seed, the same solution.
        restarts: planner runs on a free graph of ``num_nodes`` nodes, each from scratch on its own stream; the best
            of all runs is kept. At a finite horizon each result is then improved by exact best responses
            (:func:`~decpomdp.dpomdp.best_response.jesp`).
        layered_restarts: at a finite horizon, planner runs on a layered controller (node 0, then ``h - 1``
            layers of ``layer_width`` nodes: it knows the step, so it can act differently near the end), by
            cross-entropy, up to ``max_layered_horizon`` steps (its graph grows with the horizon).
        layer_width: nodes per layer of a layered controller; 0 skips layered runs.
        jesp_restarts: at a finite horizon, also run JESP from this many random 3-node controllers (on the
            streams ``(seed, "solve", "jesp", k)``); a best response whose beliefs would not fit is skipped.
        best_responses: ``False`` turns exact best responses off (no JESP after each run, no JESP restarts): the
            planner's results alone, as in an ablation.
        time_budget: seconds; when set, restarts go on (beyond ``restarts``) until it is spent, so the
            result then depends on the machine's speed. ``None``: exactly ``restarts`` runs.
        num_nodes: controller nodes per agent (``None``: ``min(max(8, 3 h), 32)``, or :func:`infinite_nodes` for an
            infinite horizon).
        threads: torch's and NumPy BLAS's threads for the whole search (``None``: their current settings).
        **planner: other :class:`~decpomdp.search.PlannerConfig` settings (over :data:`EXACT_DEFAULTS`).

    Returns:
        A :class:`Solution`.
    """
    model = _problem(problem)
    env = TabularDecPOSMDP(model, gamma, horizon=horizon)
    restarts = as_int("restarts", restarts, minimum=1)
    layered_restarts = as_int("layered_restarts", layered_restarts, minimum=0)
    seed = as_int("seed", seed)
    budget = None if time_budget is None else as_float("time_budget", time_budget, 0.0, low_open=True)
    finite = math.isfinite(env.horizon)
    if num_nodes is None:
        num_nodes = (
            min(max(8, 3 * int(env.horizon)), MAX_FINITE_NODES)
            if finite
            else infinite_nodes(env.num_agents, env.num_states)
        )
    config = PlannerConfig(num_nodes=as_int("num_nodes", num_nodes, minimum=1), **{**EXACT_DEFAULTS, **planner})
    start = time.perf_counter()
    jesp_restarts = as_int("jesp_restarts", jesp_restarts, minimum=0)
    if not isinstance(best_responses, bool):
        raise TypeError(f"best_responses: expected True or False, got {best_responses!r}")
    respond = finite and best_responses
    scorer = ExactScorer(env, threads=threads)
    best, values = None, []

    def keep(controller: JointController) -> None:
        nonlocal best
        value = float(exact_value(env, controller)[0])
        if respond:
            controller, value, _ = jesp(env, controller, value)
        values.append(value)
        if best is None or value > best[1]:
            best = (controller, value)

    layer_width = as_int("layer_width", layer_width, minimum=0)
    max_layered_horizon = as_int("max_layered_horizon", max_layered_horizon, minimum=0)
    layered = None
    if finite and layer_width and 1 < env.horizon <= max_layered_horizon:
        size = 1 + layer_width * (int(env.horizon) - 1)
        layered = config.replace(
            num_nodes=size, start_nodes=size, layer_width=layer_width, phases=("ce",), ce_reactive=False
        )
    with torch_threads(threads):  # the whole search, not only its exact scores
        rounds = max(restarts, layered_restarts if layered is not None else 0)
        runs = 0
        while runs < rounds or (budget is not None and time.perf_counter() - start < budget):
            if runs < restarts or runs >= rounds:
                keep(plan(scorer, config, seed=stream_seed(seed, "solve", runs)).best)
            if layered is not None and (runs < layered_restarts or runs >= rounds):
                keep(plan(scorer, layered, seed=stream_seed(seed, "solve", "layered", runs)).best)
            runs += 1
        for k in range(jesp_restarts if respond else 0):
            keep(
                random_controllers(
                    1,
                    num_agents=env.num_agents,
                    num_nodes=3,
                    num_actions=env.num_actions,
                    num_obs=env.num_obs,
                    generator=torch_stream(seed, "solve", "jesp", k),
                )
            )
        bounds = upper_bounds(env)
    controller, value = best
    bound = bounds.best
    if value > bound + 1e-9 * max(1.0, abs(bound)):
        raise RuntimeError(
            f"the bound {bound!r} lies below the value {value!r} of a controller: a bug in decpomdp.dpomdp.bounds"
        )
    gap = max(0.0, bound - value) / abs(bound) if bound else (0.0 if value >= bound else math.inf)
    return Solution(
        controller.named(env.action_names, env.obs_names),
        value,
        bound,
        gap,
        time.perf_counter() - start,
        env.horizon,
        env.gamma,
        bounds,
        runs,
        values,
    )
