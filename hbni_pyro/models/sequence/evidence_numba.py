"""Compiled evidence of the sequence model for statistics on the CPU.

:meth:`.evidence.SequenceEvidence.log_evidence` averages, for every block of outputs and class, the two-level
density over a few thousand posterior draws. Done with torch, one block at a time (so that one stream and a batch of
streams agree exactly), a block costs a dozen passes over ``(S, M, d)`` tensors and their hand-offs; this loop makes
one pass per block, vectorised over the draws, and sums each class's terms over the draws in one fixed order, so a
block's value does not depend on the blocks beside it either. It computes what the torch path computes (its test
oracle), up to rounding.

Shapes: ``K`` blocks, ``S`` draws, ``M`` classes, ``d`` look dimensions.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from hbni_infra.numba_cache import use_cache_dir

use_cache_dir()  # before any cached function is decorated

_LOG_2PI = math.log(2.0 * math.pi)
_FLOOR = -700.0  # terms below exp(-700) cannot change a sum that is >= 1 (as logsumexp_in_order clamps them)


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract", "nsz", "arcp"})
def log_evidence(
    mean_y: np.ndarray,
    scatter: np.ndarray,
    counts: np.ndarray,
    variance: np.ndarray,
    log_variance: np.ndarray,
    basis: np.ndarray,
    basis_loc: np.ndarray,
    within_prec: np.ndarray,
    logdet: np.ndarray,
    scale: float,
) -> np.ndarray:
    """``log sum_s exp(look_s + within_s)`` per block and class, ``(K, M)`` (the mean over draws before its
    ``- log S`` and the correlation's shift).

    Args:
        mean_y: ``(K, d)`` each block's mean look; scatter: ``(K, d, d)`` its scatter about that mean.
        counts: ``(K,)`` frames ``n`` per block, all of the same effective count ``n_eff``.
        variance, log_variance: ``(M, d, S)`` :func:`~.looks.look_variance` ``lam + 1 / n_eff`` and ``(M, S)`` the
            sum of its logs.
        basis: ``(M, d, d, S)`` :func:`~.looks.look_basis` ``A`` (row ``j``, column ``i``);
            basis_loc: ``(M, d, S)`` ``A loc``; within_prec: ``(d, d, S)`` ``W^-1``; logdet: ``(S,)`` ``log|W|``.
        scale: ``1 / (1 - rho^2)``, the factor of the scatter's trace.
    """
    K, d = mean_y.shape
    M, S = basis.shape[0], basis.shape[3]
    out = np.empty((K, M))
    within, resid, quad = np.empty(S), np.empty(S), np.empty(S)
    for k in range(K):  # the draws innermost throughout: vectorised
        n = counts[k]
        rest = -0.5 * (n - 1.0) * d * _LOG_2PI - 0.5 * d * math.log(n)
        within[:] = 0.0
        for i in range(d):
            for j in range(d):
                x = -0.5 * scale * scatter[k, i, j]
                for s in range(S):
                    within[s] += x * within_prec[i, j, s]
        for s in range(S):
            within[s] += rest - 0.5 * (n - 1.0) * logdet[s]
        for m in range(M):
            quad[:] = 0.0
            for j in range(d):
                for s in range(S):
                    resid[s] = -basis_loc[m, j, s]
                for i in range(d):
                    y = mean_y[k, i]
                    for s in range(S):
                        resid[s] += basis[m, j, i, s] * y
                for s in range(S):
                    quad[s] += resid[s] * resid[s] / variance[m, j, s]
            top = -np.inf
            for s in range(S):
                quad[s] = within[s] - 0.5 * (quad[s] + log_variance[m, s] + logdet[s] + d * _LOG_2PI)
                top = max(top, quad[s])
            total = 0.0
            for s in range(S):
                total += math.exp(max(quad[s] - top, _FLOOR))
            out[k, m] = top + math.log(total)
    return out
