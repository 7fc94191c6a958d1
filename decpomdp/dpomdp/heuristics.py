"""Admissible heuristics for exact search: ``Q_BG`` and ``Q_POMDP`` over joint beliefs, with the fast informed bound
below the part of the belief tree that fits.

For a joint belief ``b`` at step ``t`` of a horizon-``h`` problem and a joint action ``ja``:

* ``Q_POMDP(b, ja) = R(b, ja) + gamma sum_jo P(jo | b, ja) max_ja' Q_POMDP(b', ja')``: the centralised planner that
  sees every observation at once;
* ``Q_BG(b, ja) = R(b, ja) + gamma max_beta sum_jo P(jo | b, ja) Q_BG(b', beta(jo))`` (Oliehoek, Spaan and Vlassis,
  JAIR 2008): the observations are shared one step late, so the next action of each agent depends only on its own
  last observation (``beta = (beta_1, ..., beta_n)``, ``beta_i: O_i -> A_i``).

Every Dec-POMDP policy is a policy of both relaxations, so ``Q_BG <= Q_POMDP <= Q_FIB`` bound the optimal
``Q*(theta, ja)`` of every joint history ``theta`` whose belief is ``b``. The tree of beliefs reachable from the
start is built layer by layer, equal beliefs merged, as deep as :data:`DEFAULT_MAX_ENTRIES` allows; below it the fast
informed bound (:func:`~decpomdp.dpomdp.bounds.q_fib`, one backup per step) stands in. ``Q_BG`` falls back to ``Q_POMDP``'s backup where the
joint decision rules ``beta`` number more than :data:`MAX_RULES`.

Arrays are numpy float64: beliefs ``(n, S)``, ``Q`` tables ``(n, JA)`` (values from step ``t`` on, not discounted by
``gamma ** t``).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from decpomdp import budget
from decpomdp.dpomdp.bounds import DEFAULT_MAX_ENTRIES, LAYER_COPIES, Tables, fib_backup, tables
from decpomdp.dpomdp.tabular import TabularDecPOSMDP
from hbni_infra.streams import numpy_generator

MAX_RULES = 4096
"""Most joint one-step decision rules ``beta`` a ``Q_BG`` backup enumerates."""
KEY_RESOLUTION = 1e-9
"""Beliefs whose two random projections agree to this share a key (are merged and looked up as one)."""
_CHUNK = 2_000_000


def joint_rules(env: TabularDecPOSMDP) -> np.ndarray:
    """``(B, JO)`` int64: the joint action every joint one-step decision rule takes after each joint observation."""
    n_act, n_obs, n_agents = env.num_actions, env.num_obs, env.num_agents
    own = np.array(list(itertools.product(range(n_act), repeat=n_obs)))  # (A ** O, O) one agent's rules
    jo_parts = np.array(list(itertools.product(range(n_obs), repeat=n_agents)))  # (JO, N)
    strides = env.action_strides.numpy()
    rules = np.zeros((own.shape[0] ** n_agents, jo_parts.shape[0]), dtype=np.int64)
    for k, combo in enumerate(itertools.product(range(own.shape[0]), repeat=n_agents)):
        rules[k] = sum(strides[i] * own[combo[i]][jo_parts[:, i]] for i in range(n_agents))
    return rules


def belief_keys(beliefs: np.ndarray) -> np.ndarray:
    """``(n, 2)`` int64 keys of normalised beliefs ``(n, S)``: two fixed random projections on a grid."""
    weights = numpy_generator(0).uniform(1.0, 2.0, (beliefs.shape[1], 2))
    return np.rint(beliefs @ weights / KEY_RESOLUTION).astype(np.int64)


def children(beliefs: np.ndarray, tabs: Tables) -> tuple[np.ndarray, np.ndarray]:
    """``(mass (n, JA, JO), next beliefs (n, JA, JO, S))``: the probability of each joint observation after each
    joint action, and the normalised belief it leads to (zero where its probability is zero)."""
    trans, _, obs = tabs
    pred = np.stack([(tr.T @ beliefs.T).T for tr in trans], 1)  # (n, JA, S')
    joint = pred[:, :, None, :] * obs.transpose(0, 2, 1)[None]  # (n, JA, JO, S')
    mass = joint.sum(-1)
    safe = np.where(mass > 0, mass, 1.0)
    return mass, joint / safe[..., None]


def backup(
    beliefs: np.ndarray, mass: np.ndarray, q_next: np.ndarray, tabs: Tables, gamma: float, rules: np.ndarray | None
) -> np.ndarray:
    """``(n, JA)`` Q of ``beliefs (n, S)`` from the children's ``q_next (n, JA, JO, JA')`` and their ``mass (n, JA,
    JO)``: ``Q_BG``'s backup over the joint ``rules (B, JO)``, or ``Q_POMDP``'s (``rules=None``)."""
    weighted = mass[..., None] * q_next  # (n, JA, JO, JA')
    n, n_ja, n_jo, _ = weighted.shape
    if rules is None:
        future = weighted.max(-1).sum(-1)
    else:
        flat = weighted.reshape(n * n_ja, n_jo, -1)
        future = np.empty(n * n_ja)
        step = max(1, _CHUNK // (rules.shape[0] * n_jo))
        cols = np.arange(n_jo)[None, :]
        for lo in range(0, n * n_ja, step):
            part = flat[lo : lo + step]  # (m, JO, JA')
            future[lo : lo + step] = part[:, cols, rules].sum(-1).max(-1)  # (m, B, JO) -> (m,)
        future = future.reshape(n, n_ja)
    return beliefs @ tabs.reward.T + gamma * future


@dataclass
class _Layer:
    keys: dict[tuple[int, int], int]
    q: np.ndarray  # (n, JA)


class Heuristic:
    """``Q_BG`` (``kind="bg"``) or ``Q_POMDP`` (``kind="pomdp"``) of ``env`` at its finite horizon.

    Args:
        env: the problem (finite horizon; its gamma).
        kind: ``"bg"`` or ``"pomdp"``.
        max_entries: largest belief layer of the tree, in numbers.

    Inside a :class:`~decpomdp.budget.Budget` the FIB's tables of every step are reserved first, the tree is built to
    fit the memory budget, and every step checks the time (:class:`~decpomdp.budget.BudgetSpent` ends the build).
    """

    def __init__(self, env: TabularDecPOSMDP, kind: str = "bg", max_entries: int = DEFAULT_MAX_ENTRIES) -> None:
        if kind not in ("bg", "pomdp"):
            raise ValueError(f"kind: expected 'bg' or 'pomdp', got {kind!r}")
        self.horizon, self.gamma = int(env.horizon), env.gamma
        self.tabs = tables(env)
        n_ja, n_jo = self.tabs.obs.shape[0], self.tabs.obs.shape[2]
        rules_count = (env.num_actions**env.num_obs) ** env.num_agents
        self.rules = joint_rules(env) if kind == "bg" and rules_count <= MAX_RULES else None
        budget.reserve(self.horizon * self.tabs.reward.nbytes, f"the exact search's bounds of {self.horizon} steps")
        per_entry = 8 * LAYER_COPIES
        max_entries = budget.memory_limit(max_entries * per_entry) // per_entry
        self._fib = {1: self.tabs.reward}  # (JA, S) FIB Q of k steps
        for k in range(2, self.horizon + 1):
            budget.check()
            self._fib[k] = self.tabs.reward + self.gamma * fib_backup(self.tabs.trans, self.tabs.obs, self._fib[k - 1])
        # forwards: distinct beliefs of each layer, and the index of every child
        layers, links, masses = [env.start_dist.numpy()[None, :]], [], []
        while len(layers) < self.horizon and layers[-1].shape[0] * n_ja * n_jo * env.num_states <= max_entries:
            budget.check()
            mass, nxt = children(layers[-1], self.tabs)
            flat = nxt.reshape(-1, env.num_states)
            live = mass.reshape(-1) > 0
            keys = belief_keys(flat[live])
            _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
            index = np.zeros(flat.shape[0], dtype=np.int64)
            index[live] = inverse.reshape(-1)
            layers.append(flat[live][first])
            links.append(index.reshape(mass.shape))
            masses.append(mass)
        # backwards: Q of every layer (the deepest from the FIB)
        self._layers: list[_Layer] = [None] * len(layers)
        q = self._fib_q(len(layers) - 1, layers[-1])
        self._layers[-1] = _Layer(self._key_index(layers[-1]), q)
        for t in reversed(range(len(layers) - 1)):
            budget.check()
            q = backup(layers[t], masses[t], q[links[t]], self.tabs, self.gamma, self.rules)
            self._layers[t] = _Layer(self._key_index(layers[t]), q)

    @property
    def depth(self) -> int:
        """Layers of the belief tree built (the rest is the FIB)."""
        return len(self._layers)

    @property
    def root(self) -> float:
        """The bound at the start belief: ``max_ja Q(b0, ja)``."""
        return float(self._layers[0].q[0].max())

    @staticmethod
    def _key_index(beliefs: np.ndarray) -> dict[tuple[int, int], int]:
        return {tuple(k): i for i, k in enumerate(belief_keys(beliefs).tolist())}

    def _fib_q(self, t: int, beliefs: np.ndarray) -> np.ndarray:
        """``(n, JA)`` FIB ``Q`` of the ``h - t`` steps from step ``t``."""
        return beliefs @ self._fib[self.horizon - t].T

    def q(self, t: int, beliefs: np.ndarray) -> np.ndarray:
        """``(n, JA)`` upper bounds on ``Q*`` from step ``t`` for histories with the normalised ``beliefs (n, S)``."""
        if t >= self.horizon:
            return np.zeros((beliefs.shape[0], self.tabs.obs.shape[0]))
        if t >= len(self._layers):
            return self._fib_q(t, beliefs)
        layer = self._layers[t]
        index = np.array([layer.keys.get(tuple(k), -1) for k in belief_keys(beliefs).tolist()], dtype=np.int64)
        out = np.empty((beliefs.shape[0], layer.q.shape[1]))
        hit = index >= 0
        out[hit] = layer.q[index[hit]]
        if not hit.all():  # a belief the tree rounded otherwise: one backup from the next layer
            miss = beliefs[~hit]
            mass, nxt = children(miss, self.tabs)
            live = mass.reshape(-1) > 0
            q_next = np.zeros((live.size, out.shape[1]))
            q_next[live] = self.q(t + 1, nxt.reshape(-1, nxt.shape[-1])[live])
            q_next = q_next.reshape(*mass.shape, -1)
            out[~hit] = backup(miss, mass, q_next, self.tabs, self.gamma, self.rules)
        return out
