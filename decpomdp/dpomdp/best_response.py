"""Exact best responses at a finite horizon, and JESP's alternating improvement (Nair et al., 2003).

With every other agent's controller fixed, one agent faces a POMDP over ``(state, the others' joint
node)``. Its best policy is a tree over its own observation histories, found by dynamic programming:
forwards, the unnormalised belief ``P(s, q, history)`` of every (action, observation) history of the
agent; backwards, ``V(h) = max_a [r(h, a) + gamma * sum_o V(h a o)]``. The tree has
``(A_i * O_i) ** t`` beliefs at step ``t``, so :func:`best_response` refuses a horizon whose tree
exceeds ``max_entries`` numbers; :func:`jesp` then leaves the controller as it is.

The response is returned as a layered controller for that agent (node 0 the empty history, then one
node per observation history of the chosen policy), beside the others' controllers unchanged.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch

from decpomdp.controller import JointController
from decpomdp.dpomdp.bounds import DEFAULT_MAX_ENTRIES, Tables, tables
from decpomdp.dpomdp.tabular import TabularDecPOSMDP


def tree_size(env: TabularDecPOSMDP, horizon: int, others_nodes: int) -> int:
    """Numbers the belief tree of one agent's best response holds (``sum_t (A O) ** t * Q * S``)."""
    branch = env.num_actions * env.num_obs
    return sum(branch**t for t in range(int(horizon))) * others_nodes * env.num_states


def best_response(
    env: TabularDecPOSMDP,
    controller: JointController,
    agent: int,
    horizon: int | None = None,
    max_entries: int = DEFAULT_MAX_ENTRIES,
    tabs: Tables | None = None,
) -> tuple[JointController, float] | None:
    """Agent ``agent``'s best response to the others' controllers in ``controller`` (K = 1).

    Returns ``(joint controller, its exact value)``, or ``None`` when the belief tree exceeds ``max_entries``.
    ``tabs`` (default ``tables(env)``) lets a caller build the problem's tables once.
    """
    h = int(env.horizon if horizon is None else horizon)
    n_agents, n_act, n_obs, gamma = env.num_agents, env.num_actions, env.num_obs, env.gamma
    nodes = controller.num_nodes
    others = [j for j in range(n_agents) if j != agent]
    q_tuples = list(itertools.product(range(nodes), repeat=len(others)))
    if tree_size(env, h, len(q_tuples)) > max_entries:
        return None
    act = controller.action[0].numpy()
    nxt = controller.next_node[0].numpy()
    a_stride = env.action_strides.numpy()
    n_q = len(q_tuples)
    q_index = {q: k for k, q in enumerate(q_tuples)}
    # ja[a_i, q] and, per joint observation, (o_i, q') after q
    ja = np.zeros((n_act, n_q), dtype=np.int64)
    for k, q in enumerate(q_tuples):
        base = sum(a_stride[j] * act[j, node] for j, node in zip(others, q))
        ja[:, k] = base + a_stride[agent] * np.arange(n_act)
    jo_own = np.zeros(n_obs**n_agents, dtype=np.int64)
    q_next = np.zeros((n_q, n_obs**n_agents), dtype=np.int64)
    for jo, parts in enumerate(itertools.product(range(n_obs), repeat=n_agents)):
        jo_own[jo] = parts[agent]
        for k, q in enumerate(q_tuples):
            q_next[k, jo] = q_index[tuple(nxt[j, node, parts[j]] for j, node in zip(others, q))]
    trans, reward, obs = tabs or tables(env)
    n_s = env.num_states
    # forwards: beliefs (n, Q, S) of every (action, observation) history, layer by layer
    start = np.zeros((1, n_q, n_s))
    start[0, q_index[tuple(0 for _ in others)]] = env.start_dist.numpy()
    layers, rewards = [start], []
    for step in range(h):
        b = layers[-1]
        rewards.append(np.stack([np.einsum("nqs,qs->n", b, reward[ja[a]]) for a in range(n_act)], 1))  # (n, A_i)
        if step + 1 == h:
            break
        child = np.zeros((b.shape[0], n_act, n_obs, n_q, n_s))
        for a in range(n_act):
            for k in range(n_q):
                j = ja[a, k]
                pred = (trans[j].T @ b[:, k, :].T).T  # (n, S')
                for jo in range(obs.shape[2]):
                    child[:, a, jo_own[jo], q_next[k, jo]] += pred * obs[j, :, jo]
        layers.append(child.reshape(-1, n_q, n_s))
    # backwards: values and the chosen action of every history
    value, choice = np.zeros(layers[-1].shape[0]), []
    for step in reversed(range(h)):
        r = rewards[step]
        future = value.reshape(r.shape[0], n_act, n_obs).sum(2) if step + 1 < h else 0.0
        total = r + gamma * future
        choice.append(total.argmax(1))
        value = total.max(1)
    choice.reverse()
    tree = _merge_layers(*_tree(choice, n_act, n_obs, h), [n_obs**t for t in range(h)])
    return _joint(controller, agent, tree), float(value[0])


