"""Compiled per-sequence products of the sequence-aware model's sampler, for data on the CPU.

Each sequence's look and its share of the class scatter are small dense products (``d x d``, ``d = M - 1``)
whose factor depends on the sequence's class: batched torch products either compute every class's
product for every sequence and keep one, or gather a ``d x d`` factor per sequence. These loops read
each sequence's own factor instead. They compute what the torch paths of
:mod:`hbni_pyro.models.sequence.steps` compute (their test oracles); the looks' standard normals come from
counter-based streams (:func:`normals`, one stream per chain), a fifth of the cost of ``torch.randn``. The
products compile with ``fastmath`` (sums reassociated, so vectorised).

Shapes: ``B`` chains (datasets x chains per dataset, flattened), ``K`` sequences, ``M`` classes, ``G``
(class, frame count) groups, ``d`` look dimensions.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from hbni_infra.counter_random import (
    normal,
    stream_key,
    uniform,
)  # sets numba's cache directory (hbni_infra.numba_cache) first


def normals(key: np.uint64, B: int, K: int, d: int) -> np.ndarray:
    """``(B, K, d)`` standard normals, chain ``b``'s from the stream keyed by ``(key, b, 0)``."""
    out = np.empty((B, K, d))
    _fill_normals(key, out, np.zeros(1, dtype=np.uint64))
    return out


@njit(cache=True, nogil=True, _nrt=False)
def _fill_normals(key: np.uint64, out: np.ndarray, rng: np.ndarray) -> None:
    """Fill ``out (B, K, d)`` as :func:`normals` returns it. Compiled without reference counting, which would
    cost several times a draw around the ziggurat's out-of-line rare path (see
    :func:`hbni_infra.counter_random.normal`)."""
    B, K, d = out.shape
    for b in range(B):
        rng[0] = stream_key(key, b, 0)
        for k in range(K):
            for j in range(d):
                out[b, k, j] = normal(rng)


@njit(cache=True, nogil=True, fastmath=True)
def looks(
    cov: np.ndarray,
    tril: np.ndarray,
    pb_loc: np.ndarray,
    wy: np.ndarray,
    z: np.ndarray,
    c: np.ndarray,
    group: np.ndarray,
) -> np.ndarray:
    """Every look ``cov_g (pb_loc_c + wy_k) + tril_g z_k`` with ``g = group[b, k]``, ``c = c[b, k]``.

    Args:
        cov, tril: ``(B, G, d, d)`` each group's posterior covariance and its lower Cholesky factor.
        pb_loc: ``(B, M, d)`` ``B_c^-1 m_c`` per class; ``wy``: ``(B, K, d)`` ``W^-1 sum y`` per sequence.
        z: ``(B, K, d)`` standard normal draws; ``c``, ``group``: ``(B, K)`` int64 class and group.

    Returns:
        ``(B, K, d)`` looks.
    """
    B, K, d = z.shape
    out = np.empty((B, K, d))
    rhs = np.empty(d)
    for b in range(B):
        for k in range(K):
            g, m = group[b, k], c[b, k]
            for j in range(d):
                rhs[j] = pb_loc[b, m, j] + wy[b, k, j]
            for i in range(d):
                acc = 0.0
                for j in range(d):
                    acc += cov[b, g, i, j] * rhs[j]
                for j in range(i + 1):
                    acc += tril[b, g, i, j] * z[b, k, j]
                out[b, k, i] = acc
    return out


