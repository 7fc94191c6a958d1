"""One call from a ``.dpomdp`` problem to a policy, its exact value and a certified gap.

:func:`solve` plans joint finite-state controllers with the cold-start planner on exact scores
(:class:`~decpomdp.search.ExactScorer`), restarting it on independent random streams, and bounds the
optimum from above (:mod:`decpomdp.dpomdp.bounds`): ``gap = (bound - value) / |bound|`` is how far,
at most, the value is from the optimum. It runs within a time and a memory budget
(:class:`~decpomdp.budget.Budget`); when one ends, the best controller found so far is the solution, with its
bound.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import math
import numbers
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from decpomdp.baselines import random_controllers
from decpomdp.budget import Budget, BudgetSpent, check, current
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

TIME_BUDGET = 600.0
"""Default wall-clock seconds of :func:`solve`: ten times the longest default solve of the benchmark table on a
2-core machine (GridSmall's infinite horizon, about 80 s), so that no published row is cut."""
MEMORY_BUDGET = 4 * 2**30
"""Default memory budget of :func:`solve` in bytes (4 GiB): the largest table any part of the search may build (an
exact evaluation's chunk, a best response's belief layer, the exact search's open list); the benchmark table's rows
need under 1.5 GiB in all."""
MAX_HORIZON = 1000
"""Longest finite horizon :func:`solve` takes: an exact evaluation walks every step, and a layered controller has a
layer per step, so the work and memory of one evaluation grow with it. Beyond it, the discounted infinite horizon
(``math.inf``, ``gamma < 1``) is the model of a long task."""
BOUNDS_SHARE = 0.25
"""Most of the time budget the bounds may take before the search (they stop early, still valid, when it is spent)."""
SHORTER_HORIZONS = 10
"""Most shorter horizons (from ``h - 1`` down) whose exact search :func:`solve` tries for a warm start."""

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
        bound: an upper bound on the optimal value (the smallest of ``bounds``, and the exact search's).
        gap: ``(bound - value) / |bound|`` (a zero bound: 0 if met, else inf): the value is within this fraction of the optimum.
        seconds: wall-clock time of the search and the bounds.
        horizon, gamma: the problem solved (``math.inf``: the discounted infinite horizon).
        bounds: the relaxations behind ``bound`` (:class:`~decpomdp.dpomdp.bounds.Bounds`).
        restarts: planner rounds made (round ``r`` plans a free graph while ``r < restarts`` and, at a finite
            horizon, a layered one while ``r < layered_restarts``); ``values`` the exact value every start reached
            (planner runs in order, then JESP's random starts; at an infinite horizon: planner runs, loop-backs,
            then coordinate ascent's random starts).
        cpu_seconds: CPU time of the search and the bounds (this process, every thread).
        budget_ended: ``None`` when the search ran to its end; ``"time"`` or ``"memory"`` when that budget ended it
            (the controller is then the best found before, and ``bound`` still holds).
        budget_note: where the budget ended and what ran out (``""`` when it did not).
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
    budget_ended: str | None = None
    budget_note: str = ""

    @property
    def proven(self) -> bool:
        return self.bound - self.value <= PROVEN_TOLERANCE * abs(self.value)

    def __repr__(self) -> str:
        h = "inf" if math.isinf(self.horizon) else f"{self.horizon:g}"
        ended = "" if self.budget_ended is None else f", budget_ended={self.budget_ended!r}"
        return (
            f"Solution(value={self.value:.6g}, bound={self.bound:.6g}, gap={self.gap:.3%}, horizon={h}, "
            f"gamma={self.gamma:g}, nodes={self.controller.num_nodes}, restarts={self.restarts}, "
            f"proven={self.proven}{ended}, seconds={self.seconds:.1f})"
        )


def _problem(problem: Any) -> DPOMDPModel:
    if isinstance(problem, DPOMDPModel):
        return problem
    if isinstance(problem, TabularDecPOSMDP):
        return problem.model
    shipped = ", ".join(problem_names())
    if isinstance(problem, str) and not problem.strip():
        raise ValueError(
            f"problem: expected a shipped problem's name or a .dpomdp path, got an empty name; the shipped problems "
            f"are {shipped}"
        )
    if isinstance(problem, str) and problem in problem_names():
        return load_problem(problem)
    if isinstance(problem, (str, os.PathLike)):
        path = Path(problem)
        if not path.exists():
            raise FileNotFoundError(
                f"problem: no such file {str(problem)!r} and no shipped problem of that name; "
                f"the shipped problems are {shipped}"
            )
        return load_dpomdp(path)
    raise TypeError(
        f"problem: expected a shipped problem's name, a .dpomdp path, a DPOMDPModel or a TabularDecPOSMDP, "
        f"got {type(problem).__name__}"
    )


def _horizon(horizon: Any) -> float:
    """``horizon`` checked: a whole number of steps in ``[1, MAX_HORIZON]`` or ``math.inf``."""
    if isinstance(horizon, torch.Tensor) and horizon.dim() == 0:
        horizon = horizon.item()
    if isinstance(horizon, bool) or not isinstance(horizon, numbers.Real):
        raise TypeError(
            f"horizon: expected a whole number of steps (int) or math.inf, got {horizon!r} ({type(horizon).__name__})"
        )
    horizon = float(horizon)
    if horizon == math.inf:
        return horizon
    if not (math.isfinite(horizon) and horizon.is_integer() and 1 <= horizon <= MAX_HORIZON):
        raise ValueError(
            f"horizon: expected a whole number of steps in [1, {MAX_HORIZON}] or math.inf (the discounted infinite "
            f"horizon, with gamma < 1), got {horizon:g}"
        )
    return horizon


def _planner_settings(planner: dict[str, Any], num_nodes: int) -> dict[str, Any]:
    """``planner`` checked: every key a :class:`~decpomdp.search.PlannerConfig` field (else a ``TypeError`` naming it and
    the nearest keywords), every value valid for it (a :class:`PlannerConfig` is built from them)."""
    fields = [f.name for f in dataclasses.fields(PlannerConfig)]
    own = [name for name in inspect.signature(solve).parameters if name not in ("problem", "horizon", "planner")]
    for key in planner:
        if key not in fields:
            near = difflib.get_close_matches(key, own + fields, n=3, cutoff=0.6)
            hint = f"; did you mean {' or '.join(map(repr, near))}?" if near else ""
            raise TypeError(
                f"solve() got an unexpected keyword argument {key!r}{hint} (solve takes its own settings and the "
                f"fields of decpomdp.search.PlannerConfig)"
            )
    PlannerConfig(num_nodes=num_nodes, **{**EXACT_DEFAULTS, **planner})
    return dict(planner)


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


@dataclass
class _Found:
    """What a search found so far: its best controller and value, every start's value, the planner rounds made and
    the exact search's last result."""

    controller: JointController | None = None
    value: float = -math.inf
    values: list[float] = field(default_factory=list)
    runs: int = 0
    exact: GMAAResult | None = None

    def offer(self, controller: JointController, value: float, count: bool = True) -> None:
        """Keep ``controller`` if its exact ``value`` beats the best; ``count``: list the value in ``values``."""
        if count:
            self.values.append(value)
        if self.controller is None or value > self.value:
            self.controller, self.value = controller, value
            budget = current()
            if budget is not None:
                budget.note(value=value)


def _repeaters(env: TabularDecPOSMDP) -> tuple[JointController, float]:
    """The best one-node joint controller (every agent repeats one action), by exact value: the solution before any
    search."""
    joint = torch.cartesian_prod(*[torch.arange(env.num_actions)] * env.num_agents).reshape(-1, env.num_agents)
    controller = JointController(
        joint[:, :, None], torch.zeros(joint.shape[0], env.num_agents, 1, env.num_obs, dtype=torch.long)
    )
    values = exact_value(env, controller)
    best = int(values.argmax())
    return controller[best], float(values[best])


def _finite_search(
    env: TabularDecPOSMDP,
    settings: _Settings,
    seed: int,
    found: _Found,
    warm: list[JointController] = (),
    keep_restarting: bool = False,
) -> None:
    """The planner runs and JESP at ``env``'s finite horizon (JESP also from each ``warm`` controller), into ``found``;
    with ``keep_restarting``, planner rounds then go on until the running budget ends."""
    h = int(env.horizon)
    num_nodes = min(max(8, 3 * h), MAX_FINITE_NODES) if settings.num_nodes is None else settings.num_nodes
    config = PlannerConfig(num_nodes=num_nodes, **{**EXACT_DEFAULTS, **settings.planner})
    respond = settings.best_responses
    scorer = ExactScorer(env, threads=None)

    def keep(controller: JointController) -> None:
        value = float(exact_value(env, controller)[0])
        found.offer(controller, value, count=not respond)
        if respond:
            controller, value, _ = jesp(env, controller, value)
            found.offer(controller, value)

    layered, width = None, settings.layer_width
    if width and 1 < h <= settings.max_layered_horizon:
        size = 1 + width * (h - 1)
        layered = config.replace(num_nodes=size, start_nodes=size, layer_width=width, phases=("ce",), ce_reactive=False)
    restarts, layered_restarts = max(1, settings.restarts), settings.layered_restarts
    rounds = max(restarts, layered_restarts if layered is not None else 0)

    def round_(r: int, extra: bool) -> None:
        current().phase(f"planner round {r + 1}")
        if r < restarts or extra:
            keep(plan(scorer, config, seed=stream_seed(seed, "solve", r)).best)
        if layered is not None and (r < layered_restarts or extra):
            keep(plan(scorer, layered, seed=stream_seed(seed, "solve", "layered", r)).best)
        found.runs = r + 1

    for r in range(rounds):
        round_(r, False)
    current().phase("JESP")
    for controller in warm:
        keep(controller)
    for k in range(settings.jesp_restarts if respond else 0):
        check()
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
    r = rounds
    while keep_restarting:  # ends when the budget does
        round_(r, True)
        r += 1


def _exact_and_search(
    env: TabularDecPOSMDP,
    settings: _Settings,
    seed: int,
    exact_seconds: float,
    found: _Found,
    keep_restarting: bool = False,
) -> None:
    """:func:`_finite_search` around the exact search (see :func:`solve`'s ``exact_seconds``), into ``found``."""
    budget = current()
    budget.phase("exact search")
    exact = GMAA(env) if exact_seconds > 0 else None
    if exact is not None:
        found.exact = exact.run(min(exact_seconds, FIRST_EXACT_SECONDS))
        if found.exact.controller is not None and found.exact.finished:
            found.offer(found.exact.controller, found.exact.value)
            return
        if found.exact.controller is not None:
            found.offer(found.exact.controller, float(exact_value(env, found.exact.controller)[0]), count=False)
    shorter = []  # the optimum of the longest shorter horizon the exact search proves at once, and its loop-back
    h = int(env.horizon)
    for k in range(h - 1, max(0, h - 1 - SHORTER_HORIZONS), -1) if exact is not None else ():
        budget.phase(f"exact search at horizon {k}")
        short = GMAA(TabularDecPOSMDP(env.model, env.gamma, horizon=k)).run(SHORTER_EXACT_SECONDS)
        if short.finished and short.controller is not None:
            shorter = [short.controller, loop_back(short.controller)]
            break
    searched = len(found.values)
    _finite_search(env, settings, seed, found, shorter, keep_restarting)
    if exact is not None and exact_seconds > FIRST_EXACT_SECONDS:
        check()
        budget.phase("exact search")
        later = exact.run(exact_seconds - FIRST_EXACT_SECONDS, lower_bound=max(found.values[searched:]))
        found.exact = later
        if later.controller is not None and later.value > found.value:
            found.offer(later.controller, float(exact_value(env, later.controller)[0]), count=False)


def _cyclic_search(
    env: TabularDecPOSMDP,
    settings: _Settings,
    seed: int,
    loop_horizons: tuple[int, ...],
    ascent_nodes: int,
    ascent_starts: int,
    found: _Found,
) -> None:
    """Planner runs on a free graph and loop-backs of finite-horizon solutions at ``env``'s infinite horizon, each
    improved by single changes (:func:`~decpomdp.dpomdp.cyclic.ascend`) when it has at most :data:`MAX_ASCENT_NODES`
    nodes, and coordinate ascent from random small controllers; into ``found``."""
    budget = current()

    def improve(controller: JointController) -> None:
        value = float(exact_value(env, controller)[0])
        found.offer(controller, value, count=False)
        if controller.num_nodes <= MAX_ASCENT_NODES:
            controller, value, _ = ascend(env, controller, value, max_rounds=ASCENT_ROUNDS)
        found.offer(controller, value)

    if settings.restarts:
        num_nodes = settings.num_nodes or infinite_nodes(env.num_agents, env.num_states)
        config = PlannerConfig(num_nodes=num_nodes, **{**EXACT_DEFAULTS, **settings.planner})
        scorer = ExactScorer(env, threads=None)
        for r in range(settings.restarts):
            budget.phase(f"planner round {r + 1}")
            improve(plan(scorer, config, seed=stream_seed(seed, "solve", r)).best)
            found.runs = r + 1
    for h in loop_horizons:
        budget.phase(f"loop-back of horizon {h}")
        finite, part = TabularDecPOSMDP(env.model, env.gamma, horizon=h), _Found()
        _exact_and_search(finite, settings, stream_seed(seed, "loop", h), LOOP_EXACT_SECONDS, part)
        check()
        budget.phase(f"loop-back of horizon {h}")
        improve(loop_back(part.controller))
    budget.phase("coordinate ascent")
    for k in range(ascent_starts if _enumerable(env, ascent_nodes) else 0):
        check()
        controller = random_controllers(
            1,
            num_agents=env.num_agents,
            num_nodes=ascent_nodes,
            num_actions=env.num_actions,
            num_obs=env.num_obs,
            generator=torch_stream(seed, "solve", "ascent", k),
        )
        controller, value, _ = ascend(env, controller, float(exact_value(env, controller)[0]), ascent_nodes)
        found.offer(controller, value)


def _enumerable(env: TabularDecPOSMDP, ascent_nodes: int) -> bool:
    return count_controllers(ascent_nodes, env.num_actions, env.num_obs) <= MAX_ENUMERATED


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
    time_budget: float | None = TIME_BUDGET,
    memory_budget: int | None = MEMORY_BUDGET,
    keep_restarting: bool = False,
    exact_seconds: float = EXACT_SECONDS,
    num_nodes: int | None = None,
    threads: int | None = 1,
    progress: bool | None = None,
    **planner: Any,
) -> Solution:
    """Plan a joint controller for ``problem`` and certify how far its value is from the optimum, within a time and a
    memory budget.

    Args:
        problem: a shipped problem's name (:func:`~decpomdp.dpomdp.problem_names`), a ``.dpomdp`` path, a
            parsed :class:`~decpomdp.dpomdp.DPOMDPModel` or a :class:`~decpomdp.dpomdp.TabularDecPOSMDP`.
        horizon: steps ``h``, a whole number in ``[1, MAX_HORIZON]``, or ``math.inf`` for the discounted infinite
            horizon.
        gamma: discount in (0, 1] (``None``: the ``TabularDecPOSMDP``'s, else the file's); an infinite horizon
            needs ``gamma < 1``.
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
        time_budget: wall-clock seconds the whole solve may take (default :data:`TIME_BUDGET`; ``None``: no limit).
            When they are spent the search stops where it is (every loop checks), and the best controller found so
            far is the solution, with ``budget_ended="time"``. Before the search, the best one-node controller is
            evaluated and the bounds computed (these always run; the bounds stop early, still valid, after
            :data:`BOUNDS_SHARE` of the time), so a solution always has a controller and a bound.
        memory_budget: bytes the largest table of the search may take (default :data:`MEMORY_BUDGET`; ``None``: no
            limit). Every exact evaluation, best response's belief layer and the exact search's open list is
            estimated before it is allocated; one that would exceed the budget ends the search as the time does
            (``budget_ended="memory"``, ``budget_note`` names it). Belief trees whose depth is a choice (the bounds'
            and the exact search's heuristic) are built to fit it.
        keep_restarting: after the search, planner rounds (free and layered) go on from new streams until the time
            budget ends (needs a ``time_budget``; the result then depends on the machine's speed).
        exact_seconds: at a finite horizon, CPU seconds for the exact search (GMAA*-ICE, :mod:`decpomdp.dpomdp.gmaa`;
            0 skips it). It runs first for up to :data:`FIRST_EXACT_SECONDS`; if it proves the optimum there, its policy
            is the solution and the planner does not run. Otherwise the planner and JESP run (JESP also from the
            optimum of the longest of the :data:`SHORTER_HORIZONS` shorter horizons that the exact search proves at
            once), and the exact search goes on for the rest, pruning with their value as a lower bound: it either
            proves that value optimal, finds a better policy, or leaves its open list's bound. So the result depends on
            the machine's speed only when the exact search neither finishes nor is skipped (and then only through its
            bound or a better policy), or when a budget ends the search.
        num_nodes: controller nodes per agent of the planner's free graph (``None``: ``min(max(8, 3 h), 32)``, or
            :func:`infinite_nodes` for an infinite horizon).
        threads: torch's and NumPy BLAS's threads for the whole search (``None``: their current settings).
        progress: show a progress bar over the time budget, with the part running and the best value (``None``: where
            stderr is a terminal; it appears after a second).
        **planner: other :class:`~decpomdp.search.PlannerConfig` settings (over :data:`EXACT_DEFAULTS`); a name that
            is not one is a ``TypeError`` naming the nearest.

    Returns:
        A :class:`Solution`.

    Raises:
        TypeError, ValueError: an argument of the wrong type or value (the message names it), before any work.
    """
    model = _problem(problem)
    horizon = _horizon(horizon)
    if gamma is None and isinstance(problem, TabularDecPOSMDP):
        gamma = problem.gamma
    if gamma is not None:
        gamma = as_float("gamma", gamma, 0.0, 1.0, low_open=True)
    if horizon == math.inf and (model.discount if gamma is None else gamma) >= 1.0:
        raise ValueError(
            f"horizon: an infinite horizon needs gamma < 1 (it is discounted), got gamma "
            f"{model.discount if gamma is None else gamma:g}{' (the file discount)' if gamma is None else ''}"
        )
    env = TabularDecPOSMDP(model, gamma, horizon=horizon)
    finite = math.isfinite(env.horizon)
    restarts = (1 if finite else 0) if restarts is None else as_int("restarts", restarts, minimum=1)
    layered_restarts = as_int("layered_restarts", layered_restarts, minimum=0)
    seed = as_seed("seed", seed)
    if time_budget is not None:
        time_budget = as_float("time_budget", time_budget, 0.0, low_open=True)
    if memory_budget is not None:
        memory_budget = as_int("memory_budget", memory_budget, minimum=1)
    for name, flag in (("best_responses", best_responses), ("keep_restarting", keep_restarting)):
        if not isinstance(flag, bool):
            raise TypeError(f"{name}: expected True or False, got {flag!r}")
    if progress is not None and not isinstance(progress, bool):
        raise TypeError(f"progress: expected True, False or None, got {progress!r}")
    if keep_restarting and time_budget is None:
        raise ValueError("keep_restarting: restarts go on until the time budget ends, so it needs a time_budget")
    if isinstance(loop_horizons, (str, bytes)) or not hasattr(loop_horizons, "__iter__"):
        raise TypeError(f"loop_horizons: expected a sequence of horizons, got {loop_horizons!r}")
    loop_horizons = tuple(as_int("loop_horizons", h, minimum=1) for h in loop_horizons)
    if any(h > MAX_HORIZON for h in loop_horizons):
        raise ValueError(f"loop_horizons: expected horizons in [1, {MAX_HORIZON}], got {list(loop_horizons)}")
    jesp_restarts = as_int("jesp_restarts", jesp_restarts, minimum=0)
    ascent_nodes = as_int("ascent_nodes", ascent_nodes, minimum=1)
    ascent_starts = as_int("ascent_starts", ascent_starts, minimum=0)
    layer_width = as_int("layer_width", layer_width, minimum=0)
    max_layered_horizon = as_int("max_layered_horizon", max_layered_horizon, minimum=0)
    if num_nodes is not None:
        num_nodes = as_int("num_nodes", num_nodes, minimum=1)
    exact_seconds = as_float("exact_seconds", exact_seconds, 0.0)
    if threads is not None:
        threads = as_int("threads", threads, minimum=1)
    default_nodes = (
        min(max(8, 3 * int(env.horizon)), MAX_FINITE_NODES)
        if finite
        else infinite_nodes(env.num_agents, env.num_states)
    )
    planner = _planner_settings(planner, num_nodes or default_nodes)
    if not finite and not (restarts or loop_horizons or (ascent_starts and _enumerable(env, ascent_nodes))):
        raise ValueError("loop_horizons/ascent_starts/restarts: an infinite horizon needs at least one start")
    settings = _Settings(
        restarts, layered_restarts, layer_width, max_layered_horizon, jesp_restarts, best_responses, num_nodes, planner
    )
    start, cpu = time.perf_counter(), time.process_time()
    found, ended = _Found(), None
    with torch_threads(threads):  # the whole search, not only its exact scores
        fallback = _repeaters(env)
        with Budget(time_budget, memory_budget, progress, desc="bounds") as budget:
            with Budget(None if time_budget is None else BOUNDS_SHARE * time_budget, memory_budget, False):
                bounds = upper_bounds(env)
            budget.note(value=fallback[1], bound=bounds.best)
            try:
                budget.check()
                if finite:
                    _exact_and_search(env, settings, seed, exact_seconds, found, keep_restarting)
                else:
                    _cyclic_search(env, settings, seed, loop_horizons, ascent_nodes, ascent_starts, found)
            except BudgetSpent as exc:
                ended = exc
    controller, value = (found.controller, found.value) if found.value >= fallback[1] else fallback
    bound = bounds.best if found.exact is None else min(bounds.best, max(found.exact.bound, value))
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
        found.runs,
        found.values,
        time.process_time() - cpu,
        None if ended is None else ended.resource,
        "" if ended is None else ended.detail,
    )
