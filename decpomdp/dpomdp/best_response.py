"""Exact best responses at a finite horizon, and JESP's alternating improvement (Nair et al., 2003).

With every other agent's controller fixed, one agent faces a POMDP over ``(state, the others' joint
node)``. Its best policy is found by dynamic programming over its beliefs: forwards, the normalised belief
``P(s, q | history)`` after every (action, observation) history of the agent, with histories that reach
the same belief merged into one (the optimal continuation depends on the belief only, so Dec-Tiger's
``6 ** t`` histories at step ``t`` collapse to a few dozen beliefs); backwards,
``V(b) = max_a [r(b, a) + gamma * sum_o P(o | b, a) V(b a o)]``. A layer of more than ``max_entries``
numbers makes :func:`best_response` refuse; :func:`jesp` then leaves the controller as it is.

The response is returned as a layered controller for that agent (node 0 the start, then one node per
belief its policy reaches at each step, nodes that act and move alike merged), beside the others'
controllers unchanged, with its exact value.
"""

from __future__ import annotations

import itertools

import numpy as np
import scipy.sparse as sp
import torch

from decpomdp import budget
from decpomdp.budget import BudgetSpent
from decpomdp.controller import JointController
from decpomdp.dpomdp.bounds import DEFAULT_MAX_ENTRIES, LAYER_COPIES, Tables, tables
from decpomdp.dpomdp.exact import exact_value
from decpomdp.dpomdp.tabular import TabularDecPOSMDP
from hbni_infra.streams import numpy_generator

RESOLUTION = 1e-11
"""Beliefs whose two random projections (weights in [1, 2)) agree to this are merged: they are then equal to about
this much in every entry (a third projection checks each merge). The response's value is computed exactly."""