@njit(cache=True, nogil=True, fastmath=True)
def class_scatter(look: np.ndarray, loc: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per chain and class, the number of sequences and the scatter of their looks about the class mean.

    Args:
        look: ``(B, K, d)``; loc: ``(B, M, d)`` class means; c: ``(B, K)`` int64 classes.

    Returns:
        ``counts (B, M)`` and ``scatter (B, M, d, d)`` = ``sum_{k: c_k = m} (look_k - loc_m)(look_k - loc_m)^T``.
    """
    B, K, d = look.shape
    M = loc.shape[1]
    counts = np.zeros((B, M))
    scatter = np.zeros((B, M, d, d))
    dev = np.empty(d)
    for b in range(B):
        for k in range(K):
            m = c[b, k]
            counts[b, m] += 1.0
            for j in range(d):
                dev[j] = look[b, k, j] - loc[b, m, j]
            for i in range(d):
                for j in range(i + 1):
                    scatter[b, m, i, j] += dev[i] * dev[j]
        for m in range(M):
            for i in range(d):
                for j in range(i):
                    scatter[b, m, j, i] = scatter[b, m, i, j]
    return counts, scatter


@njit(cache=True, nogil=True, fastmath=True)
def class_sums(values: np.ndarray, c: np.ndarray, M: int) -> tuple[np.ndarray, np.ndarray]:
    """``counts (B, M)`` of sequences per class and ``sums (B, M, V)`` of their ``values (B, K, V)``."""
    B, K, V = values.shape
    counts = np.zeros((B, M))
    sums = np.zeros((B, M, V))
    for b in range(B):
        for k in range(K):
            m = c[b, k]
            counts[b, m] += 1.0
            for j in range(V):
                sums[b, m, j] += values[b, k, j]
    return counts, sums


@njit(cache=True, nogil=True, fastmath=True)
def offset_scatter(mean_y: np.ndarray, look: np.ndarray, count: np.ndarray) -> np.ndarray:
    """``(B, d, d)`` ``sum_k n_k (ybar_k - mu_k)(ybar_k - mu_k)^T`` of sequence means ``mean_y (B, K, d)``, looks
    ``look (B, K, d)`` and frame counts ``count (B, K)``."""
    B, K, d = look.shape
    out = np.zeros((B, d, d))
    dev = np.empty(d)
    for b in range(B):
        for k in range(K):
            n = count[b, k]
            for j in range(d):
                dev[j] = mean_y[b, k, j] - look[b, k, j]
            for i in range(d):
                w = n * dev[i]
                for j in range(i + 1):
                    out[b, i, j] += w * dev[j]
        for i in range(d):
            for j in range(i):
                out[b, j, i] = out[b, i, j]
    return out


@njit(cache=True, nogil=True, fastmath=True)
def classes(
    key: np.uint64,
    basis: np.ndarray,
    basis_loc: np.ndarray,
    inv_var: np.ndarray,
    log_var: np.ndarray,
    log_prior: np.ndarray,
    mean_y: np.ndarray,
    group: np.ndarray,
    labels: np.ndarray,
) -> np.ndarray:
    """Every sequence's class drawn from ``p(c_k = m | frames) ∝ p_m N(ybar_k; m_m, B_m + W / n_k)``, labelled ones kept.

    In the basis ``A_m`` of :func:`hbni_pyro.models.sequence.looks.look_basis` the look's covariance is ``diag(lam_m + 1/n)``, so a
    class's log weight is ``log p_m - (|A_m ybar_k - A_m m_m|^2_{1/var} + sum log var) / 2`` (the terms that are the same
    for every class dropped). Chain ``b`` draws one uniform per unknown sequence from the stream keyed by
    ``(key, b, 0)``.

    Args:
        basis: ``(B, M, d, d)`` every chain's ``A_m``; basis_loc: ``(B, M, d)`` ``A_m m_m``.
        inv_var, log_var: ``(B, M, G, d)`` ``1 / (lam_m + 1/n_g)`` and ``(B, M, G)`` the sum of ``log(lam_m + 1/n_g)``
            for the ``G`` distinct frame counts ``n_g``.
        log_prior: ``(B, M)``; mean_y: ``(D, K, d)`` each dataset's sequence means (chain ``b`` reads dataset
            ``b // (B / D)``); group: ``(D, K)`` int64 frame-count group; labels: ``(D, K)`` int64, -1 unknown.

    Returns:
        ``(B, K)`` int64 classes.
    """
    B, M, d = basis_loc.shape
    D, K = labels.shape
    per_set = B // D
    out = np.empty((B, K), dtype=np.int64)
    rng = np.zeros(1, dtype=np.uint64)
    weight = np.empty(M)
    for b in range(B):
        rng[0] = stream_key(key, b, 0)
        s = b // per_set
        for k in range(K):
            if labels[s, k] >= 0:
                out[b, k] = labels[s, k]
                continue
            g = group[s, k]
            for m in range(M):
                quad = 0.0
                for i in range(d):
                    acc = -basis_loc[b, m, i]
                    for j in range(d):
                        acc += basis[b, m, i, j] * mean_y[s, k, j]
                    quad += acc * acc * inv_var[b, m, g, i]
                weight[m] = log_prior[b, m] - 0.5 * (quad + log_var[b, m, g])
            top = weight[0]  # no infinities under fastmath: start from a weight
            for m in range(1, M):
                top = max(top, weight[m])
            total = 0.0
            for m in range(M):
                weight[m] = np.exp(weight[m] - top)
                total += weight[m]
            u = uniform(rng) * total
            chosen = M - 1
            running = 0.0
            for m in range(M):
                running += weight[m]
                if u < running:
                    chosen = m
                    break
            out[b, k] = chosen
    return out
