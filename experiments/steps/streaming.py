"""Frames in, macro-observations out: a frame classifier feeding a macro-observation process.

:func:`classify_frames` runs a :class:`~classifiers.FrameClassifier` over any iterable of uint8
BGR frames (a :mod:`classifiers.sources` source, a list, a rendered sequence) in small batches
and yields each frame with its output row, columns in the caller's class order (the order the
noise posterior was fitted in). :func:`macro_observations` runs a
:class:`~hbni_pyro.MacroObservationProcess` on those outputs and restarts it after every
macro-observation, so a long stream becomes consecutive :class:`Segment` s. Frames are read
lazily: nothing after the last frame a decision needs is decoded before that decision is made,
beyond the classifier's batch.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator, Sequence
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import Tensor

import hbni_pyro
from classifiers import FrameClassifier


class Segment(NamedTuple):
    """One macro-observation of a frame stream.

    ``start`` and ``end`` are the first and last frame indices it used (inclusive, counted from the
    stream's first frame); ``stream_ended`` says the stream ran out before the threshold or the
    frame budget was reached (then ``timed_out`` is true as well). ``outputs`` are its classifier
    outputs ``(frames_used, M)``; ``frames`` its frames when kept, else an empty list.
    """

    index: int
    start: int
    end: int
    label: int
    name: str
    confidence: float
    frames_used: int
    timed_out: bool
    stream_ended: bool
    outputs: Tensor
    frames: list[np.ndarray]

    def record(self) -> dict[str, Any]:
        """The JSON-lines record of this macro-observation."""
        return {"index": self.index, "start_frame": self.start, "end_frame": self.end, "label": self.name,
                "label_index": self.label, "confidence": self.confidence, "frames_used": self.frames_used,
                "timed_out": self.timed_out, "stream_ended": self.stream_ended}


def class_columns(clf: FrameClassifier, classes: Sequence[str]) -> list[int]:
    """Indices of ``classes`` among the classifier's columns (``clf.classes_`` is alphabetical).

    Raises:
        ValueError: ``classes`` is not a reordering of the classifier's classes.
    """
    if clf.classes_ is None:
        raise ValueError("clf: the classifier is not fitted")
    if sorted(classes) != sorted(clf.classes_) or len(set(classes)) != len(classes):
        raise ValueError(f"classes: expected a reordering of the classifier's classes {clf.classes_}, got {list(classes)}")
    return [clf.classes_.index(name) for name in classes]


def classify_frames(
    frames: Iterable[np.ndarray], clf: FrameClassifier, classes: Sequence[str], batch: int = 8
) -> Iterator[tuple[np.ndarray, Tensor]]:
    """Yield ``(frame, output)`` for every frame: ``output`` float64 ``(M,)`` in ``classes`` order.

    Args:
        batch: frames per classifier call (1: lowest latency on a live camera; 8: the backbone's
            batch and the best throughput).
    """
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise ValueError(f"batch: expected a positive int, got {batch!r}")
    order = class_columns(clf, classes)
    pending: list[np.ndarray] = []
    for frame in frames:
        pending.append(frame)
        if len(pending) == batch:
            yield from _classified(pending, clf, order)
            pending = []
    if pending:
        yield from _classified(pending, clf, order)


def _classified(frames: list[np.ndarray], clf: FrameClassifier, order: list[int]) -> Iterator[tuple[np.ndarray, Tensor]]:
    probs = clf.predict_proba(frames)[:, order].double()
    yield from zip(frames, probs)


def macro_observations(
    items: Iterable[tuple[np.ndarray, Tensor]],
    process: hbni_pyro.MacroObservationProcess,
    classes: Sequence[str],
    keep_frames: bool = False,
) -> Iterator[Segment]:
    """Consecutive macro-observations of a classified stream (``(frame, output)`` pairs).

    The process runs from the first frame until it decides, then starts afresh on the next frame;
    the last segment may be cut short by the end of the stream (``stream_ended``).

    Args:
        process: the macro-observation process (its filter, threshold and frame budget).
        classes: class names in the process's class order.
        keep_frames: keep each segment's frames (for annotation); otherwise only outputs are kept.
    """
    if len(classes) != process.num_classes:
        raise ValueError(f"classes: expected {process.num_classes} names, got {len(classes)}")
    it = iter(items)
    start = 0
    for index in itertools.count():
        first = next(it, None)
        if first is None:
            return
        used: list[tuple[np.ndarray, Tensor]] = [first]
        result = process.run(_outputs(first, it, used))
        frames = [frame for frame, _ in used] if keep_frames else []
        ended = result.timed_out and result.frames_used < process.max_frames
        yield Segment(index, start, start + result.frames_used - 1, result.label, classes[result.label],
                      result.confidence, result.frames_used, result.timed_out, ended,
                      torch.stack([o for _, o in used]), frames)
        start += result.frames_used


def _outputs(first: tuple[np.ndarray, Tensor], rest: Iterator, used: list) -> Iterator[Tensor]:
    """The outputs of ``first`` then of ``rest``, recording every pair handed out in ``used``.

    The process stops pulling as soon as it decides, so ``rest`` is left at the next segment's first frame.
    """
    yield first[1]
    for item in rest:
        used.append(item)
        yield item[1]
