"""Exact values of joint finite-state controllers on a tabular Dec-POMDP.

For K joint controllers with Nn nodes per agent, the joint node ``q = (n_1, ..., n_A)`` and the state
``s`` form a Markov chain. With ``r[q, s] = R(s, a(q))`` and
``P[q, s -> next(q, jo), s'] = T(s'|s, a(q)) O(jo|a(q), s')``:

* infinite horizon, ``gamma < 1``: ``V = r + gamma P V`` is solved as a dense linear system over
  (q, s) (``torch.linalg.solve``, controllers chunked to bound memory); above ``max_dense`` unknowns it
  is solved by fixed-point iteration to a residual below ``tol``;
* finite horizon ``h``: ``V_0 = 0``, ``V_{j+1} = r + gamma P V_j`` (backward recursion, h steps).

The value is ``sum_s b0(s) V[q = (0, ..., 0), s]``: step ``k`` rewards discounted by ``gamma ** k``,
the same convention as :class:`~decpomdp.dpomdp.tabular.TabularDecPOSMDP` under the simulator.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.dpomdp.tabular import TabularDecPOSMDP


def _joint_tables(env: TabularDecPOSMDP, ctrl: JointController) -> tuple[Tensor, Tensor, Tensor]:
    """Joint-node tables: r (K, Q, S), P (K, Q, S, S', JO), next (K, Q, JO)."""
    k, a, nn = ctrl.action.shape
    grids = torch.cartesian_prod(*[torch.arange(nn)] * a).view(-1, a) if a > 1 else torch.arange(nn)[:, None]
    agent = torch.arange(a)
    acts = ctrl.action[:, agent, grids]  # (K, Q, A)
    ja = env.joint_action(acts)  # (K, Q)
    obs = env.split_obs(torch.arange(env.observation.shape[-1]))  # (JO, A)
    # next node of agent i: next_node[k, i, q_i, o_i] -> (K, Q, JO, A)
    nxt = ctrl.next_node[:, agent, grids[:, None, :], obs[None, :, :]]
    node_strides = torch.tensor([nn ** (a - 1 - i) for i in range(a)])
    nxt_q = (nxt * node_strides).sum(-1)
    r = env.expected_reward[ja]  # (K, Q, S)
    p = env.transition[ja][..., None] * env.observation[ja][:, :, None]  # (K, Q, S, S', JO)
    return r, p, nxt_q


def _backup(v: Tensor, r: Tensor, p: Tensor, nxt: Tensor, gamma: float) -> Tensor:
    """One Bellman backup of V (K, Q, S) for fixed controllers."""
    k, q, s = v.shape
    w = torch.gather(v, 1, nxt.reshape(k, -1)[..., None].expand(-1, -1, s)).view(k, q, -1, s)  # (K, Q, JO, S')
    return r + gamma * torch.einsum("kqsxj,kqjx->kqs", p, w)


def _dense(r: Tensor, p: Tensor, nxt: Tensor, gamma: float) -> Tensor:
    k, q, s = r.shape
    jo = p.shape[-1]
    n = q * s
    rows = (torch.arange(q)[:, None] * s + torch.arange(s)).view(q, s, 1, 1).expand(q, s, s, jo)
    cols = nxt.view(k, q, 1, 1, jo) * s + torch.arange(s).view(1, 1, 1, s, 1)
    flat = (rows.unsqueeze(0) * n + cols).reshape(k, -1)
    m = torch.zeros(k, n * n, dtype=torch.float64).scatter_add_(1, flat, p.reshape(k, -1)).view(k, n, n)
    lhs = torch.eye(n, dtype=torch.float64) - gamma * m
    return torch.linalg.solve(lhs, r.reshape(k, n, 1)).view(k, q, s)


def exact_value(
    env: TabularDecPOSMDP,
    controller: JointController,
    horizon: float | None = None,
    max_dense: int = 1500,
    tol: float = 1e-10,
) -> Tensor:
    """Exact value of each of the K joint controllers, float64 (K,).

    Args:
        env: the tabular problem (its ``gamma``; its ``horizon`` unless ``horizon`` is given).
        horizon: number of steps, or ``math.inf`` for the discounted infinite-horizon value.
        max_dense: largest (joint node x state) system solved densely.
        tol: fixed-point residual for larger infinite-horizon systems.
    """
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
    gamma = env.gamma
    if horizon == math.inf and gamma >= 1.0:
        raise ValueError("horizon: an infinite horizon needs gamma < 1")
    if horizon != math.inf and not (horizon.is_integer() and horizon >= 1):
        raise ValueError(f"horizon: expected a whole number of steps >= 1 or math.inf, got {horizon}")
    n = controller.num_nodes**controller.num_agents * env.num_states
    dense = horizon == math.inf and n <= max_dense
    per_controller = n * n if dense else n * env.num_states * env.observation.shape[-1]
    chunk = max(1, int(2e7 // per_controller))
    out = []
    for i in range(0, controller.num_controllers, chunk):
        r, p, nxt = _joint_tables(env, controller[i : i + chunk])
        if dense:
            v = _dense(r, p, nxt, gamma)
        elif horizon == math.inf:
            v = torch.zeros_like(r)
            while True:
                new = _backup(v, r, p, nxt, gamma)
                done = (new - v).abs().max() <= tol * (1 - gamma)
                v = new
                if done:
                    break
        else:
            v = torch.zeros_like(r)
            for _ in range(int(horizon)):
                v = _backup(v, r, p, nxt, gamma)
        out.append(v[:, 0, :] @ env.start_dist)
    return torch.cat(out)


class ExactEvaluator:
    """An :class:`~decpomdp.evaluate.Evaluator` returning exact values (standard error 0)."""

    def __init__(self, env: TabularDecPOSMDP, horizon: float | None = None) -> None:
        if not isinstance(env, TabularDecPOSMDP):
            raise TypeError(f"env: expected a TabularDecPOSMDP, got {type(env).__name__}")
        self.env, self.horizon = env, horizon
        self.num_agents, self.num_actions, self.num_obs = env.num_agents, env.num_actions, env.num_obs

    def __call__(self, controller: JointController, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        v = exact_value(self.env, controller, self.horizon)
        return v, torch.zeros_like(v)
