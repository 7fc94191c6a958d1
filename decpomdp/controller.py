"""Batched joint finite-state controllers: K joint controllers, one FSC per agent, start node 0."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from hbni_infra.checks import as_names, first_difference
from hbni_infra.tensorfile import load_tensors, save_tensors

_KIND = "decpomdp.JointController"
_VERSION = 1


@dataclass
class JointController:
    """K joint finite-state controllers for A agents with Nn nodes and O observations each.

    Attributes:
        action: long (K, A, Nn), the MA agent ``a`` runs in node ``n`` of controller ``k``.
        next_node: long (K, A, Nn, O), the node after observing ``o`` in node ``n``.
        action_names, obs_names: the names of the domain's MAs and observations the controller was planned for
            (``None``: unnamed); saved with it, and checked against a domain it is run in.

    Every agent starts in node 0.
    """

    action: Tensor
    next_node: Tensor
    action_names: tuple[str, ...] | None = None
    obs_names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        for name, value in (("action", self.action), ("next_node", self.next_node)):
            if not isinstance(value, Tensor) or value.dtype != torch.long:
                raise TypeError(
                    f"{name}: expected a torch.long tensor, got {type(value).__name__}"
                    f"{'' if not isinstance(value, Tensor) else ' of ' + str(value.dtype)}"
                )
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
        self.action_names = as_names("action_names", self.action_names, int(self.action.max()) + 1, at_least=True)
        self.obs_names = as_names("obs_names", self.obs_names, self.next_node.shape[3])

    def named(self, action_names: Sequence[str] | None, obs_names: Sequence[str] | None) -> JointController:
        """The same controllers, named after a domain's MAs and observations."""
        return JointController(self.action, self.next_node, action_names, obs_names)

    def check_names(self, action_names: Sequence[str], obs_names: Sequence[str], what: str = "env") -> None:
        """Raise ``ValueError`` naming both lists unless the names the controller was planned with (when it has
        them) are ``action_names`` and ``obs_names`` (a domain's, ``what``), in that order."""
        for kind, planned, domain in (
            ("action_names", self.action_names, action_names),
            ("obs_names", self.obs_names, obs_names),
        ):
            if planned is not None and tuple(planned) != tuple(domain):
                first = first_difference(planned, domain)
                raise ValueError(
                    f"controller: planned for other {kind} than {what}'s (first difference at index {first}): "
                    f"{list(planned)} there, {list(domain)} in {what}"
                )

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
        """Select controllers along K (an int keeps K = 1; one outside ``[-K, K)`` is an ``IndexError`` naming the
        range)."""
        if isinstance(index, int) and not isinstance(index, bool):
            k = self.num_controllers
            if not -k <= index < k:
                raise IndexError(
                    f"index: {index} is out of range for {k} joint controller(s): expected -{k} to {k - 1}"
                )
            index = slice(index, index + 1) if index != -1 else slice(-1, None)
        action, next_node = self.action[index], self.next_node[index]
        if action.dim() != 3 or action.shape[0] == 0:
            return JointController(action, next_node)  # raises
        out = JointController.trusted(action, next_node)
        out.action_names, out.obs_names = self.action_names, self.obs_names
        return out

    @staticmethod
    def cat(controllers: list[JointController]) -> JointController:
        """Concatenate controllers along K (each already checked)."""
        return JointController.trusted(
            torch.cat([c.action for c in controllers]), torch.cat([c.next_node for c in controllers])
        )

    def save(self, path: str | os.PathLike) -> Path:
        """Atomically write the controllers to one safetensors file (no pickle)."""
        meta = {
            "shape": list(self.next_node.shape),
            "action_names": None if self.action_names is None else list(self.action_names),
            "obs_names": None if self.obs_names is None else list(self.obs_names),
        }
        return save_tensors(path, _KIND, {"action": self.action, "next_node": self.next_node}, meta, version=_VERSION)

    @classmethod
    def load(cls, path: str | os.PathLike) -> JointController:
        """Read controllers written by :meth:`save`; a corrupt or foreign file raises ``ValueError``."""
        tensors, meta = load_tensors(path, _KIND, version=_VERSION)
        if set(tensors) != {"action", "next_node"}:
            raise ValueError(
                f"path: {str(path)!r} holds {sorted(tensors)}, expected a JointController's action and next_node"
            )
        try:
            return cls(tensors["action"], tensors["next_node"], meta.get("action_names"), meta.get("obs_names"))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"path: {str(path)!r} holds an invalid controller ({exc})") from None
