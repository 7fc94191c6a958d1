"""The tabular Dec-POMDP a ``.dpomdp`` file describes, stored compactly.

Real problems have thousands of states and mostly-zero transition matrices, and their rewards
depend on one or two of (joint action, state, next state, joint observation). So transitions are a
sparse CSR table over rows ``(ja, s)``, observations a dense ``(JA, S', JO)`` table, and the reward
a dense array over only the indices it depends on (size 1 along the others), which broadcasts to
the full ``(JA, S, S', JO)`` table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_CHUNK = 1 << 20  # nonzeros per block when the expected reward gathers (nnz, JO) tables


@dataclass
class SparseTransitions:
    """``P(s' | s, ja)`` as one CSR matrix whose row ``ja * S + s`` holds ``T(. | s, ja)``.

    Attributes:
        num_actions, num_states: JA and S (the table is (JA, S, S')).
        indptr: int64 (JA * S + 1,), row offsets into ``indices``/``data``.
        indices: int64 (nnz,), next states, ascending within each row.
        data: float64 (nnz,), nonzero probabilities.
    """

    num_actions: int
    num_states: int
    indptr: np.ndarray
    indices: np.ndarray
    data: np.ndarray

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.num_actions, self.num_states, self.num_states

    @property
    def nnz(self) -> int:
        return int(self.data.size)

    def rows(self) -> np.ndarray:
        """int64 (nnz,): the row ``ja * S + s`` of every stored entry."""
        return np.repeat(np.arange(self.indptr.size - 1), np.diff(self.indptr))

    def row_sums(self) -> np.ndarray:
        """(JA, S) total probability of every row."""
        return np.bincount(self.rows(), self.data, minlength=self.indptr.size - 1).reshape(self.shape[:2])

    def toarray(self) -> np.ndarray:
        """The dense (JA, S, S') table (for small problems and tests)."""
        out = np.zeros((self.indptr.size - 1) * self.num_states)
        out[self.rows() * self.num_states + self.indices] = self.data
        return out.reshape(self.shape)


@dataclass
class DPOMDPModel:
    """A tabular Dec-POMDP (numpy float64 tables).

    Attributes:
        agent_names, state_names: lists of names.
        action_names, obs_names: per agent, a list of names.
        discount: the file's discount (a caller may use another).
        start: (S,) initial state distribution.
        transition: ``P(s' | s, ja)``, sparse (see :class:`SparseTransitions`).
        observation: (JA, S', JO) ``P(jo | ja, s')``.
        reward: reward (negated cost for ``values: cost``) of shape (JA or 1, S or 1, S' or 1, JO or 1):
            size 1 along every index it does not depend on; ``np.broadcast_to(reward, (JA, S, S', JO))``
            is the full table.
    """

    agent_names: list[str]
    state_names: list[str]
    action_names: list[list[str]]
    obs_names: list[list[str]]
    discount: float
    start: np.ndarray
    transition: SparseTransitions
    observation: np.ndarray
    reward: np.ndarray

    @property
    def num_agents(self) -> int:
        return len(self.agent_names)

    @property
    def num_states(self) -> int:
        return len(self.state_names)

    def expected_reward(self) -> np.ndarray:
        """(JA, S) ``R(s, ja) = sum_{s', jo} T(s'|s, ja) O(jo|ja, s') R(ja, s, s', jo)``, over the nonzeros of T."""
        t, r = self.transition, self.reward
        n_ja, n_s = t.shape[:2]
        rows = t.rows()
        out = np.zeros(n_ja * n_s)
        for lo in range(0, t.nnz, _CHUNK):
            row, s2, p = rows[lo : lo + _CHUNK], t.indices[lo : lo + _CHUNK], t.data[lo : lo + _CHUNK]
            ja, s = row // n_s, row % n_s
            pick = [ja if r.shape[0] > 1 else 0, s if r.shape[1] > 1 else 0, s2 if r.shape[2] > 1 else 0]
            r_jo = r[pick[0], pick[1], pick[2]]  # (n, JO or 1)
            inner = (self.observation[ja, s2] * r_jo).sum(-1)  # sum over jo of O * R
            out += np.bincount(row, p * inner, minlength=n_ja * n_s)
        return out.reshape(n_ja, n_s)
