"""A tabular Dec-POMDP's rules for the compiled engine: every primitive action a unit-duration MA.

One rollout's state is the hidden state ``s`` (team entry). At each step every agent completes at
once: ``s' ~ T(. | s, ja)`` from the sparse CSR row ``ja * S + s``, ``jo ~ O(. | ja, s')``, reward
``R(s, ja, s', jo) / gamma`` (see :mod:`decpomdp.dpomdp.tabular` for the time convention), and each
agent observes its part of ``jo``. :class:`~decpomdp.dpomdp.tabular.TabularDecPOSMDP`'s batched
torch methods are the test oracle of these rules.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from decpomdp.engine import EngineDomain, StateLayout, uniform
from decpomdp.engine.loop import chunk_function, event_loop

STATE = 0  # the team entry holding s
P_GAMMA = 0


@njit(inline="always")
def first_above(cum, lo, hi, target):
    """The first index ``i`` in ``[lo, hi)`` with ``cum[i] > target`` (``hi - 1`` if none): binary search."""
    hi -= 1
    while lo < hi:
        mid = (lo + hi) // 2
        if cum[mid] > target:
            hi = mid
        else:
            lo = mid + 1
    return lo


@njit(inline="always")
def reset(si, sf, p, tab, perception, num_agents, rng):
    """``s ~ b0``."""
    start_cum = tab[0]
    n = start_cum.shape[0]
    si[STATE] = first_above(start_cum, 0, n, uniform(rng) * start_cum[n - 1])


@njit(inline="always")
def start(si, sf, p, tab, perception, agents, actions, t, end, rng):
    """Every action lasts one step."""
    for a in range(len(agents)):
        if agents[a]:
            end[a] = t + 1.0


@njit(inline="always")
def complete(si, sf, p, tab, perception, agents, actions, t, obs, rng):
    """One step of the joint action: next state, joint observation, reward."""
    _, indptr, indices, t_cum0, o_cum, reward_table, strides, action_strides, obs_strides = tab
    s = si[STATE]
    ja = 0
    for a in range(actions.shape[0]):
        ja += actions[a] * action_strides[a]
    row = ja * o_cum.shape[1] + s
    lo, hi = indptr[row], indptr[row + 1]
    target = t_cum0[lo] + uniform(rng) * (t_cum0[hi] - t_cum0[lo])
    s2 = indices[first_above(t_cum0[1:], lo, hi, target)]
    o_row = o_cum[ja, s2]
    jo = first_above(o_row, 0, o_row.shape[0], uniform(rng) * o_row[o_row.shape[0] - 1])
    si[STATE] = s2
    n_obs = obs_strides[0] if obs_strides.shape[0] > 1 else o_row.shape[0]
    for a in range(obs.shape[0]):
        obs[a] = (jo // obs_strides[a]) % n_obs
    i = ja * strides[0] + s * strides[1] + s2 * strides[2] + jo * strides[3]
    return reward_table[i] / p[P_GAMMA]


@chunk_function
def chunk(args, out, scratch, index, lo, hi):
    """The engine's event loop with these rules, on rollouts ``lo .. hi - 1``."""
    return event_loop(reset, start, complete, args, out, scratch, index, lo, hi)


ENGINE = EngineDomain(chunk, StateLayout(team=("s",)))


def tables(
    start_dist: np.ndarray,
    indptr: np.ndarray,
    indices: np.ndarray,
    data: np.ndarray,
    o_cum: np.ndarray,
    reward: np.ndarray,
    reward_strides: list[int],
    action_strides: np.ndarray,
    obs_strides: np.ndarray,
) -> tuple:
    """The rules' tables, each its own int64 / float64 buffer: start CDF (S,), CSR ``indptr`` (JA * S + 1,) and
    ``indices`` (nnz,), the running sum of the CSR data with a leading 0 (nnz + 1,), observation CDFs
    (JA, S', JO), the flat reward table and its strides over (ja, s, s', jo) (4,), and the action and
    observation strides of the agents (A,)."""
    f64, i64 = (lambda x: np.array(x, dtype=np.float64)), (lambda x: np.array(x, dtype=np.int64))
    return (
        np.cumsum(f64(start_dist)),
        i64(indptr),
        i64(indices),
        np.concatenate([[0.0], np.cumsum(f64(data))]),
        np.ascontiguousarray(f64(o_cum)),
        f64(reward),
        i64(reward_strides),
        i64(action_strides),
        i64(obs_strides),
    )
