"""The frame-source contract: an iterable of uint8 BGR frames with their times (:mod:`classifiers.sources` and
:mod:`classifiers.bags` implement it)."""

from __future__ import annotations

import abc
import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from classifiers.stamped import StampedFrame
from hbni_infra.checks import as_int
from hbni_infra.ros import NS_PER_S


class FrameSource(abc.ABC):
    """An iterable of uint8 BGR frames ``(H, W, 3)``.

    Attributes:
        fps: the source's nominal frame rate (``None`` when unknown).
        num_frames: frames in the source when known in advance (``None`` for a camera).
    """

    fps: float | None = None
    num_frames: int | None = None

    @abc.abstractmethod
    def __iter__(self) -> Iterator[np.ndarray]: ...

    def stamped(self) -> Iterator[StampedFrame]:
        """The frames with their times (ns): a file's or folder's frame ``i`` is stamped ``i / fps`` on its own
        timeline when the source has a frame rate, else when it is read; it is received when it is read."""
        for index, image in enumerate(self):
            now = time.time_ns()
            stamp = now if self.fps is None else round(index * NS_PER_S / self.fps)
            yield StampedFrame(image, stamp, now, "", index)

    def close(self) -> None:
        """Release the file or device (iteration after closing is an error for a camera only)."""

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def frame_limit(max_frames: Any) -> int | None:
    """``max_frames`` checked: ``None`` (every frame) or an int >= 1."""
    return None if max_frames is None else as_int("max_frames", max_frames, 1)
