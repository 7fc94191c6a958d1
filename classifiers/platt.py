"""Platt scaling: ``P(y = +1 | f) = 1 / (1 + exp(A f + B))`` fitted to decision values.

Platt (1999) with the smoothed targets ``t+ = (N+ + 1) / (N+ + 2)``, ``t- = 1 / (N- + 2)`` and
the Newton method with backtracking of Lin, Lin & Weng (2007), the one libsvm uses,
vectorised over many independent problems (one per class pair, or per pair and fold).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["fit_platt", "platt_predict"]


def _loss(a: Tensor, b: Tensor, f: Tensor, t: Tensor, w: Tensor) -> Tensor:
    z = a[:, None] * f + b[:, None]  # (P, N); p = sigmoid(-z)
    # -[t log p + (1 - t) log(1 - p)] = t * softplus(z) + (1 - t) * softplus(-z) = softplus(z) - (1 - t) z
    return (w * (torch.nn.functional.softplus(z) - (1 - t) * z)).sum(-1)


def fit_platt(
    scores: Tensor, positive: Tensor, mask: Tensor | None = None, max_iter: int = 100, tol: float = 1e-10
) -> tuple[Tensor, Tensor]:
    """Fit Platt's sigmoid to each row of ``scores``.

    Args:
        scores: decision values ``(P, N)`` (or ``(N,)`` for one problem).
        positive: bool ``(P, N)``, True where the example belongs to the positive class.
        mask: bool ``(P, N)``, which examples take part in each problem (default all).
        max_iter: Newton iterations.
        tol: stop when every gradient entry is below ``tol`` times the example count.

    Returns:
        ``(A, B)``, each ``(P,)`` (or scalars for 1-D input), float64.
    """
    squeeze = scores.ndim == 1
    f = torch.atleast_2d(scores).double()
    pos = torch.atleast_2d(positive).bool()
    w = torch.ones_like(f) if mask is None else torch.atleast_2d(mask).double()
    if pos.shape != f.shape or w.shape != f.shape:
        raise ValueError(f"positive/mask: expected shape {tuple(f.shape)}, got {tuple(pos.shape)}/{tuple(w.shape)}")
    n_pos = (w * pos).sum(-1)
    n_neg = (w * ~pos).sum(-1)
    t = torch.where(pos, ((n_pos + 1) / (n_pos + 2))[:, None], (1 / (n_neg + 2))[:, None])
    a = torch.zeros_like(n_pos)
    b = torch.log((n_neg + 1) / (n_pos + 1))
    loss = _loss(a, b, f, t, w)
    sigma = 1e-12  # Levenberg floor on the Hessian diagonal (libsvm's choice)
    for _ in range(max_iter):
        z = a[:, None] * f + b[:, None]
        p = torch.sigmoid(-z)  # P(y=+1)
        d1 = w * (t - p)  # d loss / d z
        g_a, g_b = (d1 * f).sum(-1), d1.sum(-1)
        if torch.all(torch.maximum(g_a.abs(), g_b.abs()) < tol * w.sum(-1).clamp_min(1)):
            break
        d2 = w * p * (1 - p)
        h11, h22, h21 = (d2 * f * f).sum(-1) + sigma, d2.sum(-1) + sigma, (d2 * f).sum(-1)
        det = h11 * h22 - h21 * h21
        da = -(h22 * g_a - h21 * g_b) / det
        db = -(-h21 * g_a + h11 * g_b) / det
        gd = g_a * da + g_b * db
        step = torch.ones_like(a)
        pending = torch.ones_like(a, dtype=torch.bool)
        for _ in range(60):  # backtracking (Armijo), every problem at once
            new = _loss(a + step * da, b + step * db, f, t, w)
            ok = new < loss + 1e-4 * step * gd
            accept = pending & ok
            a = torch.where(accept, a + step * da, a)
            b = torch.where(accept, b + step * db, b)
            loss = torch.where(accept, new, loss)
            pending = pending & ~ok
            if not pending.any():
                break
            step = torch.where(pending, step / 2, step)
        if pending.all():  # no problem can improve further
            break
    if squeeze:
        return a[0], b[0]
    return a, b


def platt_predict(scores: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """``P(y = +1 | f) = sigmoid(-(A f + B))``; ``scores (..., P)`` with ``A, B`` of shape ``(P,)``."""
    return torch.sigmoid(-(scores.double() * a + b))
