"""Scoring controllers for the planner: any number of rollouts per call, and where controllers go.

A :class:`Scorer` scores K controllers of the *searched* agents (one shared FSC, or one per robot) on
a requested number of rollouts, and counts how often each (agent, node, observation) is traversed.
It also counts every rollout it runs (``rollouts_used``): the planner's budget is a number of
rollouts, so a run is deterministic whatever the machine's load.

* :class:`RolloutScorer`: Monte Carlo rollouts of a :class:`~decpomdp.core.DecPOSMDP` (optionally one
  controller shared by the whole team), on the compiled engine (or the batched torch simulator).
* :class:`ExactScorer`: exact values of a tabular problem (standard error 0); every edge out of a node
  reachable from node 0 counts as traversed once per rollout.

:func:`mean_stderr` is the project's one mean +- standard error of Monte Carlo values.
"""

from __future__ import annotations

from typing import Any, Protocol

import torch
from torch import Tensor

from hbni_infra.checks import as_generator, as_int
from decpomdp.controller import JointController
from decpomdp.core import DecPOSMDP
from decpomdp.domains.rollouts import shared
from decpomdp.dpomdp.exact import DEFAULT_EVAL_BUDGET, exact_value
from decpomdp.dpomdp.tabular import TabularDecPOSMDP
from decpomdp.engine import draw_seed
from decpomdp.engine import run as run_engine
from decpomdp.simulate import check, resolve_backend, simulate

_CHUNK = 200_000  # rollouts per batched torch simulation


def mean_stderr(values: Tensor) -> tuple[Tensor, Tensor]:
    """Mean and standard error (sample sd / sqrt(n)) over the last dimension: ``(..., n)`` -> two ``(...)``."""
    n = values.shape[-1]
    return values.mean(-1), (values.std(-1) / n**0.5 if n > 1 else torch.zeros_like(values[..., 0]))


