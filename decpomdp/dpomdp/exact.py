"""Exact values of joint finite-state controllers on a tabular Dec-POMDP.

For K joint controllers the (joint node q, state s) pairs form a Markov chain; with
``r[q, s] = R(s, a(q))`` the values solve ``V = r + gamma P V`` with the factored backup ``P`` of
:mod:`decpomdp.dpomdp.backup` (no S x S' x joint-observation tensor). Only joint nodes reachable
from the start node ``(0, ..., 0)`` are ever touched:

* finite horizon ``h``: the joint nodes reachable at each step ``t`` are found forwards (for a
  layered controller, only the current layer's), then ``V_t = r + gamma P V_{t+1}`` backwards over
  exactly those (``V_h = 0``);
* infinite horizon, ``gamma < 1``: over all reachable joint nodes, the system
  ``(I - gamma P) V = r`` is solved densely (``torch.linalg.solve``) when every controller's system has
  at most ``max_dense`` unknowns, and otherwise by restarted GMRES on the factored operator (batched
  over controllers) until the residual guarantees ``max |V - V*| <= tol``.

The value is ``sum_s b0(s) V[(0, ..., 0), s]``: step ``k`` rewards discounted by ``gamma ** k``, the
same convention as :class:`~decpomdp.dpomdp.tabular.TabularDecPOSMDP` under the simulator. Everything
is float64, on the device of the controller (or ``device=``); controllers are processed in chunks whose working
memory stays within ``memory_budget``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from decpomdp import budget
from decpomdp.controller import JointController
from decpomdp.dpomdp.backup import Columns, JointNodes, TransitionOperator, link, operator_for
from decpomdp.dpomdp.krylov import gmres
from decpomdp.dpomdp.tabular import TabularDecPOSMDP
from hbni_infra.threads import torch_threads

DEFAULT_EVAL_BUDGET = 512 * 1024**2
"""Default working memory of :func:`exact_value`, bytes (512 MiB)."""
_GMRES_RESTART = 30


def _check(env: TabularDecPOSMDP, controller: JointController, horizon: float | None) -> float:
    if not isinstance(env, TabularDecPOSMDP):
        raise TypeError(f"env: expected a TabularDecPOSMDP, got {type(env).__name__}")
    if not isinstance(controller, JointController):
        raise TypeError(f"controller: expected a JointController, got {type(controller).__name__}")
    if (controller.num_agents, controller.num_obs) != (env.num_agents, env.num_obs):
        raise ValueError(
            f"controller: has {controller.num_agents} agents / {controller.num_obs} observations, "
            f"env has {env.num_agents} / {env.num_obs}"
        )
    if int(controller.action.max()) >= env.num_actions:
        raise ValueError(f"controller: action entries must lie in [0, {env.num_actions})")
    horizon = env.horizon if horizon is None else float(horizon)
    if horizon == math.inf and env.gamma >= 1.0:
        raise ValueError("horizon: an infinite horizon needs gamma < 1")
    if horizon != math.inf and not (horizon.is_integer() and horizon >= 1):
        raise ValueError(f"horizon: expected a whole number of steps >= 1 or math.inf, got {horizon}")
    return horizon


def _finite(op: TransitionOperator, nodes: JointNodes, k: int, horizon: int, gamma: float, start: Tensor) -> Tensor:
    """Values (K,) at a finite horizon, over the joint nodes reachable at each step."""
    layers = []
    ids = torch.arange(k, device=nodes.device) * nodes.num_joint  # start node (0, ..., 0) of every controller
    for t in range(horizon):
        budget.check()
        cols = nodes.columns(ids)
        layers.append(cols)
        if t + 1 < horizon:
            ids = torch.unique(cols.next_ids)
    v = None
    for t in reversed(range(horizon)):
        budget.check()
        cols = layers[t]
        r = op.reward.index_select(0, cols.action)
        if v is None:
            v = r
        else:
            link(cols, layers[t + 1], k * nodes.num_joint)
            v = r.add_(op.backup(v, cols), alpha=gamma)
    order = torch.argsort(layers[0].ids)  # back to controller order
    return v[order] @ start


def _reachable(nodes: JointNodes, k: int) -> Columns:
    """All columns reachable from the start nodes, linked to themselves."""
    seen = torch.zeros(k * nodes.num_joint, dtype=torch.bool, device=nodes.device)
    frontier = torch.arange(k, device=nodes.device) * nodes.num_joint
    seen[frontier] = True
    while frontier.numel():
        nxt = torch.unique(nodes.columns(frontier).next_ids)
        frontier = nxt[~seen[nxt]]
        seen[frontier] = True
    cols = nodes.columns(seen.nonzero().squeeze(1))
    link(cols, cols, k * nodes.num_joint)
    return cols


def _dense_solve(op: TransitionOperator, cols: Columns, owner: Tensor, k: int, gamma: float) -> Tensor:
    """Solve ``(I - gamma P) V = r`` per controller as a dense system; returns V (C, S)."""
    n_s, dev = op.num_states, op.device
    count = torch.bincount(owner, minlength=k)
    first = torch.cumsum(count, 0) - count
    by_id = torch.argsort(cols.ids)  # ids k * Q + q group the columns by controller
    local = torch.empty_like(owner)
    local[by_id] = torch.arange(owner.numel(), device=dev) - first[owner[by_id]]  # column index within its controller
    n = int(count.max()) * n_s
    m = torch.zeros(k, n, n, dtype=torch.float64, device=dev)
    arange_s = torch.arange(n_s, device=dev)
    rows = (local[:, None] * n_s + arange_s).reshape(-1)  # (C * S,)
    for a, lo, hi in cols.groups:
        t_a = op.dense(a)
        for jo in range(op.num_joint_obs):
            block = t_a * op.obs_rows[a * op.num_joint_obs + jo][None, :]  # (S, S')
            tgt = local[cols.next[lo:hi, jo]]
            r_idx = (local[lo:hi, None, None] * n_s + arange_s[None, :, None]).expand(-1, n_s, n_s)
            c_idx = (tgt[:, None, None] * n_s + arange_s[None, None, :]).expand(-1, n_s, n_s)
            m.index_put_(
                (owner[lo:hi, None, None].expand(-1, n_s, n_s), r_idx, c_idx),
                block.expand(hi - lo, -1, -1),
                accumulate=True,
            )
    lhs = torch.eye(n, dtype=torch.float64, device=dev) - gamma * m
    rhs = torch.zeros(k, n, dtype=torch.float64, device=dev)
    rhs[owner.repeat_interleave(n_s), rows] = op.reward.index_select(0, cols.action).reshape(-1)
    sol = torch.linalg.solve(lhs, rhs)
    return sol[owner.repeat_interleave(n_s), rows].view(-1, n_s)


def _infinite(
    op: TransitionOperator, nodes: JointNodes, k: int, gamma: float, start: Tensor, max_dense: int, tol: float
) -> Tensor:
    """Discounted infinite-horizon values (K,) over the reachable joint nodes."""
    cols = _reachable(nodes, k)
    owner = cols.ids // nodes.num_joint
    if int(torch.bincount(owner, minlength=k).max()) * op.num_states <= max_dense:
        v = _dense_solve(op, cols, owner, k, gamma)
    else:
        r = op.reward.index_select(0, cols.action)
        v = gmres(lambda x: x - gamma * op.backup(x, cols), r, owner, k, tol * (1.0 - gamma), _GMRES_RESTART)
    at_start = (cols.ids % nodes.num_joint) == 0
    order = torch.argsort(owner[at_start])
    return v[at_start][order] @ start


def _reach(controller: JointController, horizon: int) -> tuple[int, int]:
    """(the most joint nodes any of the K controllers reaches at one step, the most it reaches over all ``horizon``
    steps together), each step's count bounded by the product of the nodes every agent's own graph reaches by then
    (tight for layered controllers, ``nodes ** agents`` for graphs that reach every node)."""
    k, a, nn = controller.action.shape
    reach = torch.zeros(k, a, nn, dtype=torch.bool)
    reach[..., 0] = True
    nxt = controller.next_node.cpu().reshape(k, a, -1)
    peak = total = torch.zeros(k, dtype=torch.float64)
    for t in range(horizon):
        count = reach.sum(-1).to(torch.float64).prod(-1)
        peak = torch.maximum(peak, count)
        grown = (
            torch.zeros(k, a, nn, dtype=torch.long).scatter_add_(
                2, nxt, reach[..., None].expand(-1, -1, -1, controller.num_obs).reshape(k, a, -1).long()
            )
            > 0
        )
        if torch.equal(grown, reach):  # nothing new from here on: every later step reaches the same
            total = total + count * (horizon - t)
            break
        total, reach = total + count, grown
    return int(peak.max()), int(total.max())


def _bytes_per_controller(controller: JointController, env: TabularDecPOSMDP, horizon: float, max_dense: int) -> int:
    """Working memory of one controller's evaluation: at a finite horizon six value tables of the most joint nodes of
    one step, every step's columns (ids, action, successors: ``2 + 2 JO + agents`` numbers each) and one position
    table over all joint nodes; at the infinite horizon the dense system or GMRES's basis over every joint node."""
    q, s = controller.num_nodes**controller.num_agents, env.num_states
    if horizon != math.inf:
        peak, total = _reach(controller, int(horizon))
        per_column = 2 + 2 * env.observation.shape[-1] + controller.num_agents
        return 8 * (6 * peak * s + per_column * total + q)
    dense = min(q * s, max_dense)  # the reachable part decides, so either solver may run
    return max(3 * 8 * dense**2, (_GMRES_RESTART + 8) * 8 * q * s)


