"""How a camera's consecutive frames resemble each other: an AR(1) correlation of frames around their look.

The sequence model treats a sequence's frames as exchangeable given its look: i.i.d. scatter ``W``
around ``mu_k``. A moving camera's frames are closer to their neighbours than that: in the mission's
held-out streams the correlation of the scatter decays with the lag as an AR(1) series does (the fitted
``rho`` is reported as ``metrics.json``'s ``hbni_frame_correlation``). The filter keeps the exchangeable model; streams simulated from a fitted posterior
(the generative planning tables, posterior predictive checks) use the AR(1) scatter

    y_t = mu_k + e_t,   e_1 = L z_1,   e_t = rho e_{t-1} + sqrt(1 - rho^2) L z_t   (L L^T = W, z ~ N(0, I))

so every frame still scatters by ``W`` about the look, and neighbours correlate by ``rho^|s - t|``.

``rho`` is estimated from labelled or unlabelled sequences alike: the scatter of each sequence about
its own mean, in log-ratio coordinates, gives the pooled lag-1 ratio ``r = sum e_t . e_{t+1} / sum e_t . e_t``.
Centring on the sample mean biases ``r`` down (to ``-1 / n`` for i.i.d. frames), so ``rho`` solves
``E[numerator](rho) / E[denominator](rho) = r`` with both expectations in closed form for the
sequences' lengths (:func:`lag_one_ratio`).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from hbni_pyro.distributions.density import ilr
from hbni_pyro.validation import DTYPE

LIMIT = 0.99
"""Estimates are kept in ``[-LIMIT, LIMIT]``."""


def _row_sums(rho: float, n: int) -> Tensor:
    """``(R 1)_t`` for the AR(1) correlation matrix ``R_st = rho^|s - t|`` of ``n`` frames, float64 ``(n,)``;
    ``rho`` in ``(-1, 1)``."""
    t = torch.arange(1, n + 1, dtype=DTYPE)
    return ((1 - rho**t) + (1 - rho ** (n - t + 1))) / (1 - rho) - 1


def lag_one_ratio(rho: float, lengths: Tensor) -> float:
    """``E[sum_t e_t e_{t+1}] / E[sum_t e_t^2]`` for AR(1) sequences (``rho`` in ``(-1, 1)``) of ``lengths`` frames
    (long ``(K,)``, each at least 2) centred on their own means; ``-1 / n`` at ``rho = 0`` for a single length ``n``."""
    num = den = 0.0
    sizes, counts = torch.unique(lengths, return_counts=True)
    for n, count in zip(sizes.tolist(), counts.tolist()):
        r1 = _row_sums(rho, n)
        total = float(r1.sum())  # 1' R 1
        den += count * (n - total / n)  # tr(C R C)
        lagged = (n - 1) * rho - (float(r1[:-1].sum()) + float(r1[1:].sum())) / n + (n - 1) * total / n**2
        num += count * lagged  # sum of the first super-diagonal of C R C
    return num / den


_ROWS = 1 << 16
"""Outputs per chunk of the estimator's passes (a few MB each: a fit's data is not copied whole)."""
_NO_SCATTER = 1e-24  # residuals whose squares sum below this fraction of the frames' squares: none (rounding)


def _chunked_ilr(x: Tensor, start: int) -> Tensor:
    return ilr(x[start : start + _ROWS].to(dtype=DTYPE, device="cpu").clamp_min(torch.finfo(DTYPE).tiny))


def estimate_frame_correlation(obs: Tensor, sequence_ids: Tensor) -> float:
    """The AR(1) correlation of frames about their sequence's look (see the module doc).

    Args:
        obs: ``(N, M)`` outputs on the simplex, each sequence's frames in time order.
        sequence_ids: long ``(N,)`` ids ``0..K-1``.

    Returns:
        ``rho`` in ``[-LIMIT, LIMIT]``; 0.0 when no sequence has three frames (two frames centred on their mean
        are perfectly anti-correlated whatever ``rho``).
    """
    ids = sequence_ids.cpu()
    if bool((ids[1:] < ids[:-1]).any()):  # sequences interleaved: put each one's frames together, in order
        order = torch.argsort(ids, stable=True)
        obs, ids = obs[order.to(obs.device)], ids[order]
    num_seq, n = int(ids.max()) + 1, ids.shape[0]
    counts = torch.bincount(ids, minlength=num_seq)
    sums = torch.zeros(num_seq, obs.shape[1] - 1, dtype=DTYPE)
    for start in range(0, n, _ROWS):  # pass 1: each sequence's mean look
        sums.index_add_(0, ids[start : start + _ROWS], _chunked_ilr(obs, start))
    means = sums / counts.clamp_min(1).unsqueeze(1)
    num = den = size = 0.0
    previous: tuple[Tensor, Tensor] | None = None  # the last residual of the chunk before, and its id
    for start in range(0, n, _ROWS):  # pass 2: residuals, their squares and lag-1 products within sequences
        part = ids[start : start + _ROWS]
        x = _chunked_ilr(obs, start)
        e = x - means[part]
        used = counts[part] >= 3
        den += float((e[used] ** 2).sum())
        size += float((x[used] ** 2).sum())
        if previous is not None:
            e, part = torch.cat([previous[0], e]), torch.cat([previous[1], part])
            used = torch.cat([used.new_zeros(1), used])  # (the first flag is never read)
        same = (part[1:] == part[:-1]) & used[1:]
        num += float((e[1:] * e[:-1]).sum(1)[same].sum())
        previous = e[-1:], part[-1:]
    if den <= _NO_SCATTER * size or not bool((counts >= 3).any()):  # (rounding in the means leaves ~1e-32 of size)
        return 0.0
    observed = num / den
    lengths = counts[counts >= 3]
    lo, hi = -LIMIT, LIMIT
    if observed <= lag_one_ratio(lo, lengths):
        return lo
    if observed >= lag_one_ratio(hi, lengths):
        return hi
    for _ in range(60):  # the ratio increases with rho: bisection to about 1e-18
        mid = 0.5 * (lo + hi)
        if lag_one_ratio(mid, lengths) < observed:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def ar1_normals(shape: tuple[int, ...], correlation: float, generator: torch.Generator, device=None) -> Tensor:
    """Standard normals float64 ``(*shape)`` forming, along the second-to-last axis, AR(1) series with lag-1
    correlation ``correlation`` and unit variance at every step (``correlation = 0``: i.i.d.)."""
    z = torch.randn(shape, generator=generator, dtype=DTYPE, device=device)
    if correlation == 0.0 or shape[-2] < 2:
        return z
    scale = math.sqrt(1.0 - correlation**2)
    out = torch.empty_like(z)
    out[..., 0, :] = z[..., 0, :]
    for t in range(1, shape[-2]):
        out[..., t, :] = correlation * out[..., t - 1, :] + scale * z[..., t, :]
    return out
