"""The optimal finite-horizon value by exhaustive search over deterministic policy trees (small cases only).

A deterministic policy of one agent for horizon ``h`` is a tree: an action for every observation history
of length < h. As a controller, node ``n`` is a history (node 0 the empty one, the children of node ``n``
in layer ``t`` its extensions by each observation); every joint combination of trees is evaluated
exactly. The count is ``(|A| ** nodes) ** agents`` with ``nodes = 1 + O + ... + O ** (h - 1)``.
"""

from __future__ import annotations

import itertools

import torch

from decpomdp.controller import JointController
from decpomdp.dpomdp.exact import exact_value
from decpomdp.dpomdp.tabular import TabularDecPOSMDP


def tree_controllers(num_agents: int, num_actions: int, num_obs: int, horizon: int) -> JointController:
    """Every joint deterministic policy tree of depth ``horizon`` as K joint controllers."""
    nodes = sum(num_obs**t for t in range(horizon))
    children = torch.arange(nodes)[:, None] * num_obs + 1 + torch.arange(num_obs)  # history n extended by o
    next_node = torch.where(children < nodes, children, 0)  # the last layer's successors are never used
    per_agent = torch.tensor(list(itertools.product(range(num_actions), repeat=nodes)))  # (P, nodes)
    joint = torch.cartesian_prod(*[torch.arange(per_agent.shape[0])] * num_agents).view(-1, num_agents)
    action = per_agent[joint]  # (K, A, nodes)
    return JointController(action, next_node.expand(action.shape[0], num_agents, nodes, num_obs).contiguous())


def exhaustive_optimum(env: TabularDecPOSMDP, horizon: int, max_policies: int = 100_000) -> tuple[float, int]:
    """(optimal value, number of joint policies searched) at a finite ``horizon`` (env's gamma).

    Raises:
        ValueError: more than ``max_policies`` joint policies.
    """
    nodes = sum(env.num_obs**t for t in range(horizon))
    count = env.num_actions ** (nodes * env.num_agents)
    if count > max_policies:
        raise ValueError(f"horizon: {count} joint policies at horizon {horizon}, more than max_policies={max_policies}")
    ctrl = tree_controllers(env.num_agents, env.num_actions, env.num_obs, horizon)
    return float(exact_value(env, ctrl, horizon=horizon).max()), count