def exact_value(
    env: TabularDecPOSMDP,
    controller: JointController,
    horizon: float | None = None,
    max_dense: int = 300,
    tol: float = 1e-10,
    memory_budget: int = DEFAULT_EVAL_BUDGET,
    threads: int | None = 1,
    device: torch.device | str | None = None,
) -> Tensor:
    """Exact value of each of the K joint controllers, float64 (K,), on ``device``.

    Args:
        env: the tabular problem (its ``gamma``; its ``horizon`` unless ``horizon`` is given).
        horizon: number of steps, or ``math.inf`` for the discounted infinite-horizon value.
        max_dense: largest per-controller (reachable joint node x state) system solved densely; above
            about 300 unknowns GMRES on the factored operator is the faster of the two.
        tol: bound on ``max |V - V*|`` for systems solved by GMRES.
        memory_budget: bytes of working memory; controllers are evaluated in chunks that fit
            (the per-controller need is bounded with every joint node reachable). Inside a
            :class:`~decpomdp.budget.Budget` with a memory limit, that limit replaces it where one controller needs
            more, and a controller that needs more than the limit ends the budget
            (:class:`~decpomdp.budget.BudgetSpent`) before anything is allocated.
        threads: torch intra-op threads during the call (None: unchanged). One by default: the
            products are many and small, and thread hand-offs cost more than they save on a busy machine.
        device: where the tables, the backups and the solves run, and where the values are returned
            (``None``: the device of ``controller``'s tensors). On the CPU the values are bit-identical
            to a call without ``device``.

    Raises:
        ValueError: bad arguments, or one controller alone needs more than ``memory_budget``.
    """
    horizon = _check(env, controller, horizon)
    if not isinstance(memory_budget, int) or memory_budget < 1:
        raise ValueError(f"memory_budget: expected a number of bytes >= 1, got {memory_budget!r}")
    need = _bytes_per_controller(controller, env, horizon, max_dense)
    running = budget.current()
    limit = memory_budget if running is None or running.memory is None else running.memory
    budget.reserve(need, "the exact evaluation of one controller")
    if need > limit:
        raise ValueError(f"memory_budget: one controller needs up to {need} bytes, more than {memory_budget}")
    chunk = max(1, min(memory_budget, limit) // need)
    device = controller.action.device if device is None else torch.device(device)
    start = env.start_dist.to(device)
    out = []
    with torch_threads(threads):
        op = operator_for(env, device)
        for i in range(0, controller.num_controllers, chunk):
            budget.check()
            part = controller[i : i + chunk]
            nodes, k = JointNodes(env, part, device), part.num_controllers
            if horizon == math.inf:
                out.append(_infinite(op, nodes, k, env.gamma, start, max_dense, tol))
            else:
                out.append(_finite(op, nodes, k, int(horizon), env.gamma, start))
    return torch.cat(out)