def _others(
    env: TabularDecPOSMDP, controller: JointController, agent: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The others' fixed controllers as tables over their joint node ``q``: the joint action ``ja[a_i, q]``,
    the agent's own observation ``jo_own[jo]`` and the others' next joint node ``q_next[q, jo]`` of every
    joint observation, and the start node's index."""
    n_agents, n_act, n_obs = env.num_agents, env.num_actions, env.num_obs
    others = [j for j in range(n_agents) if j != agent]
    q_tuples = list(itertools.product(range(controller.num_nodes), repeat=len(others)))
    q_index = {q: k for k, q in enumerate(q_tuples)}
    act, nxt = controller.action[0].numpy(), controller.next_node[0].numpy()
    a_stride = env.action_strides.numpy()
    ja = np.zeros((n_act, len(q_tuples)), dtype=np.int64)
    for k, q in enumerate(q_tuples):
        ja[:, k] = sum(a_stride[j] * act[j, node] for j, node in zip(others, q)) + a_stride[agent] * np.arange(n_act)
    jo_own = np.zeros(n_obs**n_agents, dtype=np.int64)
    q_next = np.zeros((len(q_tuples), n_obs**n_agents), dtype=np.int64)
    for jo, parts in enumerate(itertools.product(range(n_obs), repeat=n_agents)):
        jo_own[jo] = parts[agent]
        for k, q in enumerate(q_tuples):
            q_next[k, jo] = q_index[tuple(nxt[j, node, parts[j]] for j, node in zip(others, q))]
    return ja, jo_own, q_next, q_index[tuple(0 for _ in others)]


def best_response(
    env: TabularDecPOSMDP,
    controller: JointController,
    agent: int,
    horizon: int | None = None,
    max_entries: int = DEFAULT_MAX_ENTRIES,
    tabs: Tables | None = None,
) -> tuple[JointController, float] | None:
    """Agent ``agent``'s best response to the others' controllers in ``controller`` (K = 1).

    Returns ``(joint controller, its exact value)``, or ``None`` when a layer of beliefs (before merging)
    would exceed ``max_entries`` numbers. ``tabs`` (default ``tables(env)``) lets a caller build the
    problem's tables once. Inside a :class:`~decpomdp.budget.Budget`, each step checks the time and reserves its
    layer (:data:`LAYER_COPIES` arrays of it) first.
    """
    h = int(env.horizon if horizon is None else horizon)
    n_act, n_obs, gamma = env.num_actions, env.num_obs, env.gamma
    ja, jo_own, q_next, q0 = _others(env, controller, agent)
    n_s = env.num_states
    trans, reward, obs = tabs or tables(env)
    trans_t = [t.T.tocsr() for t in trans]  # T_ja' (S', S)
    # forwards: the distinct normalised beliefs (Q, n, S) of each step but the last; per belief, the reward of each
    # action, and the index and probability of the belief after each (action, own observation)
    n_jo = obs.shape[2]
    nodes = np.array([q0])  # the others' joint nodes a belief of this step can hold (a layered controller: a layer)
    belief = env.start_dist.numpy()[None, None, :]  # (Q_t, n, S): by node first, so a node's beliefs are one block
    rewards, children, probs = [_rewards(belief, ja[:, nodes], reward)], [], []
    for step in range(h - 1):
        n, q_t = belief.shape[1], nodes.size
        acts = ja[:, nodes]  # (A, Q_t)
        if step + 2 == h:  # the last step's beliefs need only their probability and rewards: no child beliefs
            if q_t * n * n_s > max_entries:
                return None
            budget.reserve(8 * q_t * n * n_s * n_act, f"a best response's beliefs at step {step + 1} of {h}")
            mass, gain = _last_step(belief, nodes, ja, q_next, jo_own, trans_t, reward, obs, n_obs)
            live = np.flatnonzero(mass > 0)
            inverse = np.arange(live.size)
            rewards.append(gain[live] / mass[live, None])
        else:
            after = np.unique(q_next[nodes])
            entries = n * n_act * n_obs * after.size * n_s
            if entries > max_entries:
                return None
            budget.reserve(8 * LAYER_COPIES * entries, f"a best response's beliefs at step {step + 1} of {h}")
            moves = [  # node q (of ``nodes``) to q' (of ``after``) after each joint observation, one 1 per column
                sp.csr_matrix(
                    (np.ones(q_t), (np.searchsorted(after, q_next[nodes, jo]), np.arange(q_t))), (after.size, q_t)
                )
                for jo in range(n_jo)
            ]
            child = np.zeros((n_act, n_obs, after.size, n * n_s))
            for a in range(n_act):
                pred = _predicted(belief, acts[a], trans_t)
                seen = obs[acts[a]]  # (Q_t, S', JO)
                for jo in range(n_jo):
                    child[a, jo_own[jo]] += moves[jo] @ (pred * seen[:, None, :, jo]).reshape(q_t, -1)
            flat = (
                child.reshape(n_act, n_obs, after.size, n, n_s).transpose(3, 0, 1, 2, 4).reshape(n * n_act * n_obs, -1)
            )
            mass = flat.sum(1)
            live = np.flatnonzero(mass > 0)
            first, inverse = _distinct_beliefs(flat[live] if live.size < mass.size else flat, mass[live])
            rows = live[first]
            belief = np.ascontiguousarray(
                (flat[rows] / mass[rows, None]).reshape(-1, after.size, n_s).transpose(1, 0, 2)
            )
            nodes = after
            rewards.append(_rewards(belief, ja[:, nodes], reward))
        index = np.zeros(mass.shape[0], dtype=np.int64)
        index[live] = inverse
        children.append(index.reshape(n, n_act, n_obs))
        probs.append(mass.reshape(n, n_act, n_obs))
    # backwards: the value and the chosen action of every belief
    value, choice = np.zeros(0), []
    for step in reversed(range(h)):
        total = rewards[step] + (gamma * (probs[step] * value[children[step]]).sum(2) if step + 1 < h else 0.0)
        choice.append(total.argmax(1))
        value = total.max(1)
    choice.reverse()
    joint = _joint(controller, agent, _merge_layers(*_policy(choice, children, probs, n_obs, h)))
    return joint, float(exact_value(env, joint)[0])


def _predicted(belief: np.ndarray, acts: np.ndarray, trans_t: list) -> np.ndarray:
    """``(Q, n, S')`` unnormalised next-state distribution of each belief ``(Q, n, S)`` when the others' nodes take
    the joint actions ``acts (Q,)``, one sparse product per joint action; ``trans_t[ja]`` is ``T_ja (S', S)``."""
    q_t, n, n_s = belief.shape
    pred = np.empty((q_t, n, n_s))
    for j in np.unique(acts):
        qs = np.flatnonzero(acts == j)
        pred[qs] = (trans_t[j] @ belief[qs].reshape(-1, n_s).T).T.reshape(qs.size, n, n_s)
    return pred


def _last_step(
    belief: np.ndarray,
    nodes: np.ndarray,
    ja: np.ndarray,
    q_next: np.ndarray,
    jo_own: np.ndarray,
    trans_t: list,
    reward: np.ndarray,
    obs: np.ndarray,
    n_obs: int,
) -> tuple[np.ndarray, np.ndarray]:
    """For the beliefs ``(Q, n, S)`` of the step before the last (the others at ``nodes``): the probability
    ``(n A O,)`` of each (action, own observation) and ``(n A O, A)`` the expected last reward of each last
    action times it, rows ordered (belief, action, observation); dense products with the observation and
    reward tables, no next beliefs formed."""
    n_act, (_, n, n_s) = ja.shape[0], belief.shape
    own = np.eye(n_obs)[jo_own]  # (JO, O)
    mass = np.zeros((n, n_act, n_obs))
    gain = np.zeros((n, n_act, n_obs, n_act))
    after = [reward[ja[:, q_next[q]]].transpose(2, 1, 0) for q in nodes]  # (S', JO, A'): last rewards at the next node
    for a in range(n_act):
        pred = _predicted(belief, ja[a, nodes], trans_t)
        seen = obs[ja[a, nodes]]  # (Q, S', JO)
        for k in range(nodes.size):
            table = np.concatenate([seen[k][:, :, None], seen[k][:, :, None] * after[k]], 2)  # (S', JO, 1 + A')
            out = (pred[k] @ table.reshape(n_s, -1)).reshape(n, -1, 1 + n_act)
            mass[:, a] += out[:, :, 0] @ own
            gain[:, a] += np.einsum("njb,jo->nob", out[:, :, 1:], own)
    return mass.reshape(-1), gain.reshape(-1, n_act)


def _rewards(belief: np.ndarray, acts: np.ndarray, reward: np.ndarray) -> np.ndarray:
    """``(n, A)`` expected reward of each action from each belief ``(Q, n, S)`` over the others' nodes, whose
    joint actions are ``acts (A, Q)``; ``reward (JA, S)``."""
    return np.stack([np.einsum("qns,qs->n", belief, reward[acts[a]]) for a in range(acts.shape[0])], 1)


def _distinct_beliefs(mass_rows: np.ndarray, mass: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For the rows of ``mass_rows (n, d)`` (unnormalised beliefs of total ``mass (n,)``, all positive): the index
    of each distinct belief's first row, and each row's distinct index.

    Rows are keyed by two random projections of the normalised belief on :data:`RESOLUTION`'s grid, and every merge
    is checked by a third projection; should one fail, the beliefs are compared entry by entry (``np.unique``).
    """
    weights = numpy_generator(0).uniform(1.0, 2.0, (mass_rows.shape[1], 3))
    proj = (mass_rows @ weights) / mass[:, None]  # (n, 3), each in [1, 2)
    keys = np.rint(proj[:, :2] / RESOLUTION).astype(np.int64)
    order = np.lexsort((keys[:, 1], keys[:, 0]))  # stable: a group's first row in ``order`` is its first row
    ordered = keys[order]
    starts = np.concatenate([[True], (ordered[1:] != ordered[:-1]).any(1)])
    inverse = np.empty(order.size, dtype=np.int64)
    inverse[order] = np.cumsum(starts) - 1
    first = order[starts]
    if np.abs(proj[first[inverse], 2] - proj[:, 2]).max(initial=0.0) > 4 * RESOLUTION:
        exact = np.rint(mass_rows / mass[:, None] / RESOLUTION)
        _, first, inverse = np.unique(exact, axis=0, return_index=True, return_inverse=True)
    return first, inverse.reshape(-1)


def _policy(
    choice: list[np.ndarray], children: list[np.ndarray], probs: list[np.ndarray], n_obs: int, horizon: int
) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """(action (N,), next (N, O), layer sizes) of the chosen policy: layer ``t`` holds a node per belief it
    reaches at step ``t`` (node 0 the start); an impossible observation moves to the next layer's first node,
    and the last layer's successors (never used) are the nodes themselves."""
    actions, succ, sizes = [], [], []
    layer = np.zeros(1, dtype=np.int64)  # belief indices of this step's nodes
    first = 0
    for step in range(horizon):
        acts = choice[step][layer]
        actions.extend(int(a) for a in acts)
        sizes.append(layer.shape[0])
        if step + 1 == horizon:
            succ.extend([[first + pos] * n_obs for pos in range(layer.shape[0])])
            break
        reached = children[step][layer, acts]  # (n, O)
        live = probs[step][layer, acts] > 0
        nxt_layer, slot = np.unique(reached[live], return_inverse=True)
        targets = np.zeros(reached.shape, dtype=np.int64)
        targets[live] = slot.reshape(-1)
        nxt_first = first + layer.shape[0]
        succ.extend((nxt_first + targets).tolist())
        layer, first = (nxt_layer if nxt_layer.size else np.zeros(1, dtype=np.int64)), nxt_first
    return np.asarray(actions), np.asarray(succ, dtype=np.int64), sizes


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
    round improves nothing. Returns (controller, value, best responses accepted); when a running
    :class:`~decpomdp.budget.Budget` ends, the best reached so far."""
    accepted, tabs = 0, tables(env)
    for _ in range(max_rounds):
        improved = False
        for agent in range(env.num_agents):
            try:
                out = best_response(env, controller, agent, horizon, max_entries, tabs)
            except BudgetSpent:
                return controller, value, accepted
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
