"""Frames in, classifier outputs out, in the caller's class order.

:func:`classify_frames` runs a :class:`~classifiers.FrameClassifier` over any iterable of uint8 BGR frames
(a :mod:`classifiers.sources` source, a list, a rendered sequence) in small batches and yields each frame
with its output row, columns in the caller's class order (the order the noise posterior was fitted in).
Frames are read lazily: nothing is decoded beyond the batch being classified.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence

import numpy as np
from torch import Tensor

from classifiers.pipeline import FrameClassifier
from hbni_infra.checks import as_int


def class_columns(clf: FrameClassifier, classes: Sequence[str], name: str = "classes") -> list[int]:
    """Indices of ``classes`` among the classifier's columns (``clf.classes_`` is alphabetical).

    Raises:
        TypeError: ``classes`` is a string or not a sequence (``name`` names it).
        ValueError: ``classes`` is not a reordering of the classifier's classes (both lists named).
    """
    if clf.classes_ is None:
        raise ValueError("clf: the classifier is not fitted")
    if isinstance(classes, str) or not hasattr(classes, "__iter__"):
        raise TypeError(f"{name}: expected a sequence of class names, got {type(classes).__name__}")
    classes = list(classes)
    if not all(_hashable(c) for c in classes) or len(classes) != len(clf.classes_) or set(classes) != set(clf.classes_):
        raise ValueError(f"{name}: expected a reordering of the classifier's classes {clf.classes_}, got {classes}")
    return [clf.classes_.index(c) for c in classes]


def _hashable(value: object) -> bool:
    try:
        hash(value)
    except TypeError:
        return False
    return True


def classify_frames(
    frames: Iterable[np.ndarray], clf: FrameClassifier, classes: Sequence[str], batch: int = 8
) -> Iterator[tuple[np.ndarray, Tensor]]:
    """Yield ``(frame, output)`` for every frame: ``output`` float64 ``(M,)`` in ``classes`` order.

    Args:
        batch: frames per classifier call (1: lowest latency on a live camera; 8: the backbone's
            batch and the best throughput).
    """
    batch = as_int("batch", batch, minimum=1)
    order = class_columns(clf, classes)
    pending: list[np.ndarray] = []
    for frame in frames:
        pending.append(frame)
        if len(pending) == batch:
            yield from _classified(pending, clf, order)
            pending = []
    if pending:
        yield from _classified(pending, clf, order)


def _classified(
    frames: list[np.ndarray], clf: FrameClassifier, order: list[int]
) -> Iterator[tuple[np.ndarray, Tensor]]:
    probs = clf.predict_proba(frames)[:, order].double()
    yield from zip(frames, probs)
