"""Small tensor helpers for the batched simulator and the domains' fast paths (CPU).

Masks in the fast paths are uint8 0/1 tensors (bool tensors seen through ``view(torch.uint8)``):
on CPU, ops that produce or consume bool tensors (``where``, ``==``, ``any``) cost several times
more than integer arithmetic, so selections are arithmetic blends ``b + mask * (a - b)``, negation
is ``mask ^ 1``, and equalities of small integers are ``1 - min((a - b) ** 2, 1)``.
"""

from __future__ import annotations

import sys

import torch
from torch import Tensor


def any_true(mask: Tensor) -> bool:
    """``bool(mask.any())`` for a contiguous bool or uint8 tensor (a uint8 max, much faster than ``any`` on CPU)."""
    return mask.numel() > 0 and bool(mask.view(torch.uint8).max())


def lookup(table: Tensor, index: Tensor) -> Tensor:
    """``table[index]`` for a 1-D table and an int32/int64 index (a flat ``index_select``, the fastest gather on CPU)."""
    return table.index_select(0, index.reshape(-1)).view(index.shape)


def as_u8(mask: Tensor) -> Tensor:
    """uint8 0/1 view of a bool tensor (no copy when contiguous)."""
    return mask.contiguous().view(torch.uint8)


def equal_u8(a: Tensor, b: Tensor) -> Tensor:
    """uint8 0/1: ``a == b`` for integer tensors."""
    d = a - b
    return (1 - d.mul_(d).clamp_(max=1)).to(torch.uint8)


def pair(x: Tensor) -> Tensor:
    """(B,) -> contiguous (B, 2) with ``x`` in both columns (ops broadcasting a (B, 1) operand are slow on CPU)."""
    if x.dtype == torch.uint8 and sys.byteorder == "little":  # each byte doubled: x * 257 as int16
        return x.to(torch.int16).mul_(257).view(torch.uint8).view(-1, 2)
    return torch.stack([x, x], dim=1)


def select(mask: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """``where(mask, a, b)`` for a uint8 0/1 mask and finite float tensors, exact (a lerp with weight 0 or 1)."""
    return torch.lerp(b, a.to(b.dtype), mask.to(b.dtype))
