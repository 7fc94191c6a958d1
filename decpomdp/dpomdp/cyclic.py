"""Cyclic (infinite-horizon) joint controllers: loop-backs of finite-horizon policies and coordinate ascent.

At a discounted infinite horizon a controller's value is exact (:func:`~decpomdp.dpomdp.exact_value` solves the
linear system of its reachable joint nodes), so whole batches of candidates are compared exactly:

* :func:`loop_back`: a layered finite-horizon policy (its last layer's nodes loop on themselves) whose last layer
  moves back to node 0, so the policy restarts every ``h`` steps. Where the problem resets itself (Dec-Tiger after a
  door opens), the ``h``-step optimum repeated is close to the infinite-horizon optimum.
* :func:`ascend`: coordinate ascent, agent after agent. With the others' controllers fixed, every controller of the
  agent in a candidate set is evaluated and the best kept, until a round improves nothing. The candidates are
  either every ``n``-node controller (:func:`every_controller`: an exact best response among ``n``-node
  controllers) or every single change of the agent's current one (:func:`neighbours`: one node's action or one
  edge).

Tables are torch.long: ``action (P, N)`` and ``next (P, N, O)`` for P controllers of one agent.
"""

from __future__ import annotations

import torch
from torch import Tensor

from decpomdp.budget import BudgetSpent
from decpomdp.controller import JointController
from decpomdp.dpomdp.exact import exact_value
from decpomdp.dpomdp.tabular import TabularDecPOSMDP


def every_controller(num_nodes: int, num_actions: int, num_obs: int) -> tuple[Tensor, Tensor]:
    """Every deterministic ``num_nodes``-node controller of one agent: ``action (P, N)``, ``next (P, N, O)``
    with ``P = A ** N * N ** (N * O)``."""
    acts = torch.cartesian_prod(*[torch.arange(num_actions)] * num_nodes).view(-1, num_nodes)
    moves = torch.cartesian_prod(*[torch.arange(num_nodes)] * (num_nodes * num_obs)).view(-1, num_nodes, num_obs)
    count = acts.shape[0] * moves.shape[0]
    action = acts[:, None].expand(-1, moves.shape[0], -1).reshape(count, num_nodes)
    nxt = moves[None].expand(acts.shape[0], -1, -1, -1).reshape(count, num_nodes, num_obs)
    return action, nxt


def count_controllers(num_nodes: int, num_actions: int, num_obs: int) -> int:
    """How many controllers :func:`every_controller` lists."""
    return num_actions**num_nodes * num_nodes ** (num_nodes * num_obs)


def neighbours(action: Tensor, nxt: Tensor, num_actions: int) -> tuple[Tensor, Tensor]:
    """Every controller one change away from ``action (N,)``, ``next (N, O)``: one node's action replaced, or one
    edge moved to another node. Returns ``action (P, N)``, ``next (P, N, O)``."""
    n, n_obs = nxt.shape
    acts, moves = [], []
    for node in range(n):
        for a in range(num_actions):
            if a != int(action[node]):
                acts.append(action.clone())
                acts[-1][node] = a
                moves.append(nxt)
        for o in range(n_obs):
            for target in range(n):
                if target != int(nxt[node, o]):
                    moved = nxt.clone()
                    moved[node, o] = target
                    acts.append(action)
                    moves.append(moved)
    return torch.stack(acts), torch.stack(moves)


def pad_nodes(controller: JointController, num_nodes: int) -> JointController:
    """``controller`` with unused nodes appended (action 0, looping to node 0) up to ``num_nodes`` per agent."""
    pad = num_nodes - controller.num_nodes
    if pad <= 0:
        return controller
    action = torch.nn.functional.pad(controller.action, (0, pad))
    nxt = torch.nn.functional.pad(controller.next_node, (0, 0, 0, pad))
    return JointController(action, nxt)


def with_agent(controller: JointController, agent: int, action: Tensor, nxt: Tensor) -> JointController:
    """P joint controllers: ``controller`` (K = 1) with ``agent``'s controller replaced by each row of ``action (P,
    N)``, ``next (P, N, O)``; every agent padded to one node count."""
    n = max(controller.num_nodes, action.shape[1])
    base = pad_nodes(controller, n)
    count = action.shape[0]
    acts = base.action.expand(count, -1, -1).clone()
    moves = base.next_node.expand(count, -1, -1, -1).clone()
    acts[:, agent] = 0
    moves[:, agent] = 0
    acts[:, agent, : action.shape[1]] = action
    moves[:, agent, : action.shape[1]] = nxt
    return JointController.trusted(acts, moves)


CHUNK = 1024
"""Controllers evaluated together by :func:`_values`: a batch of this many small dense systems stays in cache (all
19,683 three-node controllers of an agent at once take 2 x 200 MB, and twice the CPU time)."""


def _values(env: TabularDecPOSMDP, joint: JointController) -> Tensor:
    """Exact infinite-horizon values (K,), :data:`CHUNK` controllers at a time; where GMRES stalls at its tolerance
    (values of hundreds, a residual of 1e-11), the systems are solved densely instead."""
    out = []
    for lo in range(0, joint.action.shape[0], CHUNK):
        part = joint[lo : lo + CHUNK]
        try:
            out.append(exact_value(env, part, horizon=float("inf")))
        except RuntimeError:
            unknowns = part.num_nodes**part.num_agents * env.num_states
            out.append(exact_value(env, part, horizon=float("inf"), max_dense=unknowns))
    return torch.cat(out)


def loop_back(controller: JointController) -> JointController:
    """``controller`` with every node whose successors are all itself (a layered controller's last layer) moving
    to node 0 instead."""
    nodes = torch.arange(controller.num_nodes)[None, None, :, None]
    stuck = (controller.next_node == nodes).all(-1, keepdim=True)
    return JointController(controller.action, torch.where(stuck, 0, controller.next_node))


def ascend(
    env: TabularDecPOSMDP,
    controller: JointController,
    value: float,
    num_nodes: int | None = None,
    max_rounds: int = 20,
    tol: float = 1e-9,
) -> tuple[JointController, float, int]:
    """Coordinate ascent on ``controller`` (K = 1, of exact infinite-horizon ``value``): per agent, the best of
    every ``num_nodes``-node controller (``None``: of every single change of its current one, see
    :func:`neighbours`), kept when it gains more than ``tol * max(1, |value|)``; until a round improves nothing.

    Returns (controller, value, rounds made); when a running :class:`~decpomdp.budget.Budget` ends, the best reached
    so far.
    """
    every = None if num_nodes is None else every_controller(num_nodes, env.num_actions, env.num_obs)
    rounds = 0
    for rounds in range(1, max_rounds + 1):
        improved = False
        for agent in range(env.num_agents):
            if every is None:
                cand = neighbours(controller.action[0, agent], controller.next_node[0, agent], env.num_actions)
            else:
                cand = every
            joint = with_agent(controller, agent, *cand)
            try:
                values = _values(env, joint)
            except BudgetSpent:
                return controller, value, rounds
            k = int(values.argmax())
            if float(values[k]) > value + tol * max(1.0, abs(value)):
                controller, value, improved = joint[k], float(values[k]), True
        if not improved:
            break
    return controller, value, rounds
