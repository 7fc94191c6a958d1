"""Restarted GMRES for many independent linear systems at once (one per controller).

The unknowns of all systems are stacked as rows of one (C, S) tensor; ``owner[c]`` says which
system row ``c`` belongs to. The operator is applied to the whole stack in one call (it must not
mix systems); inner products, norms and the small least-squares problems are per system, so every
system runs its own GMRES(m) iteration in lock step. Work tensors live on the device of ``b``.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from decpomdp import budget

_TINY = 1e-300
_BREAKDOWN = 1e-12  # relative size of the orthogonalised vector below which the Krylov space is invariant


def _dot(x: Tensor, y: Tensor, owner: Tensor, k: int) -> Tensor:
    """Per-system inner products (K,) of stacked (C, S) tensors."""
    return torch.zeros(k, dtype=x.dtype, device=x.device).index_add_(0, owner, (x * y).sum(1))


def _max_abs(x: Tensor, owner: Tensor, k: int) -> Tensor:
    """Per-system max-norms (K,)."""
    return torch.zeros(k, dtype=x.dtype, device=x.device).scatter_reduce_(0, owner, x.abs().amax(1), "amax")


def gmres(
    apply: Callable[[Tensor], Tensor],
    b: Tensor,
    owner: Tensor,
    k: int,
    tol: float,
    restart: int = 30,
    max_restarts: int = 200,
) -> Tensor:
    """Solve ``A x = b`` for K stacked systems until every residual's max-norm is at most ``tol``.

    Args:
        apply: ``x (C, S) -> A x (C, S)``, block diagonal over systems.
        b: float64 (C, S) right-hand sides.
        owner: long (C,), the system of every row.
        k: number of systems.
        tol: required ``max |b - A x|`` per system.
        restart: Krylov dimension m before each restart.
        max_restarts: give up (RuntimeError) after this many restarts.

    Every Krylov step checks a running :class:`~decpomdp.budget.Budget` (it may end the solve).
    """
    x = torch.zeros_like(b)
    for _ in range(max_restarts):
        r = b - apply(x)
        if bool((_max_abs(r, owner, k) <= tol).all()):
            return x
        beta = _dot(r, r, owner, k).sqrt()
        basis = [r / beta.clamp_min(_TINY)[owner, None]]
        h = torch.zeros(k, restart + 1, restart, dtype=b.dtype, device=b.device)
        for j in range(restart):
            budget.check()
            w = apply(basis[j])
            before = _dot(w, w, owner, k).sqrt()
            for _ in range(2):  # modified Gram-Schmidt, twice: keeps the basis orthogonal to rounding
                for i in range(j + 1):
                    hij = _dot(w, basis[i], owner, k)
                    h[:, i, j] += hij
                    w -= hij[owner, None] * basis[i]
            norm = _dot(w, w, owner, k).sqrt()
            # (lucky) breakdown: the Krylov space is invariant, the solution lies in it; a rounding-noise
            # vector would not be orthogonal to the basis, so it is replaced by zero
            norm = torch.where(norm > _BREAKDOWN * before, norm, 0.0)
            h[:, j + 1, j] = norm
            basis.append(torch.where((norm > 0)[owner, None], w / norm.clamp_min(_TINY)[owner, None], 0.0))
        rhs = torch.zeros(k, restart + 1, dtype=b.dtype, device=b.device)
        rhs[:, 0] = beta
        y = torch.linalg.lstsq(h, rhs[..., None]).solution[..., 0]  # (K, m)
        for j in range(restart):
            x += y[:, j][owner, None] * basis[j]
    raise RuntimeError(f"gmres: residual above {tol} after {max_restarts} restarts of {restart} steps")
