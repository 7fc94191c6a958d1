"""Batched joint finite-state controllers: K joint controllers, one FSC per agent, start node 0."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from infra.tensorfile import load_tensors, save_tensors

_KIND = "decpomdp.JointController"
_VERSION = 1


@dataclass
class JointController:
    """K joint finite-state controllers for A agents with Nn nodes and O observations each.

    Attributes:
        action: long (K, A, Nn), the MA agent ``a`` runs in node ``n`` of controller ``k``.
        next_node: long (K, A, Nn, O), the node after observing ``o`` in node ``n``.

    Every agent starts in node 0.
    """

    action: Tensor
    next_node: Tensor

    def __post_init__(self) -> None:
        for name, value in (("action", self.action), ("next_node", self.next_node)):
            if not isinstance(value, Tensor) or value.dtype != torch.long:
                raise TypeError(f"{name}: expected a torch.long tensor, got {type(value).__name__}"
                                f"{'' if not isinstance(value, Tensor) else ' of ' + str(value.dtype)}")
        if self.action.dim() != 3:
            raise ValueError(f"action: expected shape (K, A, Nn), got {tuple(self.action.shape)}")
        k, a, nn = self.action.shape
        if self.next_node.dim() != 4 or tuple(self.next_node.shape[:3]) != (k, a, nn):
            raise ValueError(f"next_node: expected shape ({k}, {a}, {nn}, O), got {tuple(self.next_node.shape)}")
        if min(k, a, nn, self.next_node.shape[3]) < 1:
            raise ValueError(f"action/next_node: every dimension must be >= 1, got {tuple(self.next_node.shape)}")
        if bool((self.action < 0).any()):
            raise ValueError("action: entries must be >= 0")
        if bool(((self.next_node < 0) | (self.next_node >= nn)).any()):
            raise ValueError(f"next_node: entries must lie in [0, {nn})")

    @property
    def num_controllers(self) -> int:
        return self.action.shape[0]

    @property
    def num_agents(self) -> int:
        return self.action.shape[1]

    @property
    def num_nodes(self) -> int:
        return self.action.shape[2]

    @property
    def num_obs(self) -> int:
        return self.next_node.shape[3]

    @classmethod
    def trusted(cls, action: Tensor, next_node: Tensor) -> JointController:
        """A controller built from tables already known to be valid (rows of checked controllers, samples of
        the planners' distributions), without the checks: they cost more than a batch of rollouts."""
        out = cls.__new__(cls)
        out.action, out.next_node = action, next_node
        return out

    def __getitem__(self, index: int | slice | Tensor) -> JointController:
        """Select controllers along K (an int keeps K = 1)."""
        if isinstance(index, int):
            index = slice(index, index + 1) if index != -1 else slice(-1, None)
        action, next_node = self.action[index], self.next_node[index]
        if action.dim() != 3 or action.shape[0] == 0:
            return JointController(action, next_node)  # raises
        return JointController.trusted(action, next_node)

    @staticmethod
    def cat(controllers: list[JointController]) -> JointController:
        """Concatenate controllers along K (each already checked)."""
        return JointController.trusted(torch.cat([c.action for c in controllers]),
                                       torch.cat([c.next_node for c in controllers]))

    def save(self, path: str | os.PathLike) -> Path:
        """Atomically write the controllers to one safetensors file (no pickle)."""
        meta = {"shape": list(self.next_node.shape)}
        return save_tensors(path, _KIND, {"action": self.action, "next_node": self.next_node}, meta, version=_VERSION)

    @classmethod
    def load(cls, path: str | os.PathLike) -> JointController:
        """Read controllers written by :meth:`save`; a corrupt or foreign file raises ``ValueError``."""
        tensors, _ = load_tensors(path, _KIND, version=_VERSION)
        if set(tensors) != {"action", "next_node"}:
            raise ValueError(f"path: {str(path)!r} holds {sorted(tensors)}, expected a JointController's action and "
                             "next_node")
        try:
            return cls(tensors["action"], tensors["next_node"])
        except (TypeError, ValueError) as exc:
            raise ValueError(f"path: {str(path)!r} holds an invalid controller ({exc})") from None
