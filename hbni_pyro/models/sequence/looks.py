"""The sequence model's look terms: how a sequence's mean look tells classes apart, its look integrated out.

In the two-level model a sequence's look ``mu ~ N(loc_c, between_c)`` and its frames ``y_i ~ N(mu, within)``
(log-ratio coordinates, :func:`hbni_pyro.distributions.density.ilr`). Integrating ``mu`` out, ``n`` frames enter
only through ``n``, their mean and their scatter: :func:`look_log_marginal` (the mean look, which depends on the
class) times :func:`within_log_prob` (the scatter, which does not). :func:`look_basis` diagonalises
``between + within / n`` for every ``n`` at once, so the program, the kernel and the evidence evaluate both terms
for any frame count from one decomposition.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def look_basis(between: Tensor, within: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """A basis in which ``between + within / n`` is diagonal for every ``n`` at once.

    With ``within = L L^T`` and ``L^-1 between L^-T = Q diag(lam) Q^T``, the matrix ``A = Q^T L^-1``
    gives ``A (between + within / n) A^T = diag(lam + 1/n)`` and
    ``log|between + within / n| = log|within| + sum_i log(lam_i + 1/n)``.

    Args:
        between, within: ``(..., d, d)`` covariances (broadcasting).

    Returns:
        ``A (..., d, d)``, ``lam (..., d)`` and ``log|within| (...)``.
    """
    tril = torch.linalg.cholesky(within)
    eye = torch.eye(within.shape[-1], dtype=within.dtype, device=within.device)
    tril_inv = torch.linalg.solve_triangular(tril, eye, upper=False)
    lam, q = torch.linalg.eigh(tril_inv @ between @ tril_inv.transpose(-1, -2))
    return q.transpose(-1, -2) @ tril_inv, lam, 2 * tril.diagonal(dim1=-2, dim2=-1).log().sum(-1)


def look_variance(count: Tensor | float, lam: Tensor) -> tuple[Tensor, Tensor]:
    """The variances ``lam + 1/n`` of a look's mean in the basis of :func:`look_basis`, ``(..., d)``, and the sum of
    their logs ``(...)`` (``count`` broadcasts against ``lam``'s batch shape)."""
    count = torch.as_tensor(count, dtype=lam.dtype)
    var = lam + 1 / (count.unsqueeze(-1) if count.dim() else count)
    return var, var.log().sum(-1)


def look_log_marginal(count: Tensor | float, resid: Tensor, lam: Tensor, logdet_within: Tensor) -> Tensor:
    """``log N(ybar; loc, between + within / n)``: how a sequence's mean look tells classes apart.

    In the two-level model a sequence's look ``mu ~ N(loc_c, between_c)`` and its frames
    ``y_i ~ N(mu, within)`` (log-ratio coordinates); integrating ``mu`` out, the ``n`` frames'
    density is this term times :func:`within_log_prob`, which does not depend on the class.

    Args:
        count: frames ``n`` (broadcasts against the result).
        resid: ``A (ybar - loc)`` in the basis of :func:`look_basis`, ``(..., d)``.
        lam, logdet_within: from :func:`look_basis`, ``(..., d)`` and ``(...)``.

    Returns:
        ``(...)`` log density.
    """
    var, log_var = look_variance(count, lam)
    d = resid.shape[-1]
    return -0.5 * ((resid * resid / var).sum(-1) + log_var + logdet_within + d * math.log(2 * math.pi))


def within_log_prob(count: Tensor | float, trace: Tensor, logdet_within: Tensor, dim: int) -> Tensor:
    """The rest of ``n`` frames' density in the two-level model (see :func:`look_log_marginal`):
    ``-(n - 1) d/2 log 2 pi - (n - 1)/2 log|W| - d/2 log n - trace/2``.

    Args:
        count: frames ``n``; trace: ``tr(W^-1 scatter)`` with ``scatter = sum_i (y_i - ybar)(y_i - ybar)^T``
            (see :func:`scatter_trace`); logdet_within: ``log|W|``; dim: ``d``. All broadcast.
    """
    count = torch.as_tensor(count, dtype=trace.dtype)
    return -0.5 * (count - 1) * (dim * math.log(2 * math.pi) + logdet_within) - 0.5 * dim * count.log() - 0.5 * trace


def scatter_trace(prec: Tensor, scatter: Tensor) -> Tensor:
    """``tr(prec @ scatter)`` for symmetric matrices ``(..., d, d)`` (broadcasting)."""
    return (prec * scatter).sum((-1, -2))
