"""Upper bounds on the optimal value of a tabular Dec-POMDP, by relaxations that are easier to solve.

Every joint policy of the Dec-POMDP is a policy of the centralised POMDP (one planner that sees every
agent's observation), and every POMDP policy is a policy of the underlying MDP (one that sees the
state). So, with ``V*`` the Dec-POMDP optimum from the start belief ``b0``:

    V*  <=  V_POMDP(b0)  <=  V_FIB(b0)  <=  V_MDP(b0)

* :func:`q_mdp`: the MDP's ``Q(s, ja)`` by backward induction (finite horizon) or value iteration
  from above (infinite horizon: each iterate of a monotone backup started above the fixed point stays
  above it, so every iterate is a valid bound).
* :func:`q_fib`: the fast informed bound (Hauskrecht, 2000), ``Q(s, a) = R(s, a) + gamma
  sum_o max_a' sum_s' T(s'|s, a) O(o|a, s') Q(s', a')``, which keeps what the observations tell.
* :func:`lookahead_bound`: the centralised POMDP solved exactly over every belief reachable in
  the first ``depth`` steps, with the FIB at the leaves: exact ``V_POMDP`` when ``depth`` reaches the
  horizon. The depth is the largest whose last belief layer fits ``max_entries`` numbers.

Arrays are numpy float64; ``T`` stays sparse, so the cost per backup is ``JA * JO * nnz(T) * JA``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from decpomdp import budget
from decpomdp.dpomdp.tabular import TabularDecPOSMDP

_MAX_SWEEPS = 10_000
DEFAULT_MAX_ENTRIES = 20_000_000
"""Largest belief layer of :func:`lookahead_bound`, in float64 numbers (160 MB)."""
LAYER_COPIES = 3
"""Peak working memory of :func:`lookahead_bound` in belief layers: a layer's children are formed, transposed and
filtered (three arrays of the next layer's size at once)."""


class Bounds(NamedTuple):
    """Upper bounds on the optimum from the start belief: ``best`` is the smallest of them."""

    q_mdp: float
    fib: float
    lookahead: float
    depth: int
    """The belief tree's depth behind ``lookahead``."""

    @property
    def best(self) -> float:
        return min(self.q_mdp, self.fib, self.lookahead)


class Tables(NamedTuple):
    """A problem's dynamics as numpy arrays, built once and shared by the bounds and best responses."""

    trans: list[sp.csr_matrix]
    """Per joint action the sparse ``T_ja (S, S')``."""
    reward: np.ndarray
    """``R (JA, S)``."""
    obs: np.ndarray
    """``O (JA, S', JO)``."""


def tables(env: TabularDecPOSMDP) -> Tables:
    """The :class:`Tables` of ``env``."""
    t = env.model.transition
    n_ja, n_s = t.shape[:2]
    full = sp.csr_matrix((t.data, t.indices, t.indptr), shape=(n_ja * n_s, n_s))
    return Tables(
        [full[ja * n_s : (ja + 1) * n_s] for ja in range(n_ja)], env.expected_reward.numpy(), env.observation.numpy()
    )


def _iterate(env: TabularDecPOSMDP, horizon: float, backup, tol: float) -> np.ndarray:
    """(JA, S) ``Q`` at step 0 of ``Q = R + gamma * backup(Q)``: ``horizon`` steps from ``Q = R`` (the last
    step's), or (infinite horizon) from ``max R / (1 - gamma)`` everywhere until a sweep moves less than ``tol``.

    Inside a :class:`~decpomdp.budget.Budget` whose time is over, the iteration stops and the result stays a bound:
    at a finite horizon, the ``k`` steps done plus the largest reward for each step left (discounted); at the infinite
    horizon, the iterate reached (every iterate from above is a bound)."""
    reward = env.expected_reward.numpy()
    if math.isfinite(horizon):
        q = reward.copy()
        for done in range(1, int(horizon)):
            if budget.time_left() <= 0:
                return q + _tail(reward.max(), env.gamma, done, int(horizon))
            q = reward + env.gamma * backup(q)
        return q
    q = np.full_like(reward, reward.max() / (1 - env.gamma))
    for _ in range(_MAX_SWEEPS):
        if budget.time_left() <= 0:
            break
        new = reward + env.gamma * backup(q)
        moved = np.abs(new - q).max()
        q = new
        if moved <= tol:
            break
    return q


def _tail(largest: float, gamma: float, done: int, horizon: int) -> float:
    """``largest * sum_{t = done}^{horizon - 1} gamma ** t``: the most the steps after the first ``done`` can earn."""
    left = horizon - done
    return largest * (left if gamma == 1.0 else gamma**done * (1.0 - gamma**left) / (1.0 - gamma))


def q_mdp(
    env: TabularDecPOSMDP, horizon: float | None = None, tol: float = 1e-10, tabs: Tables | None = None
) -> np.ndarray:
    """(JA, S) ``Q`` of the underlying MDP at step 0 (``horizon`` defaults to ``env.horizon``; ``tabs``
    to ``tables(env)``)."""
    trans = (tabs or tables(env)).trans
    return _iterate(
        env, env.horizon if horizon is None else horizon, lambda q: np.stack([tr @ q.max(0) for tr in trans]), tol
    )


def q_fib(
    env: TabularDecPOSMDP, horizon: float | None = None, tol: float = 1e-10, tabs: Tables | None = None
) -> np.ndarray:
    """(JA, S) fast informed bound ``Q`` at step 0: every policy's value from a belief ``b`` is at most
    ``max_ja b . Q[ja]`` (``horizon`` defaults to ``env.horizon``; ``tabs`` to ``tables(env)``)."""
    tabs = tabs or tables(env)
    return _iterate(
        env, env.horizon if horizon is None else horizon, lambda q: fib_backup(tabs.trans, tabs.obs, q), tol
    )


def fib_backup(trans: list[sp.csr_matrix], obs: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(JA, S) ``sum_o max_a' sum_s' T(s'|s, a) O(o|a, s') q[a', s']``."""
    out = np.zeros((len(trans), trans[0].shape[0]))
    for ja, tr in enumerate(trans):
        for jo in range(obs.shape[2]):
            out[ja] += (tr @ (obs[ja, :, jo, None] * q.T)).max(1)  # (S, JA') -> max over the next action
    return out


def lookahead_bound(
    env: TabularDecPOSMDP,
    horizon: float | None = None,
    max_entries: int = DEFAULT_MAX_ENTRIES,
    tabs: Tables | None = None,
) -> tuple[float, int]:
    """(bound, depth): the centralised POMDP's exact value over its belief tree ``depth`` steps deep, with
    the FIB of the remaining steps at the leaves.

    ``depth`` is the largest number of steps (at most the horizon) whose last layer of
    ``(JA * JO) ** depth`` beliefs over ``S`` states holds at most ``max_entries`` numbers (8 bytes
    each); beliefs of probability zero are dropped as they arise. ``tabs`` defaults to ``tables(env)``.
    Inside a :class:`~decpomdp.budget.Budget` the tree is also built to fit its memory (:data:`LAYER_COPIES` layers
    at once), and not at all (``depth`` 0: the FIB) once its time is over.
    """
    horizon = env.horizon if horizon is None else horizon
    tabs = tabs or tables(env)
    trans, reward, obs = tabs
    n_ja, n_jo = obs.shape[0], obs.shape[2]
    per_entry = 8 * LAYER_COPIES
    max_entries = budget.memory_limit(max_entries * per_entry) // per_entry
    depth = 0
    while budget.time_left() > 0 and depth < horizon and (n_ja * n_jo) ** (depth + 1) * env.num_states <= max_entries:
        depth += 1
    rest = horizon - depth
    leaf = q_fib(env, rest, tabs=tabs) if rest > 0 else None
    gamma = env.gamma
    # forward: the reachable unnormalised beliefs of each layer, with their parents
    layers = [env.start_dist.numpy()[None, :]]  # (N, S), each row P(s, history)
    parents = []
    for _ in range(depth):
        b = layers[-1]
        pred = np.stack([(tr.T @ b.T).T for tr in trans], 1)  # (N, JA, S') = sum_s b(s) T(s'|s, ja)
        joint = pred[:, :, :, None] * obs[None]  # (N, JA, S', JO)
        joint = joint.transpose(0, 1, 3, 2).reshape(-1, joint.shape[2])  # (N * JA * JO, S')
        keep = joint.sum(1) > 0
        parents.append((np.flatnonzero(keep), b.shape[0]))
        layers.append(joint[keep])
    # backward: V(b) = max_ja [ b . R[ja] + gamma * sum_jo V(b') ] on unnormalised beliefs (values scale with mass)
    value = (layers[-1] @ leaf.T).max(1) if leaf is not None else np.zeros(layers[-1].shape[0])
    for t in reversed(range(depth)):
        kept, n = parents[t]
        child = np.zeros(n * n_ja * n_jo)
        child[kept] = value
        future = child.reshape(n, n_ja, n_jo).sum(2)  # (N, JA)
        value = (layers[t] @ reward.T + gamma * future).max(1)
    return float(value[0]), depth


def upper_bounds(env: TabularDecPOSMDP, horizon: float | None = None, max_entries: int = DEFAULT_MAX_ENTRIES) -> Bounds:
    """The three bounds from the start belief (``horizon`` defaults to ``env.horizon``)."""
    horizon = env.horizon if horizon is None else horizon
    b0, tabs = env.start_dist.numpy(), tables(env)
    mdp = float((q_mdp(env, horizon, tabs=tabs) @ b0).max())
    fib = float((q_fib(env, horizon, tabs=tabs) @ b0).max())
    look, depth = lookahead_bound(env, horizon, max_entries, tabs)
    return Bounds(mdp, fib, look, depth)
