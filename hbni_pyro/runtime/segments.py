"""A classified frame stream cut into consecutive macro-observations.

:func:`macro_observations` runs a :class:`~hbni_pyro.MacroObservationProcess` on ``(frame, output)``
pairs (for instance :func:`classifiers.classify.classify_frames`) and restarts it after every
macro-observation, so a long stream becomes consecutive :class:`Segment` s. The process pulls frames
lazily: nothing after the last frame a decision needs is read before that decision is made.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator, Sequence
from typing import Any, NamedTuple

import torch
from torch import Tensor

from hbni_pyro.filters.macro import MacroObservationProcess
from hbni_pyro.filters.streaming import HBNIFilter
from hbni_pyro.validation import check_same_classes
from hbni_infra.checks import as_names


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
    frames: list[Any]

    def record(self) -> dict[str, Any]:
        """The JSON-lines record of this macro-observation."""
        return {
            "index": self.index,
            "start_frame": self.start,
            "end_frame": self.end,
            "label": self.name,
            "label_index": self.label,
            "confidence": self.confidence,
            "frames_used": self.frames_used,
            "timed_out": self.timed_out,
            "stream_ended": self.stream_ended,
        }


def macro_observations(
    items: Iterable[tuple[Any, Tensor]],
    process: MacroObservationProcess,
    classes: Sequence[str],
    keep_frames: bool = False,
) -> Iterator[Segment]:
    """Consecutive macro-observations of a classified stream (``(frame, output)`` pairs).

    The process runs from the first frame until it decides, then starts afresh on the next frame;
    the last segment may be cut short by the end of the stream (``stream_ended``).

    Args:
        process: the macro-observation process (its filter, threshold and frame budget).
        classes: class names in the process's class order (its posterior's names when it has them; a process
            on an HBNI posterior without names is refused: nothing says which column is which class).
        keep_frames: keep each segment's frames (for annotation); otherwise only outputs are kept.
    """
    if not isinstance(process, MacroObservationProcess):
        raise TypeError(f"process: expected a MacroObservationProcess, got {type(process).__name__}")
    classes = as_names("classes", classes, process.num_classes)
    if classes is None:
        raise TypeError("classes: expected a sequence of names, got None")
    if process.class_names is None and isinstance(process.filter, HBNIFilter):
        raise ValueError(
            f"process: its posterior has no class names, so its columns cannot be matched to classes {list(classes)}; "
            "fit it with class_names=[...], or name it in its column order: posterior.named([...])"
        )
    check_same_classes(process.class_names, classes, "the process's posterior")
    it = iter(items)
    start = 0
    for index in itertools.count():
        first = next(it, None)
        if first is None:
            return
        used: list[tuple[Any, Tensor]] = [first]
        result = process.run(_outputs(first, it, used))
        frames = [frame for frame, _ in used] if keep_frames else []
        ended = result.timed_out and result.frames_used < process.max_frames
        yield Segment(
            index,
            start,
            start + result.frames_used - 1,
            result.label,
            classes[result.label],
            result.confidence,
            result.frames_used,
            result.timed_out,
            ended,
            torch.stack([o for _, o in used]),
            frames,
        )
        start += result.frames_used


def _outputs(first: tuple[Any, Tensor], rest: Iterator, used: list) -> Iterator[Tensor]:
    """The outputs of ``first`` then of ``rest``, recording every pair handed out in ``used``.

    The process stops pulling as soon as it decides, so ``rest`` is left at the next segment's first frame.
    """
    yield first[1]
    for item in rest:
        used.append(item)
        yield item[1]
