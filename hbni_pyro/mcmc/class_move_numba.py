"""Compiled class move of the paper's model for data on the CPU: the MH move of every unknown class,
the per-class sufficient statistics and (after warm-up) the label counts.

The move is that of :func:`hbni_pyro.mcmc.class_moves.update_classes` (``beta=None``): stay with
probability ``stay_prob``, else propose from the alias tables of ``w_i``, accept by the Hastings
ratio. Under the paper's model ``log p(c_i = k) + log Dir(o_i; theta_k e_k + 1)`` is
``offset_k + theta_k log o_ik``, so a move is ``O(1)`` per output.

Given the parameters the classes are independent, so the moves of a block of :data:`ROWS` outputs
run in three passes, each a loop without unpredictable branches: :func:`propose` draws every
(output, chain) pair's coin and proposal and keeps the pairs that would change class (about a
third of them); :func:`accept` decides those by the Hastings ratio (about one in thirty is accepted);
:func:`tally` sums the statistics of the new classes. A proposal decided in the same loop as the
coin flip cost three times as much, the flip and the acceptance being branches the processor
cannot predict.

Random numbers are counter-based (SplitMix64, :mod:`hbni_infra.counter_random`), one stream per
(iteration, chain, block), and the statistics are summed block by block in a fixed order, so a seed
gives the same draws whatever the thread count. Classes are stored outputs-major, ``(D, N, Cp)``:
an output's chains are adjacent, as every pass reads them.

Shapes: ``D`` datasets, ``Cp`` chains per dataset, ``N`` outputs, ``M`` classes.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from hbni_infra.counter_random import (
    accepts,
    stream_key,
    uniform,
)  # sets numba's cache directory (hbni_infra.numba_cache) first

ROWS = 512
"""Outputs per block (one random stream and one partial sum per chain and block)."""


@njit(cache=True)
def propose(
    c: np.ndarray,
    labels: np.ndarray,
    alias_prob: np.ndarray,
    alias: np.ndarray,
    stay_prob: float,
    streams: np.ndarray,
    rows: tuple[int, int],
    out: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> int:
    """Every pair's coin and proposal over outputs ``rows = (start, stop)``; returns how many pairs would move.

    Args:
        c: ``(N, Cp)`` classes; labels ``(N,)``, -1 where unknown.
        alias_prob, alias: ``(N, M)`` alias tables of the proposal weights.
        streams: ``(Cp,)`` every chain's stream state, advanced by one draw per unknown output.
        out: ``(rows, chains, classes)`` int64 buffers of length ``ROWS * Cp``, filled with the moving pairs.
    """
    M, Cp = alias.shape[1], c.shape[1]
    scale = M / (1.0 - stay_prob)
    # flat views and unsigned indices: numba adds no negative-index wraparound to an unsigned index
    flat_c, flat_prob, flat_alias = c.reshape(-1), alias_prob.reshape(-1), alias.reshape(-1)
    out_rows, out_chains, out_classes = out
    rng = np.zeros(1, dtype=np.uint64)
    n = 0
    for i in range(rows[0], rows[1]):
        if labels[i] >= 0:
            continue
        for ch in range(Cp):
            rng[0] = streams[ch]
            v = uniform(rng)
            streams[ch] = rng[0]
            x = max(v - stay_prob, 0.0) * scale
            k = min(np.int64(x), M - 1)
            ik = np.uint64(i * M + k)
            p = k if x - k < flat_prob[ik] else flat_alias[ik]
            at = np.uint64(n)
            out_rows[at], out_chains[at], out_classes[at] = i, ch, p
            n += (v >= stay_prob) & (p != flat_c[np.uint64(i * Cp + ch)])
    return n


@njit(cache=True)
def accept(
    c: np.ndarray,
    log_obs: np.ndarray,
    log_w: np.ndarray,
    offset: np.ndarray,
    theta: np.ndarray,
    streams: np.ndarray,
    moves: tuple[np.ndarray, np.ndarray, np.ndarray],
    n: int,
    accepted: np.ndarray,
) -> None:
    """Accept or reject the first ``n`` proposed ``moves`` (as :func:`propose` left them) by the Hastings ratio,
    in place on ``c (N, Cp)``; ``offset, theta (Cp, M)``, ``log_obs, log_w (N, M)``, ``accepted (Cp,)`` counts."""
    rng = np.zeros(1, dtype=np.uint64)
    rows, chains, classes = moves
    for j in range(n):
        i, ch, p = rows[j], chains[j], classes[j]
        cur = c[i, ch]
        log_ratio = (
            offset[ch, p]
            + theta[ch, p] * log_obs[i, p]
            - offset[ch, cur]
            - theta[ch, cur] * log_obs[i, cur]
            + log_w[i, cur]
            - log_w[i, p]
        )
        rng[0] = streams[ch]
        if accepts(rng, log_ratio):
            c[i, ch] = p
            accepted[ch] += 1
        streams[ch] = rng[0]


@njit(cache=True)
def tally(
    c: np.ndarray,
    log_obs: np.ndarray,
    rows: tuple[int, int],
    counts: np.ndarray,
    sums: np.ndarray,
    label_counts: np.ndarray,
    record: bool,
) -> None:
    """Add the classes ``c (N, Cp)`` of outputs ``rows = (start, stop)`` to ``counts`` and the own-entry ``sums``
    ``(Cp, M)``, and, when ``record``, to ``label_counts (N, M)``."""
    Cp, M = c.shape[1], log_obs.shape[1]
    flat_c, flat_obs, flat_labels = c.reshape(-1), log_obs.reshape(-1), label_counts.reshape(-1)
    flat_counts, flat_sums = counts.reshape(-1), sums.reshape(-1)
    for i in range(rows[0], rows[1]):
        for ch in range(Cp):
            cur = flat_c[np.uint64(i * Cp + ch)]
            own, entry = np.uint64(ch * M + cur), np.uint64(i * M + cur)
            flat_counts[own] += 1.0
            flat_sums[own] += flat_obs[entry]
            if record:
                flat_labels[entry] += 1.0


@njit(cache=True)
def class_move_stats(
    c: np.ndarray,
    labels: np.ndarray,
    log_obs: np.ndarray,
    log_w: np.ndarray,
    alias_prob: np.ndarray,
    alias: np.ndarray,
    offset: np.ndarray,
    theta: np.ndarray,
    stay_prob: float,
    seed: np.uint64,
    iteration: np.int64,
    label_counts: np.ndarray,
    record: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One class move of every chain, in place on ``c (D, N, Cp)`` int64.

    Args:
        labels: ``(D, N)`` int64, -1 where unknown (labelled outputs keep their class).
        log_obs, log_w, alias_prob: ``(D, N, M)`` float64 log outputs, log proposal weights, alias
            probabilities; ``alias (D, N, M)`` int64.
        offset, theta: ``(D, Cp, M)`` float64 ``lgamma(M + theta) - lgamma(1 + theta) + log prior`` and ``theta``.
        stay_prob: probability that a proposal keeps the current class.
        seed, iteration: key of the random streams.
        label_counts: ``(D, N, M)`` float64, incremented by every chain's new class when ``record``.

    Returns:
        ``counts (D, Cp, M)``, own-entry sums ``sum_{i: c_i = m} log o_im (D, Cp, M)`` of the new
        classes and accepted moves per chain ``(D, Cp)`` int64.
    """
    D, N, Cp = c.shape
    M = log_obs.shape[2]
    blocks = (N + ROWS - 1) // ROWS
    part_counts = np.zeros((D, blocks, Cp, M))
    part_sums = np.zeros((D, blocks, Cp, M))
    part_acc = np.zeros((D, blocks, Cp), dtype=np.int64)
    streams = np.zeros(Cp, dtype=np.uint64)  # every chain's stream over this block
    moves = (np.empty(ROWS * Cp, np.int64), np.empty(ROWS * Cp, np.int64), np.empty(ROWS * Cp, np.int64))
    for job in range(D * blocks):
        d, b = job // blocks, job % blocks
        rows = (b * ROWS, min(N, (b + 1) * ROWS))
        for ch in range(Cp):
            streams[ch] = stream_key(seed, iteration, (d * Cp + ch) * blocks + b)
        n = propose(c[d], labels[d], alias_prob[d], alias[d], stay_prob, streams, rows, moves)
        accept(c[d], log_obs[d], log_w[d], offset[d], theta[d], streams, moves, n, part_acc[d, b])
        tally(c[d], log_obs[d], rows, part_counts[d, b], part_sums[d, b], label_counts[d], record)
    counts = np.zeros((D, Cp, M))
    sums = np.zeros((D, Cp, M))
    accepted = np.zeros((D, Cp), dtype=np.int64)
    for d in range(D):
        for b in range(blocks):
            counts[d] += part_counts[d, b]
            sums[d] += part_sums[d, b]
            accepted[d] += part_acc[d, b]
    return counts, sums, accepted