def _tree(choice: list[np.ndarray], n_act: int, n_obs: int, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """(action (N,), next (N, O)) of the chosen policy tree: node 0 the empty history, then breadth first."""
    actions, succ = [], []
    frontier = [0]  # indices of the current layer's histories in the belief tree
    first = 0
    for step in range(horizon):
        acts = choice[step][frontier]
        actions.extend(int(a) for a in acts)
        nxt_first = first + len(frontier)
        children = []
        for pos, (node, a) in enumerate(zip(frontier, acts)):
            row = []
            for o in range(n_obs):
                if step + 1 < horizon:
                    row.append(nxt_first + pos * n_obs + o)
                    children.append((node * n_act + int(a)) * n_obs + o)
                else:
                    row.append(first + pos)  # the last layer's successors are never used
            succ.append(row)
        frontier, first = children, nxt_first
    return np.asarray(actions), np.asarray(succ)


def _joint(controller: JointController, agent: int, tree: tuple[np.ndarray, np.ndarray]) -> JointController:
    """``controller`` with ``agent``'s controller replaced by ``tree``, every agent padded to one node count."""
    action, succ = tree
    n = max(controller.num_nodes, action.shape[0])
    pad = n - controller.num_nodes
    old_a = torch.nn.functional.pad(controller.action, (0, pad))
    old_n = torch.nn.functional.pad(controller.next_node, (0, 0, 0, pad))
    old_a[0, agent] = 0
    old_n[0, agent] = 0
    old_a[0, agent, : action.shape[0]] = torch.as_tensor(action)
    old_n[0, agent, : action.shape[0]] = torch.as_tensor(succ)
    return JointController(old_a, old_n, controller.action_names, controller.obs_names)


def jesp(
    env: TabularDecPOSMDP,
    controller: JointController,
    value: float,
    horizon: int | None = None,
    max_entries: int = DEFAULT_MAX_ENTRIES,
    max_rounds: int = 20,
) -> tuple[JointController, float, int]:
    """Alternate exact best responses, agent after agent, from ``controller`` (of exact ``value``) until a
    round improves nothing. Returns (controller, value, best responses accepted)."""
    accepted, tabs = 0, tables(env)
    for _ in range(max_rounds):
        improved = False
        for agent in range(env.num_agents):
            out = best_response(env, controller, agent, horizon, max_entries, tabs)
            if out is not None and out[1] > value + 1e-12 * max(1.0, abs(value)):
                (controller, value), improved = out, True
                accepted += 1
        if not improved:
            break
    return controller, value, accepted


def _merge_layers(action: np.ndarray, succ: np.ndarray, sizes: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """A layered controller (layer ``t`` holds ``sizes[t]`` consecutive nodes, successors in layer ``t + 1``,
    the last layer's in itself) with the nodes of a layer that act and move alike merged, bottom-up."""
    bounds = np.cumsum([0] + list(sizes))
    h = len(sizes)
    label = np.zeros(action.shape[0], dtype=np.int64)
    layers: list[list[tuple]] = []
    for t in reversed(range(h)):
        keys: dict[tuple, int] = {}
        for node in range(bounds[t], bounds[t + 1]):
            key = (int(action[node]),) + (tuple(int(label[c]) for c in succ[node]) if t + 1 < h else ())
            label[node] = keys.setdefault(key, len(keys))
        layers.append(list(keys))
    layers.reverse()
    offsets = np.cumsum([0] + [len(layer) for layer in layers])
    out_action, out_succ = [], []
    for t, layer in enumerate(layers):
        for i, key in enumerate(layer):
            out_action.append(key[0])
            out_succ.append([offsets[t + 1] + c for c in key[1:]] if t + 1 < h else [offsets[t] + i] * succ.shape[1])
    return np.asarray(out_action), np.asarray(out_succ, dtype=np.int64)
