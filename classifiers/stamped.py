"""Frames with their times: what a robot needs to say *when* it saw what it saw.

A :class:`StampedFrame` is a uint8 BGR frame ``(H, W, 3)`` with its header stamp (when the camera took it),
its receive time (when it reached the recorder or this process) and the camera's frame id. Every
:mod:`classifiers.sources` source yields them from ``stamped()``; :func:`classify_stamped` classifies them
like :func:`classifiers.classify_frames` and keeps each frame's times beside its output.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator, Sequence
from typing import NamedTuple

import numpy as np
from torch import Tensor

from classifiers.pipeline import FrameClassifier
from classifiers.classify import classify_frames


class StampedFrame(NamedTuple):
    """A frame and its times, in integer nanoseconds since the epoch.

    Attributes:
        image: uint8 BGR ``(H, W, 3)``.
        stamp: the header stamp (a bag's ``header.stamp``; see each source for the others).
        received: when the frame was received (a bag's log time; else when it was read).
        frame_id: the camera's coordinate frame (a bag's ``header.frame_id``; ``""`` when unknown).
        index: the frame's position in its source, from 0 (a bag: the message's index on its topic).
    """

    image: np.ndarray
    stamp: int
    received: int
    frame_id: str
    index: int


def classify_stamped(
    frames: Iterable[StampedFrame], clf: FrameClassifier, classes: Sequence[str], batch: int = 8
) -> Iterator[tuple[StampedFrame, Tensor]]:
    """Yield ``(frame, output)`` for every stamped frame: ``output`` float64 ``(M,)`` in ``classes`` order.

    The same batches and outputs as :func:`classifiers.classify_frames` on the images; frames are read
    lazily (at most one batch ahead).
    """
    stamped, images = itertools.tee(frames)
    for frame, (_, output) in zip(stamped, classify_frames((f.image for f in images), clf, classes, batch)):
        yield frame, output
