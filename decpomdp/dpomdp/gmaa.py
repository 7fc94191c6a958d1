"""Anytime exact search at a finite horizon: GMAA* with incremental clustering and expansion (GMAA*-ICE,
Oliehoek, Spaan, Amato and Whiteson, JAIR 2013).

A partial joint policy fixes every agent's action for every observation history of the first ``t`` steps. Its
histories of step ``t`` are *types*: two histories of one agent whose beliefs over (state, the others' histories)
are equal are merged (lossless clustering; their best continuations are the same). Choosing the step's actions, type
by type, is a collaborative Bayesian game; the search assigns one type's action at a time (incremental expansion), so
a node is (partial policy of ``t`` steps, the first actions of step ``t``). Its priority ``f`` is an upper bound on
every policy below it: the reward of the steps fixed, plus, for step ``t`` and after, the admissible heuristic ``Q``
(:class:`~decpomdp.dpomdp.heuristics.Heuristic`, ``Q_BG`` by default) of each joint type's belief, maximised over the
actions not yet fixed (:func:`stage_bound`).

The search is best-first. A node whose ``f`` is at most the best complete policy found (or a given lower bound)
is dropped. When the open list empties, the best policy is optimal; when the budget runs out, the largest ``f`` in
the open list (or the incumbent, if larger) bounds the optimum. Arrays are numpy float64; type counts stay small
because of the clustering, so the stage tables are dense: ``prob (n_1, ..., n_N, S)``, ``q (n_1, ..., n_N, A_1, ...,
A_N)``.
"""

from __future__ import annotations

import heapq
import itertools
import math
import time
import weakref
from dataclasses import dataclass

import numpy as np
import torch

from decpomdp import budget
from decpomdp.budget import BudgetSpent
from decpomdp.controller import JointController
from decpomdp.dpomdp.heuristics import Heuristic, belief_keys
from decpomdp.dpomdp.tabular import TabularDecPOSMDP

DEFAULT_MAX_OPEN = 500_000
"""Largest open list; beyond it the search stops (reporting the bound reached)."""
ENTRY_BYTES = 200
"""Bytes of one open-list entry besides its stage's tables (the heap's tuple, its actions and numbers)."""


@dataclass
class Stage:
    """A partial joint policy of ``t`` steps: its types at step ``t`` and what they are worth.

    Attributes:
        t: the step.
        prob: ``(n_1, ..., n_N, S)`` joint probability of each joint type and state.
        q: ``(n_1, ..., n_N, A_1, ..., A_N)`` ``gamma ** t P(theta) Q(b_theta, ja)``: the heuristic from step ``t``.
        reward: ``(n_1, ..., n_N, A_1, ..., A_N)`` ``gamma ** t P(theta) R(b_theta, ja)``: step ``t``'s reward.
        past: discounted reward of the steps before ``t``.
        order: the (agent, type) pairs in the order their actions are chosen (agent by agent, likelier types first).
        parent: the stage before (``None`` at step 0); ``rules`` its chosen actions per agent (``(n_i,)`` each);
            ``succ`` per agent ``(n_i of the parent, O)``: the type each parent type moves to after each own
            observation (-1: impossible).
    """

    t: int
    prob: np.ndarray
    q: np.ndarray
    reward: np.ndarray
    past: float
    order: list[tuple[int, int]]
    parent: Stage | None = None
    rules: list[np.ndarray] | None = None
    succ: list[np.ndarray] | None = None