class Scorer(Protocol):
    """What the planner needs from a problem.

    Attributes:
        num_agents, num_actions, num_obs: sizes of the searched controllers (A, |MA|, O).
        rollouts_used: rollouts run so far (0 for exact scorers).
        exact: whether scores are exact (standard error 0): a score is then never repeated to race candidates.

    A scorer that can score on common random numbers says so with ``common_streams = True`` and takes
    ``common=True`` in ``__call__`` and ``returns(controller, rollouts, generator, common)`` (per-rollout returns,
    float64 (K, rollouts)): rollout ``r`` of every controller then draws from the same stream, chosen by the
    generator's state (two calls with generators in the same state use the same streams).
    """

    exact: bool
    num_agents: int
    num_actions: int
    num_obs: int
    rollouts_used: int

    def __call__(self, controller: JointController, rollouts: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """Mean and standard error, float64 (K,), of each controller over ``rollouts`` rollouts."""
        ...

    def visits(self, controller: JointController, rollouts: int, generator: torch.Generator) -> Tensor:
        """float64 (A, Nn, O): mean number of times per rollout that agent ``a`` in node ``n`` observed ``o``
        (K = 1)."""
        ...


class _NodeTracker(DecPOSMDP):
    """Delegates to ``env`` and counts, per rollout batch, the (agent, node, observation) of every completion."""

    def __init__(self, env: DecPOSMDP, controller: JointController) -> None:
        self.env = env
        self.num_agents, self.num_actions, self.num_obs = env.num_agents, env.num_actions, env.num_obs
        self.gamma, self.horizon = env.gamma, env.horizon
        self.action_names, self.obs_names = env.action_names, env.obs_names
        a, nn = controller.num_agents, controller.num_nodes
        self.next_node = controller.next_node[0].reshape(-1)
        self.offset = torch.arange(a) * nn  # (A,) start of each agent's rows
        self.counts = torch.zeros(a * nn * self.num_obs, dtype=torch.float64)

    def reset(self, batch, generator):
        state = self.env.reset(batch, generator)
        state["_search_node"] = torch.zeros(batch, self.num_agents, dtype=torch.long)
        return state

    def start(self, state, agents, actions, t, end_time, generator):
        return self.env.start(state, agents, actions, t, end_time, generator)

    def complete(self, state, agents, actions, t, generator):
        reward, obs = self.env.complete(state, agents, actions, t, generator)
        node = state["_search_node"]
        row = (self.offset + node) * self.num_obs + obs.clamp(0, self.num_obs - 1)
        self.counts.index_add_(0, row[agents], torch.ones(int(agents.sum()), dtype=torch.float64))
        state["_search_node"] = torch.where(agents, self.next_node[row], node)
        return reward, obs


class RolloutScorer:
    """Monte Carlo scores on ``env``; with ``shared=True`` every robot runs the one searched controller.

    Args:
        env: the Dec-POSMDP (finite horizon).
        shared: search one controller (A = 1) that the whole team runs, instead of one per robot.
        backend: ``"engine"``, ``"torch"`` or ``None`` (the compiled engine where ``env`` is written for it).
    """

    def __init__(self, env: DecPOSMDP, shared: bool = False, backend: str | None = None) -> None:
        if not isinstance(env, DecPOSMDP):
            raise TypeError(f"env: expected a DecPOSMDP, got {type(env).__name__}")
        if not isinstance(shared, bool):
            raise TypeError(f"shared: expected a bool, got {type(shared).__name__}")
        self.env, self.shared, self.backend = env, shared, resolve_backend(env, backend)
        self.num_agents = 1 if shared else env.num_agents
        self.num_actions, self.num_obs = env.num_actions, env.num_obs
        self.rollouts_used, self.exact = 0, False
        self.common_streams = self.backend == "engine"

    def fingerprint(self) -> dict[str, Any]:
        return {
            "class": f"{type(self).__module__}.{type(self).__qualname__}",
            "env": self.env,
            "shared": self.shared,
            "backend": self.backend,
        }

    def team(self, controller: JointController) -> JointController:
        """The joint controller the team runs for searched controllers ``controller``."""
        return shared(controller, self.env.num_agents) if self.shared else controller

    def __call__(
        self, controller: JointController, rollouts: int, generator: torch.Generator, common: bool = False
    ) -> tuple[Tensor, Tensor]:
        return mean_stderr(self.returns(controller, rollouts, generator, common))

    def returns(
        self, controller: JointController, rollouts: int, generator: torch.Generator, common: bool = False
    ) -> Tensor:
        """float64 (K, rollouts) discounted returns; ``common``: every controller on the same streams (engine only)."""
        if not isinstance(controller, JointController):
            raise TypeError(f"controller: expected a JointController, got {type(controller).__name__}")
        rollouts, generator = as_int("rollouts", rollouts, 2), as_generator("generator", generator)
        if common and not self.common_streams:
            raise ValueError("common: common random numbers need the compiled engine (backend='engine')")
        if self.backend == "engine":
            check(self.env, self.team(controller))
            seed = draw_seed(generator)
            returns = run_engine(self.env, self.team(controller), rollouts, seed, common_streams=common).returns
        else:
            per = max(1, _CHUNK // rollouts)
            returns = torch.cat(
                [
                    simulate(self.env, self.team(controller[i : i + per]), rollouts, generator, "torch")
                    for i in range(0, controller.num_controllers, per)
                ]
            )
        self.rollouts_used += returns.numel()
        return returns

    def visits(self, controller: JointController, rollouts: int, generator: torch.Generator) -> Tensor:
        rollouts, generator = as_int("rollouts", rollouts, 1), as_generator("generator", generator)
        team = self.team(controller[0])
        if self.backend == "engine":
            counts = run_engine(self.env, team, rollouts, draw_seed(generator), visits=True).visits / rollouts
        else:
            tracker = _NodeTracker(self.env, team)
            simulate(tracker, team, rollouts, generator, "torch")
            counts = tracker.counts.view(team.num_agents, team.num_nodes, self.num_obs) / rollouts
        self.rollouts_used += rollouts
        return counts.sum(0, keepdim=True) if self.shared else counts


class ExactScorer:
    """Exact values of a tabular problem (:func:`~decpomdp.dpomdp.exact_value`) with zero standard errors;
    ``rollouts`` is ignored, and every edge out of a node reachable from node 0 (through any observations)
    counts as visited once.

    Args:
        env: the tabular problem.
        horizon: overrides ``env.horizon`` (None keeps it; ``math.inf``: the discounted infinite horizon).
        memory_budget, threads: per call, see :func:`~decpomdp.dpomdp.exact_value`.
    """

    def __init__(
        self,
        env: TabularDecPOSMDP,
        horizon: float | None = None,
        memory_budget: int = DEFAULT_EVAL_BUDGET,
        threads: int | None = 1,
    ) -> None:
        if not isinstance(env, TabularDecPOSMDP):
            raise TypeError(f"env: expected a TabularDecPOSMDP, got {type(env).__name__}")
        self.env, self.horizon, self.memory_budget, self.threads = env, horizon, memory_budget, threads
        self.exact = True
        self.num_agents, self.num_actions, self.num_obs = env.num_agents, env.num_actions, env.num_obs
        self.rollouts_used = 0

    def fingerprint(self) -> dict[str, Any]:
        return {"class": f"{type(self).__module__}.{type(self).__qualname__}", "env": self.env, "horizon": self.horizon}

    def __call__(self, controller: JointController, rollouts: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        mean = exact_value(
            self.env, controller, self.horizon, memory_budget=self.memory_budget, threads=self.threads
        ).to(torch.float64)
        return mean, torch.zeros_like(mean)

    def visits(self, controller: JointController, rollouts: int, generator: torch.Generator) -> Tensor:
        return reachable(controller)[..., None].to(torch.float64).expand(-1, -1, self.num_obs).clone()


def reachable(controller: JointController) -> Tensor:
    """bool (A, Nn): the nodes of each agent's graph (K = 1) reachable from node 0 through any observations."""
    nxt = controller.next_node[0]  # (A, Nn, O)
    a, nn, _ = nxt.shape
    seen = torch.zeros(a, nn, dtype=torch.bool)
    seen[:, 0] = True
    for _ in range(nn):
        hits = seen[..., None].expand_as(nxt).reshape(a, -1).long()
        grown = seen | (torch.zeros(a, nn, dtype=torch.long).scatter_add_(1, nxt.reshape(a, -1), hits) > 0)
        if torch.equal(grown, seen):
            break
        seen = grown
    return seen
