"""Pairwise coupling: pairwise probabilities ``r[i, j] = P(y = i | y in {i, j})`` -> ``p`` on the simplex.

Method 2 of Wu, Lin & Weng (2004), the one libsvm's ``multiclass_probability`` uses:
``min_p 1/2 p^T Q p`` subject to ``sum(p) = 1`` with ``Q_tt = sum_{j != t} r_jt^2`` and
``Q_tj = -r_jt r_tj``. libsvm runs a fixed-point iteration to a loose tolerance; here the
equality-constrained quadratic program is solved exactly, one batched linear solve of its
KKT system ``[[Q, 1], [1^T, 0]] [p; b] = [0; 1]``. Wu et al. (Theorem 2) show the solution
is non-negative; a last clamp guards rounding.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["pairwise_coupling"]


def pairwise_coupling(r: Tensor) -> Tensor:
    """Couple pairwise probabilities ``r (B, M, M)`` (``r[i, j] + r[j, i] = 1``, diagonal ignored) -> ``(B, M)``."""
    if r.ndim != 3 or r.shape[1] != r.shape[2]:
        raise ValueError(f"r: expected shape (B, M, M), got {tuple(r.shape)}")
    bsz, m, _ = r.shape
    r = r.double()
    eye = torch.eye(m, dtype=torch.bool)
    rt = r.transpose(1, 2)  # rt[t, j] = r[j, t]
    q = torch.where(eye, 0.0, -rt * r)  # Q[t, j] = -r[j, t] r[t, j]
    diag = torch.where(eye, 0.0, rt * rt).sum(-1)  # Q[t, t] = sum_j r[j, t]^2
    q = q + torch.diag_embed(diag)
    kkt = torch.zeros(bsz, m + 1, m + 1, dtype=torch.float64)
    kkt[:, :m, :m] = q
    kkt[:, :m, m] = 1.0
    kkt[:, m, :m] = 1.0
    rhs = torch.zeros(bsz, m + 1, dtype=torch.float64)
    rhs[:, m] = 1.0
    p = torch.linalg.solve(kkt, rhs)[:, :m].clamp_min(0.0)
    return p / p.sum(-1, keepdim=True)
