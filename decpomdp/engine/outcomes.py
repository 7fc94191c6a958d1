"""Perception for the compiled engine: per true class, a finite law of ``(label, frames)`` outcomes.

Every perception model the planners use is such a law: :class:`~decpomdp.perception.PerfectPerception`
(one outcome per class), a tabulated macro-observation model (one outcome per ``(label, frames)``
cell) and a replay of recorded streams (one equally likely outcome per banked stream of the class:
a filter is deterministic given its stream, so each stream's outcome is computed once). A model
says so by an ``outcomes()`` method returning ``(probs, label, frames)``, each ``(C, K)``; rows of
``probs`` sum to 1, and padding entries have probability 0.

:class:`OutcomeTable` stores the rows as cumulative sums, and :func:`sample_outcome` draws from one
by binary search: one uniform per inference.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numba import njit

from hbni_infra.counter_random import uniform


class OutcomeTable(NamedTuple):
    """Per true class ``c``, outcome ``j`` has ``label[c, j]`` and ``frames[c, j]``; ``cdf[c, j]`` is
    ``P(outcome <= j | c)``. float64 / int64 / int64, each (C, K)."""

    cdf: np.ndarray
    label: np.ndarray
    frames: np.ndarray


def outcome_table(perception: Any) -> OutcomeTable | None:
    """The :class:`OutcomeTable` of a perception model with an ``outcomes()`` method, else ``None``."""
    outcomes = getattr(perception, "outcomes", None)
    if not callable(outcomes):
        return None
    probs, label, frames = (np.ascontiguousarray(np.asarray(x)) for x in outcomes())
    c = int(perception.num_classes)
    if probs.ndim != 2 or probs.shape[0] != c or label.shape != probs.shape or frames.shape != probs.shape:
        raise ValueError(
            f"perception.outcomes(): expected three ({c}, K) arrays, got shapes "
            f"{probs.shape}, {label.shape}, {frames.shape}"
        )
    probs = probs.astype(np.float64)
    if not np.isfinite(probs).all() or (probs < 0).any() or np.abs(probs.sum(1) - 1.0).max() > 1e-9:
        raise ValueError("perception.outcomes(): each class's probabilities must be finite, >= 0 and sum to 1")
    live = probs > 0
    label, frames = label.astype(np.int64), frames.astype(np.int64)
    if ((label < 0) | (label >= c))[live].any() or (frames < 1)[live].any():
        raise ValueError(f"perception.outcomes(): labels must lie in [0, {c}) and frames be >= 1")
    cdf = np.cumsum(probs, axis=1)
    cdf[:, -1] = np.maximum(cdf[:, -1], 1.0)  # exactly 1 at the end, so a uniform in [0, 1) always lands
    return OutcomeTable(cdf, label, frames)


def no_perception() -> OutcomeTable:
    """The placeholder table of a domain without perception (one class, one outcome)."""
    return OutcomeTable(np.ones((1, 1)), np.zeros((1, 1), dtype=np.int64), np.ones((1, 1), dtype=np.int64))


@njit
def sample_outcome(perception: tuple, true_class: np.int64, rng: np.ndarray) -> tuple[np.int64, np.int64]:
    """``(label, frames)`` of one inference of an object of class ``true_class``."""
    cdf, label, frames = perception
    row = cdf[true_class]
    u = uniform(rng)
    lo, hi = 0, row.shape[0] - 1
    while lo < hi:  # the first j with cdf[j] > u
        mid = (lo + hi) // 2
        if row[mid] > u:
            hi = mid
        else:
            lo = mid + 1
    return label[true_class, lo], frames[true_class, lo]