def stage_bound(q: np.ndarray, assigned: list[np.ndarray]) -> float:
    """Upper bound on ``max over step rules of sum_theta q[theta, rule(theta)]`` with some types' actions fixed:
    ``assigned[i] (n_i,)`` holds agent ``i``'s fixed actions (-1: free). Exact when every agent but the last is
    fixed (the last agent's best action is then chosen per type); otherwise each joint type maximises the earlier
    agents' free actions on its own."""
    n = len(assigned)
    x = q
    for i in range(n - 1):  # reduce agent i's action axis: its fixed action, or the max over actions
        axis = n + 0  # after each reduction, agent i's action axis is always at position n
        fixed = assigned[i]
        best = x.max(axis=axis)
        free = fixed < 0
        if not free.all():
            shape = [1] * x.ndim
            shape[i] = fixed.size
            idx = np.where(free, 0, fixed).reshape(shape)
            chosen = np.take_along_axis(x, np.broadcast_to(idx, x.shape[:n] + (1,) + x.shape[n + 1 :]), axis).squeeze(
                axis
            )
            mask = free.reshape([-1 if k == i else 1 for k in range(n)] + [1] * (x.ndim - n - 1))
            x = np.where(mask, best, chosen)
        else:
            x = best
    # x: (n_1, ..., n_N, A_N); the last agent per type
    last = assigned[n - 1]
    per_type = np.moveaxis(x, n - 1, 0).reshape(x.shape[n - 1], -1, x.shape[-1]).sum(1)  # (n_N, A_N)
    fixed = last >= 0
    return float(per_type.max(1)[~fixed].sum() + per_type[np.flatnonzero(fixed), last[fixed]].sum())


