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
from decpomdp.dpomdp.gmaa import GMAA, GMAAResult
from decpomdp.dpomdp.model import DPOMDPModel
from decpomdp.dpomdp.parser import load_dpomdp
from decpomdp.dpomdp.problems import load_problem, problem_names
from decpomdp.dpomdp.tabular import TabularDecPOSMDP
from hbni_infra.checks import as_float, as_int, as_seed
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


EXACT_SECONDS = 30.0
"""Default CPU seconds of :func:`solve`'s exact search (GMAA*-ICE) at a finite horizon."""
FIRST_EXACT_SECONDS = 5.0
"""CPU seconds the exact search gets before the planner runs (see :func:`solve`'s ``exact_seconds``)."""
SHORTER_EXACT_SECONDS = 1.0
"""CPU seconds of the exact search at each shorter horizon whose optimum warm-starts JESP when the exact search does
not prove a horizon at once (tried from ``h - 1`` down, until one is proven)."""
LOOP_EXACT_SECONDS = 2.0
"""CPU seconds of the exact search for each finite horizon an infinite-horizon :func:`solve` loops back."""
PROVEN_TOLERANCE = 1e-6
"""A solution is proven optimal when ``bound - value <= PROVEN_TOLERANCE * |value|``."""
LOOP_HORIZONS = (2, 3, 4, 5, 6, 7, 8)
"""Finite horizons whose solutions :func:`solve` loops back into infinite-horizon controllers."""
ASCENT_ROUNDS = 5
"""Most rounds of single changes :func:`solve` makes on an infinite-horizon controller (each round evaluates every
single change of every agent's controller exactly)."""
MAX_ASCENT_NODES = 12
"""Largest controller (nodes per agent) whose single changes :func:`solve` tries at an infinite horizon: each change is
an exact evaluation over up to ``nodes ** agents`` joint nodes, and there are about ``nodes ** 2 * observations`` of
them per agent."""
MAX_ENUMERATED = 20_000
"""Most controllers of one agent coordinate ascent enumerates (3 nodes with 3 actions and 2 observations: 19,683)."""

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
            (planner runs in order, then JESP's random starts; at an infinite horizon: planner runs, loop-backs,
            then coordinate ascent's random starts).
        cpu_seconds: CPU time of the search and the bounds (this process, every thread).
        proven: whether optimality is certified: ``bound - value <= 1e-6 |value|``.
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
    cpu_seconds: float = 0.0

    @property
    def proven(self) -> bool:
        return self.bound - self.value <= PROVEN_TOLERANCE * abs(self.value)

    def __repr__(self) -> str:
        h = "inf" if math.isinf(self.horizon) else f"{self.horizon:g}"
        return (
            f"Solution(value={self.value:.6g}, bound={self.bound:.6g}, gap={self.gap:.3%}, horizon={h}, "
            f"gamma={self.gamma:g}, nodes={self.controller.num_nodes}, restarts={self.restarts}, "
            f"proven={self.proven}, seconds={self.seconds:.1f})"
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


@dataclass(frozen=True)
class _Settings:
    """The search settings of :func:`solve` (checked there)."""

    restarts: int
    layered_restarts: int
    layer_width: int
    max_layered_horizon: int
    jesp_restarts: int
    best_responses: bool
    num_nodes: int | None
    planner: dict


def _finite_search(
    env: TabularDecPOSMDP,
    settings: _Settings,
    seed: int,
    budget: float | None,
    start: float,
    warm: list[JointController] = (),
) -> tuple[JointController, float, list[float], int]:
    """(controller, value, every start's value, rounds) of the planner runs and JESP at ``env``'s finite horizon,
    JESP also starting from each ``warm`` controller."""
    h = int(env.horizon)
    num_nodes = min(max(8, 3 * h), MAX_FINITE_NODES) if settings.num_nodes is None else settings.num_nodes
    config = PlannerConfig(num_nodes=num_nodes, **{**EXACT_DEFAULTS, **settings.planner})
    respond = settings.best_responses
    scorer = ExactScorer(env, threads=None)
    best, values = None, []

    def keep(controller: JointController) -> None:
        nonlocal best
        value = float(exact_value(env, controller)[0])
        if respond:
            controller, value, _ = jesp(env, controller, value)
        values.append(value)
        if best is None or value > best[1]:
            best = (controller, value)

    layered, width = None, settings.layer_width
    if width and 1 < h <= settings.max_layered_horizon:
        size = 1 + width * (h - 1)
        layered = config.replace(num_nodes=size, start_nodes=size, layer_width=width, phases=("ce",), ce_reactive=False)
    restarts, layered_restarts = max(1, settings.restarts), settings.layered_restarts
    rounds = max(restarts, layered_restarts if layered is not None else 0)
    runs = 0
    while runs < rounds or (budget is not None and time.perf_counter() - start < budget):
        if runs < restarts or runs >= rounds:
            keep(plan(scorer, config, seed=stream_seed(seed, "solve", runs)).best)
        if layered is not None and (runs < layered_restarts or runs >= rounds):
            keep(plan(scorer, layered, seed=stream_seed(seed, "solve", "layered", runs)).best)
        runs += 1
    for controller in warm:
        keep(controller)
    for k in range(settings.jesp_restarts if respond else 0):
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
    return best[0], best[1], values, runs


def _exact_and_search(
    env: TabularDecPOSMDP, settings: _Settings, seed: int, budget: float | None, start: float, exact_seconds: float
) -> tuple[JointController, float, list[float], int, GMAAResult | None]:
    """:func:`_finite_search` around the exact search (see :func:`solve`'s ``exact_seconds``); also returns the exact
    search's last result (``None`` if skipped)."""
    exact = GMAA(env) if exact_seconds > 0 else None
    found = None if exact is None else exact.run(min(exact_seconds, FIRST_EXACT_SECONDS))
    if found is not None and found.finished and found.controller is not None:
        return found.controller, found.value, [found.value], 0, found
    shorter = []  # the optimum of the longest shorter horizon the exact search proves at once, and its loop-back
    for h in range(int(env.horizon) - 1, 0, -1) if exact is not None else ():
        short = GMAA(TabularDecPOSMDP(env.model, env.gamma, horizon=h)).run(SHORTER_EXACT_SECONDS)
        if short.finished and short.controller is not None:
            shorter = [short.controller, loop_back(short.controller)]
            break
    controller, value, values, runs = _finite_search(env, settings, seed, budget, start, shorter)
    if exact is not None and exact_seconds > FIRST_EXACT_SECONDS:
        found = exact.run(exact_seconds - FIRST_EXACT_SECONDS, lower_bound=value)
    if found is not None and found.controller is not None and found.value > value:
        controller, value = found.controller, float(exact_value(env, found.controller)[0])
    return controller, value, values, runs, found


def _cyclic_search(
    env: TabularDecPOSMDP,
    settings: _Settings,
    seed: int,
    loop_horizons: tuple[int, ...],
    ascent_nodes: int,
    ascent_starts: int,
) -> tuple[JointController, float, list[float], int]:
    """(controller, value, every start's value, planner runs) at ``env``'s infinite horizon: planner runs on a free
    graph and loop-backs of finite-horizon solutions, each improved by single changes
    (:func:`~decpomdp.dpomdp.cyclic.ascend`) when it has at most :data:`MAX_ASCENT_NODES` nodes, and coordinate ascent
    from random small controllers."""
    starts = []
    if settings.restarts:
        num_nodes = settings.num_nodes or infinite_nodes(env.num_agents, env.num_states)
        config = PlannerConfig(num_nodes=num_nodes, **{**EXACT_DEFAULTS, **settings.planner})
        scorer = ExactScorer(env, threads=None)
        starts += [plan(scorer, config, seed=stream_seed(seed, "solve", r)).best for r in range(settings.restarts)]
    for h in loop_horizons:
        finite = TabularDecPOSMDP(env.model, env.gamma, horizon=h)
        found = _exact_and_search(finite, settings, stream_seed(seed, "loop", h), None, 0.0, LOOP_EXACT_SECONDS)
        starts.append(loop_back(found[0]))
    best, values = None, []
    for controller in starts:
        value = float(exact_value(env, controller)[0])
        if controller.num_nodes <= MAX_ASCENT_NODES:
            controller, value, _ = ascend(env, controller, value, max_rounds=ASCENT_ROUNDS)
        values.append(value)
        if best is None or value > best[1]:
            best = (controller, value)
    enumerable = count_controllers(ascent_nodes, env.num_actions, env.num_obs) <= MAX_ENUMERATED
    for k in range(ascent_starts if enumerable else 0):
        controller = random_controllers(
            1,
            num_agents=env.num_agents,
            num_nodes=ascent_nodes,
            num_actions=env.num_actions,
            num_obs=env.num_obs,
            generator=torch_stream(seed, "solve", "ascent", k),
        )
        controller, value, _ = ascend(env, controller, float(exact_value(env, controller)[0]), ascent_nodes)
        values.append(value)
        if best is None or value > best[1]:
            best = (controller, value)
    if best is None:
        raise ValueError("loop_horizons/ascent_starts/restarts: an infinite horizon needs at least one start")
    return best[0], best[1], values, settings.restarts


def solve(
    problem: str | os.PathLike | DPOMDPModel | TabularDecPOSMDP,
    horizon: float,
    gamma: float | None = None,
    *,
    seed: int = 0,
    restarts: int | None = None,
    layered_restarts: int = 1,
    layer_width: int = 3,
    max_layered_horizon: int = 20,
    jesp_restarts: int = 20,
    best_responses: bool = True,
    loop_horizons: tuple[int, ...] = LOOP_HORIZONS,
    ascent_nodes: int = 3,
    ascent_starts: int = 12,
    time_budget: float | None = None,
    exact_seconds: float = EXACT_SECONDS,
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
            (:func:`~decpomdp.dpomdp.best_response.jesp`). ``None``: 1 at a finite horizon, 0 at an infinite one
            (where loop-backs and coordinate ascent do better, see below).
        layered_restarts: at a finite horizon, planner runs on a layered controller (node 0, then ``h - 1``
            layers of ``layer_width`` nodes: it knows the step, so it can act differently near the end), by
            cross-entropy, up to ``max_layered_horizon`` steps (its graph grows with the horizon).
        layer_width: nodes per layer of a layered controller; 0 skips layered runs.
        jesp_restarts: at a finite horizon, also run JESP from this many random 3-node controllers (on the
            streams ``(seed, "solve", "jesp", k)``); a best response whose beliefs would not fit is skipped.
        best_responses: ``False`` turns exact best responses off (no JESP after each run, no JESP restarts): the
            planner's results alone, as in an ablation.
        loop_horizons: at an infinite horizon, the finite horizons ``h`` whose solutions (searched at the same
            discount, with the settings above) become cyclic controllers that restart every ``h`` steps
            (:func:`~decpomdp.dpomdp.cyclic.loop_back`); the best is then improved by single changes
            (:func:`~decpomdp.dpomdp.cyclic.ascend`).
        ascent_nodes, ascent_starts: at an infinite horizon, coordinate ascent over every ``ascent_nodes``-node
            controller of one agent at a time (an exact best response among them), from ``ascent_starts`` random
            joint controllers (streams ``(seed, "solve", "ascent", k)``); skipped where one agent has more than
            :data:`MAX_ENUMERATED` such controllers.
        exact_seconds: at a finite horizon, CPU seconds for the exact search (GMAA*-ICE, :mod:`decpomdp.dpomdp.gmaa`;
            0 skips it). It runs first for up to :data:`FIRST_EXACT_SECONDS`; if it proves the optimum there, its policy
            is the solution and the planner does not run. Otherwise the planner and JESP run, and the exact search goes on
            for the rest, pruning with their value as a lower bound: it either proves that value optimal, finds a better
            policy, or leaves its open list's bound. So the result depends on the machine's speed only when the exact
            search neither finishes nor is skipped (and then only through its bound or a better policy).
        time_budget: seconds; when set, restarts go on (beyond ``restarts``) until it is spent, so the
            result then depends on the machine's speed. ``None``: exactly ``restarts`` runs.
        num_nodes: controller nodes per agent of the planner's free graph (``None``: ``min(max(8, 3 h), 32)``, or
            :func:`infinite_nodes` for an infinite horizon).
        threads: torch's and NumPy BLAS's threads for the whole search (``None``: their current settings).
        **planner: other :class:`~decpomdp.search.PlannerConfig` settings (over :data:`EXACT_DEFAULTS`).

    Returns:
        A :class:`Solution`.
    """
    model = _problem(problem)
    env = TabularDecPOSMDP(model, gamma, horizon=horizon)
    finite = math.isfinite(env.horizon)
    restarts = (1 if finite else 0) if restarts is None else as_int("restarts", restarts, minimum=1)
    layered_restarts = as_int("layered_restarts", layered_restarts, minimum=0)
    seed = as_seed("seed", seed)
    budget = None if time_budget is None else as_float("time_budget", time_budget, 0.0, low_open=True)
    jesp_restarts = as_int("jesp_restarts", jesp_restarts, minimum=0)
    if not isinstance(best_responses, bool):
        raise TypeError(f"best_responses: expected True or False, got {best_responses!r}")
    loop_horizons = tuple(as_int("loop_horizons", h, minimum=1) for h in loop_horizons)
    ascent_nodes = as_int("ascent_nodes", ascent_nodes, minimum=1)
    ascent_starts = as_int("ascent_starts", ascent_starts, minimum=0)
    layer_width = as_int("layer_width", layer_width, minimum=0)
    max_layered_horizon = as_int("max_layered_horizon", max_layered_horizon, minimum=0)
    if num_nodes is not None:
        num_nodes = as_int("num_nodes", num_nodes, minimum=1)
    settings = _Settings(
        restarts, layered_restarts, layer_width, max_layered_horizon, jesp_restarts, best_responses, num_nodes, planner
    )
    exact_seconds = as_float("exact_seconds", exact_seconds, 0.0)
    start, cpu, found = time.perf_counter(), time.process_time(), None
    with torch_threads(threads):  # the whole search, not only its exact scores
        if finite:
            controller, value, values, runs, found = _exact_and_search(
                env, settings, seed, budget, start, exact_seconds
            )
        else:
            controller, value, values, runs = _cyclic_search(
                env, settings, seed, loop_horizons, ascent_nodes, ascent_starts
            )
        bounds = upper_bounds(env)
    bound = bounds.best if found is None else min(bounds.best, max(found.bound, value))
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
        time.process_time() - cpu,
    )
