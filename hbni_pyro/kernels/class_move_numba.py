"""Compiled class move of the paper's model for data on the CPU: the MH move of every unknown class,
the per-class sufficient statistics and (after warm-up) the label counts, fused in one pass.

The move is that of :func:`hbni_pyro.kernels.mh_steps.update_classes` (``beta=None``): stay with
probability ``stay_prob``, else propose from the alias tables of ``w_i``, accept by the Hastings
ratio. Under the paper's model ``log p(c_i = k) + log Dir(o_i; theta_k e_k + 1)`` is
``offset_k + theta_k log o_ik``, so a move is ``O(1)`` per output.

Random numbers are counter-based (SplitMix64, :mod:`infra.counter_random`), one stream per
(iteration, chain, block of :data:`ROWS` outputs), and the statistics are summed block by block in
a fixed order, so a seed gives the same draws whatever the thread count. Within a block the outputs are
the outer loop and the chains the inner one, each chain drawing from its own stream: an output's row of
log outputs and alias tables is read once for all chains (the same draws as chains outer, a quarter faster).

Shapes: ``D`` datasets, ``Cp`` chains per dataset, ``N`` outputs, ``M`` classes.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from infra.counter_random import accepts, stream_key, uniform  # sets numba's cache directory (infra.numba_cache) first

ROWS = 512
"""Outputs per block (one random stream and one partial sum per chain and block)."""


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
    """One class move of every chain, in place on ``c (D, Cp, N)`` int64.

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
    D, Cp, N = c.shape
    M = log_obs.shape[2]
    blocks = (N + ROWS - 1) // ROWS
    part_counts = np.zeros((D, blocks, Cp, M))
    part_sums = np.zeros((D, blocks, Cp, M))
    part_acc = np.zeros((D, blocks, Cp), dtype=np.int64)
    streams = np.zeros(Cp, dtype=np.uint64)  # every chain's stream over this block
    rng = np.zeros(1, dtype=np.uint64)
    for job in range(D * blocks):
        d, b = job // blocks, job % blocks
        for ch in range(Cp):
            streams[ch] = stream_key(seed, iteration, (d * Cp + ch) * blocks + b)
        for i in range(b * ROWS, min(N, (b + 1) * ROWS)):  # an output's row is read once for all chains
            free = labels[d, i] < 0
            lo_i, lw_i, prob_i, alias_i = log_obs[d, i], log_w[d, i], alias_prob[d, i], alias[d, i]
            for ch in range(Cp):
                cur = c[d, ch, i]
                if free:
                    rng[0] = streams[ch]
                    v = uniform(rng)
                    if v >= stay_prob:
                        x = (v - stay_prob) / (1.0 - stay_prob) * M
                        k = min(np.int64(x), M - 1)
                        p = k if x - k < prob_i[k] else alias_i[k]
                        if p != cur:
                            log_ratio = (
                                offset[d, ch, p]
                                + theta[d, ch, p] * lo_i[p]
                                - offset[d, ch, cur]
                                - theta[d, ch, cur] * lo_i[cur]
                                + lw_i[cur]
                                - lw_i[p]
                            )
                            if accepts(rng, log_ratio):
                                cur = p
                                c[d, ch, i] = p
                                part_acc[d, b, ch] += 1
                    streams[ch] = rng[0]
                part_counts[d, b, ch, cur] += 1.0
                part_sums[d, b, ch, cur] += lo_i[cur]
                if record:
                    label_counts[d, i, cur] += 1.0
    counts = np.zeros((D, Cp, M))
    sums = np.zeros((D, Cp, M))
    accepted = np.zeros((D, Cp), dtype=np.int64)
    for d in range(D):
        for b in range(blocks):
            counts[d] += part_counts[d, b]
            sums[d] += part_sums[d, b]
            accepted[d] += part_acc[d, b]
    return counts, sums, accepted