def cluster(prob: np.ndarray, num_agents: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """Merge each agent's types whose conditional over (the others' types, state) is equal, and drop types of
    probability zero, until nothing merges. ``prob (n_1, ..., n_N, S)``; returns the clustered table and, per
    agent, each original type's new index (-1: dropped)."""
    maps = [np.arange(prob.shape[i]) for i in range(num_agents)]
    while True:
        changed = False
        for i in range(num_agents):
            rows = np.moveaxis(prob, i, 0).reshape(prob.shape[i], -1)
            mass = rows.sum(1)
            live = np.flatnonzero(mass > 0)
            keys = belief_keys(rows[live] / mass[live, None])
            _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
            inverse = inverse.reshape(-1)
            if first.size == prob.shape[i]:
                continue
            merged = np.zeros((first.size, rows.shape[1]))
            np.add.at(merged, inverse, rows[live])
            new_index = np.full(prob.shape[i], -1)
            new_index[live] = inverse
            maps[i] = np.where(maps[i] >= 0, new_index[np.maximum(maps[i], 0)], -1)
            shape = list(np.moveaxis(prob, i, 0).shape)
            shape[0] = first.size
            prob = np.moveaxis(merged.reshape(shape), 0, i)
            changed = True
        if not changed:
            return prob, maps


PRUNE_TOLERANCE = 1e-9
"""A node is kept only when its bound exceeds the incumbent's value by more than this (relative, at least absolute)."""


def _above(f: float, value: float) -> bool:
    """Whether a bound ``f`` may still beat ``value`` by more than :data:`PRUNE_TOLERANCE`."""
    return value == -math.inf or f > value + PRUNE_TOLERANCE * max(1.0, abs(value))


class GMAA:
    """GMAA*-ICE on ``env`` (finite horizon): :meth:`run` searches until proven or out of budget.

    Args:
        env: the problem at a finite horizon.
        heuristic: ``"bg"`` (``Q_BG``) or ``"pomdp"`` (``Q_POMDP``), see :class:`~decpomdp.dpomdp.heuristics.Heuristic`.
    """

    def __init__(self, env: TabularDecPOSMDP, heuristic: str = "bg") -> None:
        if not isinstance(env, TabularDecPOSMDP):
            raise TypeError(f"env: expected a TabularDecPOSMDP, got {type(env).__name__}")
        if not math.isfinite(env.horizon):
            raise ValueError("env: GMAA* needs a finite horizon")
        self.env = env
        self.heuristic = Heuristic(env, heuristic)
        self.tabs = self.heuristic.tabs
        n, n_act = env.num_agents, env.num_actions
        self._ja = (  # (A, ..., A) the joint action index of every tuple of actions
            np.ravel_multi_index(np.indices((n_act,) * n), (n_act,) * n) if n > 1 else np.arange(n_act)
        )
        parts = np.array(list(itertools.product(range(env.num_obs), repeat=n)))  # (JO, N)
        self._jo_parts = parts
        prob = env.start_dist.numpy().reshape((1,) * n + (-1,))
        self.held = 0  # bytes of the stages' tables alive (each released when its stage is freed)
        self.root = self._stage(0, prob, 0.0)

    def _stage(self, t: int, prob: np.ndarray, past: float, **links) -> Stage:
        env, n = self.env, self.env.num_agents
        types = prob.shape[:n]
        flat = prob.reshape(-1, prob.shape[-1])
        mass = flat.sum(1)
        live = mass > 0
        scale = env.gamma**t
        q = np.zeros((flat.shape[0], self.tabs.reward.shape[0]))
        q[live] = self.heuristic.q(t, flat[live] / mass[live, None]) * mass[live, None] * scale
        reward = flat @ self.tabs.reward.T * scale
        shape = types + (env.num_actions,) * n
        weight = [np.moveaxis(prob, i, 0).reshape(types[i], -1).sum(1) for i in range(n)]
        order = [(i, int(k)) for i in range(n) for k in np.argsort(-weight[i], kind="stable")]
        stage = Stage(t, prob, q[:, self._ja].reshape(shape), reward[:, self._ja].reshape(shape), past, order, **links)
        nbytes = stage.prob.nbytes + stage.q.nbytes + stage.reward.nbytes
        self.held += nbytes
        weakref.finalize(stage, self._release, nbytes)
        return stage

    def _release(self, nbytes: int) -> None:
        self.held -= nbytes

    def _next(self, stage: Stage, rules: list[np.ndarray]) -> tuple[float, Stage | None]:
        """(the value fixed so far, the next stage or ``None`` at the horizon) after ``stage`` with ``rules``."""
        env, n = self.env, self.env.num_agents
        grids = np.meshgrid(*[np.arange(r.size) for r in rules], indexing="ij")
        ja_idx = tuple(rules[i][grids[i]] for i in range(n))
        past = stage.past + float(stage.reward[tuple(grids) + ja_idx].sum())
        if stage.t + 1 >= env.horizon:
            return past, None
        ja = self._ja[ja_idx].reshape(-1)  # per joint type
        flat = stage.prob.reshape(-1, stage.prob.shape[-1])
        trans, _, obs = self.tabs
        nxt = np.zeros((flat.shape[0], obs.shape[2], flat.shape[1]))  # (theta, JO, S')
        for j in np.unique(ja):
            rows = np.flatnonzero(ja == j)
            pred = (trans[j].T @ flat[rows].T).T  # (m, S')
            nxt[rows] = pred[:, None, :] * obs[j].T[None]
        # (n_1, ..., n_N, o_1, ..., o_N, S') -> (n_1, o_1, ..., n_N, o_N, S')
        types = stage.prob.shape[:n]
        table = nxt.reshape(types + (env.num_obs,) * n + (-1,))
        perm = [k for i in range(n) for k in (i, n + i)] + [2 * n]
        table = table.transpose(perm).reshape(tuple(t * env.num_obs for t in types) + (-1,))
        prob, maps = cluster(table, n)
        succ = [maps[i].reshape(types[i], env.num_obs) for i in range(n)]
        return past, self._stage(stage.t + 1, prob, past, parent=stage, rules=rules, succ=succ)

    def _assigned(self, stage: Stage, actions: tuple[int, ...]) -> list[np.ndarray]:
        n = self.env.num_agents
        out = [np.full(stage.prob.shape[i], -1) for i in range(n)]
        for (i, k), a in zip(stage.order, actions):
            out[i][k] = a
        return out

    def run(
        self, time_budget: float = 60.0, lower_bound: float = -math.inf, max_open: int = DEFAULT_MAX_OPEN
    ) -> GMAAResult:
        """Search for at most ``time_budget`` CPU seconds; nodes whose bound is at most ``lower_bound`` (the value of
        a known policy) are dropped. Returns a :class:`GMAAResult`.

        Inside a :class:`~decpomdp.budget.Budget` the search also stops when its time is over, or when its open list
        (the stages' tables and :data:`ENTRY_BYTES` per entry) would exceed its memory; its result then stands as
        after any stop, and the budget is spent."""
        start = time.process_time()
        best_value, best_policy = lower_bound, None
        root_f = self.heuristic.root
        heap = [(-root_f, 0, self.root, ())]
        counter, expanded = 1, 0
        bound = root_f
        while heap:
            neg_f, _, stage, actions = heap[0]
            if not _above(-neg_f, best_value):
                heap = []
                break
            if time.process_time() - start > time_budget or len(heap) > max_open:
                break
            try:
                budget.reserve(self.held + len(heap) * ENTRY_BYTES, "the exact search's open list")
            except BudgetSpent:
                break
            heapq.heappop(heap)
            expanded += 1
            assigned = self._assigned(stage, actions)
            i, k = stage.order[len(actions)]
            for a in range(self.env.num_actions):
                assigned[i][k] = a
                child = actions + (a,)
                if len(child) < len(stage.order):
                    f = stage.past + stage_bound(stage.q, assigned)
                    item = (stage, child)
                else:
                    past, nxt = self._next(stage, [r.copy() for r in assigned])
                    if nxt is None:
                        if past > best_value:
                            best_value, best_policy = past, (stage, [r.copy() for r in assigned])
                        continue
                    f = past + stage_bound(nxt.q, self._assigned(nxt, ()))
                    item = (nxt, ())
                if _above(f, best_value):
                    heapq.heappush(heap, (-f, counter, *item))
                    counter += 1
        open_bound = -heap[0][0] if heap else -math.inf
        bound = max(best_value, open_bound)
        controller = None if best_policy is None else self.controller(*best_policy)
        return GMAAResult(best_value, bound, controller, expanded, time.process_time() - start, not heap)

    def controller(self, stage: Stage, rules: list[np.ndarray]) -> JointController:
        """The complete policy ``rules`` of the last ``stage`` (and the rules above it) as a layered controller: one
        node per type and step, moving to its next type after each own observation."""
        chain = [(stage, rules)]
        while chain[-1][0].parent is not None:
            s = chain[-1][0]
            chain.append((s.parent, s.rules))
        chain.reverse()  # [(stage t, its rules)] for t = 0..h-1
        n, n_obs = self.env.num_agents, self.env.num_obs
        per_agent = []
        for i in range(n):
            sizes = [r[i].size for _, r in chain]
            offsets = np.cumsum([0] + sizes)
            action = np.concatenate([r[i] for _, r in chain])
            nxt = np.zeros((action.size, n_obs), dtype=np.int64)
            for t in range(len(chain)):
                rows = np.arange(offsets[t], offsets[t + 1])
                if t + 1 < len(chain):
                    succ = chain[t + 1][0].succ[i]
                    nxt[rows] = np.where(succ >= 0, offsets[t + 1] + np.maximum(succ, 0), offsets[t + 1])
                else:
                    nxt[rows] = rows[:, None]
            per_agent.append((action, nxt))
        size = max(a.size for a, _ in per_agent)
        act = torch.zeros(1, n, size, dtype=torch.long)
        move = torch.zeros(1, n, size, n_obs, dtype=torch.long)
        for i, (a, x) in enumerate(per_agent):
            act[0, i, : a.size] = torch.as_tensor(a)
            move[0, i, : a.size] = torch.as_tensor(x)
        return JointController(act, move)


@dataclass
class GMAAResult:
    """What :meth:`GMAA.run` found.

    Attributes:
        value: the best complete policy's value (the ``lower_bound`` given, if none beat it).
        bound: an upper bound on the optimum (``value`` when ``finished``).
        controller: the best policy found as a layered joint controller (``None`` if none beat ``lower_bound``).
        expanded: nodes expanded; cpu_seconds: CPU time spent.
        finished: the open list emptied: ``value`` is optimal (or no policy beats ``lower_bound``).
    """

    value: float
    bound: float
    controller: JointController | None
    expanded: int
    cpu_seconds: float
    finished: bool


def gmaa_ice(
    env: TabularDecPOSMDP, time_budget: float = 60.0, lower_bound: float = -math.inf, heuristic: str = "bg"
) -> GMAAResult:
    """GMAA*-ICE on ``env`` for at most ``time_budget`` CPU seconds (see :class:`GMAA`)."""
    return GMAA(env, heuristic).run(time_budget, lower_bound)
