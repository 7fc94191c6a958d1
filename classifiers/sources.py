"""Frame sources: a video file, a folder of frames or a camera, read through OpenCV, and ROS bags.

Every source iterates over uint8 BGR frames ``(H, W, 3)``, the layout
:meth:`classifiers.FrameClassifier.proba` takes, and is a context manager that releases
its file or device. :meth:`FrameSource.stamped` gives the same frames as
:class:`~classifiers.stamped.StampedFrame` s, with their header stamp and receive time.
:func:`open_source` picks the kind from what it is given:

* a ROS bag (a rosbag2 directory, or a ``.mcap``, ``.db3`` or ``.bag`` file):
  :class:`~classifiers.bags.BagSource`, one image topic (the ``ros`` extra);
* an existing directory: :class:`FrameFolder`, a flat folder of images read in name order
  (numbers compared as numbers, so ``frame_2.png`` comes before ``frame_10.png``) by
  :class:`classifiers.data.ImageFolder`;
* an existing file: :class:`VideoFile`, any container and codec the OpenCV build decodes;
* an int (or a string of digits that is not a path): :class:`Camera`, a device index.

A bag, video file or folder can be iterated more than once (each pass starts at its first frame); a
camera is one live stream.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from classifiers.bags import BagSource, is_bag
from classifiers.data.image_folder import ImageFolder
from classifiers.frame_source import FrameSource, frame_limit
from classifiers.stamped import StampedFrame

__all__ = ["Camera", "FrameFolder", "FrameSource", "VideoFile", "open_source"]


def _bgr(frame: np.ndarray) -> np.ndarray:
    """A decoded frame as contiguous uint8 BGR ``(H, W, 3)`` (grey and BGRA frames converted)."""
    if frame.ndim == 2:
        return cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2BGR)
    return np.ascontiguousarray(frame)


def _read_all(capture: cv2.VideoCapture, limit: int | None) -> Iterator[np.ndarray]:
    count = 0
    while limit is None or count < limit:
        ok, frame = capture.read()
        if not ok:
            return
        count += 1
        yield _bgr(frame)


class VideoFile(FrameSource):
    """The frames of a video file, in order (the first ``max_frames`` of them when given).

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: OpenCV cannot open it as a video, or ``max_frames < 1``.
    """

    def __init__(self, path: str | os.PathLike, max_frames: int | None = None) -> None:
        self.max_frames = frame_limit(max_frames)
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"source: no such video file {str(self.path)!r}")
        capture = self._open()
        fps = capture.get(cv2.CAP_PROP_FPS)
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        capture.release()
        self.fps = float(fps) if fps > 0 else None
        self.num_frames = count if count > 0 else None  # the container's count: exact for most codecs
        if self.num_frames is not None and self.max_frames is not None:
            self.num_frames = min(self.num_frames, self.max_frames)

    def _open(self) -> cv2.VideoCapture:
        capture = cv2.VideoCapture(str(self.path))
        if not capture.isOpened():
            capture.release()
            raise ValueError(f"source: {str(self.path)!r} could not be opened as a video by OpenCV")
        return capture

    def __iter__(self) -> Iterator[np.ndarray]:
        capture = self._open()
        try:
            yield from _read_all(capture, self.max_frames)
        finally:
            capture.release()

    def __repr__(self) -> str:
        return f"VideoFile({str(self.path)!r}, fps={self.fps}, frames={self.num_frames})"


class FrameFolder(FrameSource):
    """The images directly inside a folder (unlabelled, flat), read by :class:`classifiers.data.ImageFolder`:
    ``.png``, ``.jpg``, ``.jpeg`` or ``.bmp``, in name order with numbers compared as numbers.

    Args:
        path: the folder.
        fps: nominal frame rate to report (a folder has none of its own).
        max_frames: read only the first this many frames (``None``: all of them).

    Raises:
        FileNotFoundError: ``path`` is not a directory.
        ValueError: no image in the folder, it holds ``<class>/`` folders (a labelled folder, not frames), or
            ``max_frames < 1``.
    """

    def __init__(self, path: str | os.PathLike, fps: float | None = None, max_frames: int | None = None) -> None:
        self.max_frames = frame_limit(max_frames)
        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"source: no such folder {str(self.path)!r}")
        self._folder = ImageFolder(self.path)
        if self._folder.labelled:
            raise ValueError(
                f"source: {str(self.path)!r} holds <class>/ folders of images, not a flat folder of "
                "frames (a labelled folder is read by classifiers.data.ImageFolder)"
            )
        self.files = [f for f, _ in self._folder.samples][: self.max_frames]
        self.fps = fps
        self.num_frames = len(self.files)

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(self.num_frames):
            yield self._folder[i][0]

    def __repr__(self) -> str:
        return f"FrameFolder({str(self.path)!r}, frames={self.num_frames})"


class Camera(FrameSource):
    """A live camera by device index; iteration stops after ``max_frames`` frames or when a read fails.

    Raises:
        TypeError: ``max_frames`` is not an int or ``None``.
        ValueError: ``index`` is not an int >= 0, ``max_frames < 1``, or
            the device cannot be opened.
    """

    def __init__(self, index: int, max_frames: int | None = None) -> None:
        if isinstance(index, bool) or not isinstance(index, int) or index < 0:
            raise ValueError(f"source: expected a camera index >= 0, got {index!r}")
        self.index, self.max_frames = index, frame_limit(max_frames)
        self._capture = cv2.VideoCapture(index)
        if not self._capture.isOpened():
            self._capture.release()
            raise ValueError(f"source: camera {index} could not be opened")
        fps = self._capture.get(cv2.CAP_PROP_FPS)
        self.fps = float(fps) if fps > 0 else None

    def __iter__(self) -> Iterator[np.ndarray]:
        if not self._capture.isOpened():
            raise ValueError(f"source: camera {self.index} is closed")
        yield from _read_all(self._capture, self.max_frames)

    def stamped(self) -> Iterator[StampedFrame]:
        """The frames, stamped and received when they are read (ns since the epoch)."""
        for index, image in enumerate(self):
            now = time.time_ns()
            yield StampedFrame(image, now, now, "", index)

    def close(self) -> None:
        self._capture.release()

    def __repr__(self) -> str:
        return f"Camera({self.index}, max_frames={self.max_frames})"


def open_source(
    source: str | int | os.PathLike,
    max_frames: int | None = None,
    topic: str | None = None,
    window: Sequence[float | None] | None = None,
) -> FrameSource:
    """A :class:`FrameSource` for a ROS bag, a video file, a folder of frames or a camera index.

    Args:
        source: a ROS bag (:func:`classifiers.bags.is_bag`), an existing file (video) or directory (frames), or
            a camera index (an int, or a string of digits that names no existing path).
        max_frames: stop after this many frames, whatever the source (``None``: a file's or folder's every
            frame, a camera until a read fails).
        topic: a bag's image topic (``None``: its only one); bags only.
        window: ``(start, stop)`` seconds from a bag's first message (receive times); bags only.

    Raises:
        TypeError: ``source`` is neither a path nor an int, or ``max_frames`` not an int.
        ValueError: an empty path, ``max_frames < 1``, or ``topic`` or ``window`` for a source that is not a bag.
        FileNotFoundError: a path that does not exist.
    """
    max_frames = frame_limit(max_frames)
    if isinstance(source, bool) or not isinstance(source, (str, int, os.PathLike)):
        raise TypeError(
            "source: expected a video file, a folder of frames or a camera index, or a ROS bag, "
            f"got {type(source).__name__}"
        )
    if not isinstance(source, int) and not str(os.fspath(source)).strip():
        raise ValueError(
            f"source: expected a video file, a folder of frames, a camera index or a ROS bag, got an empty path {source!r}"
        )
    if not isinstance(source, int) and is_bag(source):
        return BagSource(source, topic, max_frames, window)
    for name, value in (("topic", topic), ("window", window)):
        if value is not None:
            raise ValueError(f"{name}: only a ROS bag source has topics and receive times, got source {source!r}")
    if isinstance(source, int):
        return Camera(source, max_frames)
    path = Path(source)
    if path.is_dir():
        return FrameFolder(path, max_frames=max_frames)
    if path.is_file():
        return VideoFile(path, max_frames)
    if isinstance(source, str) and source.isdigit():
        return Camera(int(source), max_frames)
    raise FileNotFoundError(
        f"source: no such video file or folder {str(path)!r}, nor a ROS bag (a camera is given by its index)"
    )
