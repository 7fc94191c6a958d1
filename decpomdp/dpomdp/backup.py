"""The factored Bellman backup of fixed joint controllers on a tabular Dec-POMDP.

A *column* is one (controller k, joint node q) pair. With ``a = a(k, q)`` its joint action and
``n(jo)`` its next column after joint observation ``jo``, the backup of values ``V`` (one row of S
values per column) is

    (P V)[c, s] = sum_{s'} T(s' | s, a) W[c, s'],   W[c, s'] = sum_{jo} O(jo | a, s') V[n(jo), s'],

computed in two passes: first over joint observations into ``W`` (JO gathers of (C, S') rows), then
one sparse (or, for dense rows, dense) matrix product per joint action over all the columns that use
it. No (S x S' x JO) tensor is ever formed; the work is ``C * (JO * S + nnz(T) / JA)``.
"""

from __future__ import annotations

import warnings
import weakref
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.dpomdp.tabular import TabularDecPOSMDP

DENSE_FRACTION = 0.25
"""A joint action's transition matrix is kept dense when at least this fraction of it is nonzero."""


class TransitionOperator:
    """Per joint action, ``T[a]`` as an (S, S') torch CSR matrix (dense when dense enough), plus O and R tables.

    Args:
        env: the tabular problem.
        device: where every table lives (CPU by default).

    Attributes:
        device: the device of every table.
        matrices: per joint action, float64 (S, S') sparse CSR or dense tensor.
        obs_rows: float64 (JA * JO, S'), row ``a * JO + jo`` is ``O(jo | a, .)``.
        reward: float64 (JA, S) expected immediate reward.
    """

    def __init__(self, env: TabularDecPOSMDP, device: torch.device | str = "cpu") -> None:
        self.device = torch.device(device)
        t = env.model.transition
        n_ja, n_s = t.shape[:2]
        self.num_states, self.num_joint_obs = n_s, env.observation.shape[-1]
        self.matrices: list[Tensor] = []
        for a in range(n_ja):
            lo, hi = int(t.indptr[a * n_s]), int(t.indptr[(a + 1) * n_s])
            crow = torch.as_tensor(t.indptr[a * n_s : (a + 1) * n_s + 1] - lo)
            with warnings.catch_warnings():  # "sparse CSR support is in beta": the product used here is stable
                warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
                csr = torch.sparse_csr_tensor(
                    crow,
                    torch.as_tensor(t.indices[lo:hi]),
                    torch.as_tensor(t.data[lo:hi]),
                    size=(n_s, n_s),
                    dtype=torch.float64,
                    check_invariants=True,
                )
            self.matrices.append((csr.to_dense() if hi - lo >= DENSE_FRACTION * n_s * n_s else csr).to(self.device))
        self.obs_rows = env.observation.permute(0, 2, 1).reshape(-1, n_s).contiguous().to(self.device)
        self.reward = env.expected_reward.to(self.device)

    def dense(self, a: int) -> Tensor:
        """``T[a]`` as a dense (S, S') tensor."""
        m = self.matrices[a]
        return m if m.layout == torch.strided else m.to_dense()

    def backup(self, v: Tensor, cols: Columns) -> Tensor:
        """``P V`` (C, S) for the columns ``cols``; ``v`` (C', S) holds the values of ``cols.next``'s targets.

        Per joint action (a run of columns), ``sum_jo O(jo | a, .) * V(next_jo)``: the observation row is
        broadcast over the run, not gathered per column."""
        jo_count = self.num_joint_obs
        out = torch.empty(cols.action.numel(), self.num_states, dtype=torch.float64, device=self.device)
        for a, lo, hi in cols.groups:
            nxt = v.index_select(0, cols.next[lo:hi].reshape(-1)).view(hi - lo, jo_count, -1)
            w = torch.zeros(hi - lo, self.num_states, dtype=torch.float64, device=self.device)
            for jo in range(jo_count):
                w.addcmul_(self.obs_rows[a * jo_count + jo], nxt[:, jo])
            out[lo:hi] = (self.matrices[a] @ w.T).T
        return out


_OPERATORS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def operator_for(env: TabularDecPOSMDP, device: torch.device | str = "cpu") -> TransitionOperator:
    """The (cached, one per device) :class:`TransitionOperator` of ``env`` on ``device``."""
    device = torch.device(device)
    per_device = _OPERATORS.setdefault(env, {})
    op = per_device.get(device)
    if op is None:
        op = per_device[device] = TransitionOperator(env, device)
    return op


@dataclass
class Columns:
    """A set of (controller, joint node) columns, sorted by joint action.

    Attributes:
        ids: long (C,), flat id ``k * Q + q`` of every column.
        action: long (C,), its joint action.
        next: long (C, JO), for every joint observation the *position* of the next column in the
            column set it backs up from (filled by :func:`link`).
        next_ids: long (C, JO), flat ids of the next columns.
        groups: (joint action, start, end) of every run of equal actions.
    """

    ids: Tensor
    action: Tensor
    next: Tensor
    next_ids: Tensor
    groups: list[tuple[int, int, int]]


class JointNodes:
    """Joint action and successors of the joint nodes of K joint controllers (first agent most significant).

    Every index table lives on ``device`` (default: the controller's); ids passed to :meth:`columns` must too.
    """

    def __init__(
        self, env: TabularDecPOSMDP, controller: JointController, device: torch.device | str | None = None
    ) -> None:
        _, a, nn = controller.action.shape
        self.device = controller.action.device if device is None else torch.device(device)
        self.num_nodes, self.num_joint = nn, nn**a
        self.action, self.next_node = controller.action.to(self.device), controller.next_node.to(self.device)
        self.node_strides = torch.tensor([nn ** (a - 1 - i) for i in range(a)], device=self.device)
        self.action_strides = env.action_strides.to(self.device)
        self.agent = torch.arange(a, device=self.device)
        self.obs = env.split_obs(torch.arange(env.observation.shape[-1])).to(self.device)  # (JO, A)

    def columns(self, ids: Tensor) -> Columns:
        """The :class:`Columns` for flat ids ``k * Q + q`` (any order; duplicates not allowed)."""
        k, q = ids // self.num_joint, ids % self.num_joint
        nodes = (q[:, None] // self.node_strides) % self.num_nodes  # (C, A)
        ja = (self.action[k[:, None], self.agent, nodes] * self.action_strides).sum(-1)  # env.joint_action
        nxt = self.next_node[k[:, None, None], self.agent, nodes[:, None, :], self.obs[None, :, :]]  # (C, JO, A)
        next_ids = k[:, None] * self.num_joint + (nxt * self.node_strides).sum(-1)
        order = torch.sort(ja, stable=True).indices
        ja, ids, next_ids = ja[order], ids[order], next_ids[order]
        counts = torch.bincount(ja).tolist()
        ends = np.cumsum(counts)
        groups = [(a, int(e - c), int(e)) for a, (c, e) in enumerate(zip(counts, ends)) if c]
        return Columns(ids, ja, torch.empty(0, dtype=torch.long, device=self.device), next_ids, groups)


def link(cols: Columns, targets: Columns, num_ids: int) -> None:
    """Point ``cols.next`` at the positions of ``cols.next_ids`` within ``targets`` (which must contain them)."""
    pos = torch.full((num_ids,), -1, dtype=torch.long, device=targets.ids.device)
    pos[targets.ids] = torch.arange(targets.ids.numel(), device=targets.ids.device)
    cols.next = pos[cols.next_ids]
