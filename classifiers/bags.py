"""ROS bags as a frame source: an image topic of a rosbag2 (MCAP or sqlite3) or ROS 1 bag, read with ``rosbags``.

:class:`BagSource` reads ``sensor_msgs/msg/Image`` (any encoding :func:`hbni_infra.ros.image_from_message`
converts: ``bgr8``, ``rgb8``, ``mono8``, ``bgra8``, ``rgba8``, Bayer, 16-bit, ...) and
``sensor_msgs/msg/CompressedImage`` (JPEG, PNG) messages without a ROS installation, and is a
:class:`~classifiers.sources.FrameSource` like the others: uint8 BGR frames, ``max_frames``, and
:meth:`BagSource.stamped` frames with their header stamp, the bag's receive (log) time and frame id. A
time window (seconds from the bag's first message, on receive times, as ``ros2 bag play --start-offset``)
reads part of a recording. :func:`write_image_bag` writes frames as an image topic of a new bag (its inverse:
demo and test recordings).

The ``rosbags`` packages are the ``ros`` extra's, imported when a bag is opened (``pip install
'hbni-pyro[ros]'``).
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from classifiers.frame_source import FrameSource, frame_limit
from classifiers.stamped import StampedFrame
from hbni_infra import ros
from hbni_infra.files import atomic_path

__all__ = ["BAG_SUFFIXES", "IMAGE_TYPES", "STORAGES", "BagSource", "is_bag", "write_image_bag"]

IMAGE_TYPES = (ros.IMAGE, ros.COMPRESSED_IMAGE)
"""The message types of an image topic."""
BAG_SUFFIXES = (".mcap", ".db3", ".bag")
"""Files read as bags: a rosbag2 storage file (MCAP, sqlite3) or a ROS 1 bag."""
STORAGES = ("mcap", "sqlite3", "rosbag1")
"""What :func:`write_image_bag` writes: a rosbag2 directory with MCAP or sqlite3 storage, or a ROS 1 ``.bag``."""


def is_bag(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a bag: a rosbag2 directory (it holds ``metadata.yaml``) or a :data:`BAG_SUFFIXES` file."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.is_file() and path.suffix in BAG_SUFFIXES


def _window(window: Any) -> tuple[float, float] | None:
    """``window`` checked: ``None`` or ``(start, stop)`` seconds, ``0 <= start < stop`` (``stop`` may be ``None``)."""
    if window is None:
        return None
    if isinstance(window, (str, bytes)) or not isinstance(window, Sequence) or len(window) != 2:
        raise TypeError(f"window: expected (start, stop) in seconds from the bag's start, got {window!r}")
    start, stop = window
    stop = math.inf if stop is None else stop
    for value in (start, stop):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TypeError(f"window: expected numbers of seconds, got {window!r}")
    if not 0 <= start < stop:
        raise ValueError(f"window: expected 0 <= start < stop seconds from the bag's start, got {window!r}")
    return float(start), float(stop)


class BagSource(FrameSource):
    """The frames of one image topic of a ROS bag, in receive order.

    Args:
        path: a rosbag2 directory (``metadata.yaml`` and its storage files), a single ``.mcap`` or ``.db3``
            file, or a ROS 1 ``.bag`` file.
        topic: the image topic to read (``None``: the bag's only ``Image`` or ``CompressedImage`` topic).
        max_frames: read only the first this many frames (``None``: all of them).
        window: ``(start, stop)`` seconds from the bag's first message, on receive times, ``stop`` exclusive
            (``None`` for either end: no bound); ``None``: the whole bag.

    Attributes:
        topic, msgtype: the topic read and its message type.
        start_time: the bag's first receive time (ns since the epoch).
        fps: the topic's mean rate over the bag's duration (``None`` with fewer than two messages).
        num_frames: the topic's message count (capped by ``max_frames``; ``None`` with a window).

    :meth:`stamped` frames carry the header stamp, the receive time, the header's frame id and the
    message's index among those read (from 0). Iterating again starts again from the first message.

    Raises:
        FileNotFoundError: no such path.
        ValueError: not a readable bag (corrupt, truncated, unknown storage: the message says which file and
            why), no image topic, several image topics and no ``topic`` (the error lists them), a ``topic``
            the bag lacks or that carries no images, or a bad ``max_frames`` or ``window``. While iterating: a
            message that cannot be read or decoded (an unknown encoding, short data, corrupt bytes), naming
            the topic and the message's index and receive time; a damaged MCAP chunk (its data fail the CRC-32
            that bags written here carry), naming the file and the chunk's byte offset and times; a header stamp
            before the previous frame's (stamps running backwards, a clock jump).
        ImportError: the ``ros`` extra is not installed (the message says what to install).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        topic: str | None = None,
        max_frames: int | None = None,
        window: Sequence[float | None] | None = None,
    ) -> None:
        self.max_frames = frame_limit(max_frames)
        self.window = _window(window)
        if topic is not None and not isinstance(topic, str):
            raise TypeError(f"topic: expected a topic name (str) or None, got {type(topic).__name__}")
        if topic == "":
            raise ValueError("topic: expected a topic name or None, got ''")
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"source: no such bag {str(self.path)!r}")
        with self._reader() as reader:
            topics = {name: info.msgtype for name, info in reader.topics.items()}
            images = sorted(name for name, msgtype in topics.items() if msgtype in IMAGE_TYPES)
            self.topic = self._pick(topic, topics, images)
            self.msgtype = topics[self.topic]
            count = reader.topics[self.topic].msgcount
            self.start_time = reader.start_time if count else 0
            duration = (reader.end_time - 1 - reader.start_time) / ros.NS_PER_S if count else 0.0  # end: last + 1 ns
        self.fps = (count - 1) / duration if count > 1 and duration > 0 else None
        self.num_frames = None if self.window is not None else min(count, self.max_frames or count)

    def _pick(self, topic: str | None, topics: dict[str, str], images: list[str]) -> str:
        where = f"{str(self.path)!r}"
        listed = ", ".join(f"{name} ({msgtype})" for name, msgtype in sorted(topics.items())) or "none"
        if topic is None:
            if not images:
                raise ValueError(
                    f"source: {where} has no image topic (sensor_msgs/msg/Image or CompressedImage); its topics: "
                    f"{listed}"
                )
            if len(images) > 1:
                raise ValueError(f"topic: {where} has {len(images)} image topics, {images}: pick one with topic")
            return images[0]
        if topic not in topics:
            raise ValueError(f"topic: {where} has no topic {topic!r}; its image topics: {images}")
        if topics[topic] not in IMAGE_TYPES:
            raise ValueError(
                f"topic: {topic!r} of {where} carries {topics[topic]}, not images "
                f"(sensor_msgs/msg/Image or CompressedImage); its image topics: {images}"
            )
        return topic

    @contextlib.contextmanager
    def _reader(self) -> Iterator[Any]:
        """An open ``AnyReader``, closed after the block; a bag it cannot open is a ValueError naming the file."""
        highlevel = ros.require("rosbags.highlevel")
        try:
            reader = highlevel.AnyReader([self.path])
            reader.open()
        except Exception as exc:
            raise ValueError(f"source: {str(self.path)!r} could not be read as a ROS bag: {_cause(exc)}") from exc
        try:
            yield reader
        finally:
            reader.close()

    def stamped(self) -> Iterator[StampedFrame]:
        with self._reader() as reader:
            connections = [c for c in reader.connections if c.topic == self.topic]
            start = stop = None
            if self.window is not None:
                start = reader.start_time + round(self.window[0] * ros.NS_PER_S)
                stop = None if math.isinf(self.window[1]) else reader.start_time + round(self.window[1] * ros.NS_PER_S)
            messages = reader.messages(connections, start=start, stop=stop)
            index, previous = 0, None
            while self.max_frames is None or index < self.max_frames:
                try:
                    item = next(messages, None)
                except Exception as exc:
                    raise ValueError(f"{self._where(index)} could not be read: {self._damage(exc)}") from exc
                if item is None:
                    return
                connection, received, raw = item
                try:
                    msg = reader.deserialize(raw, connection.msgtype)
                    image = ros.image_from_message(msg)
                except Exception as exc:
                    raise ValueError(
                        f"{self._where(index)} (receive time {received} ns) could not be decoded: {_cause(exc)}"
                    ) from exc
                stamp = ros.nanoseconds(msg.header.stamp)
                if previous is not None and stamp < previous:
                    raise ValueError(
                        f"{self._where(index)}: its header stamp {stamp} ns is {(previous - stamp) / ros.NS_PER_S:g} "
                        f"s before the previous frame's ({previous} ns): the stamps run backwards (a clock jump), "
                        f"so macro-observations would end before they start; read the parts on either side of it "
                        f"with window=(start, stop)"
                    )
                previous = stamp
                yield StampedFrame(image, stamp, received, msg.header.frame_id, index)
                index += 1

    def _damage(self, exc: BaseException) -> str:
        """What a read error says, with the damaged chunks of the bag's MCAP files named where a CRC check failed."""
        cause = _cause(exc)
        if "checksum" not in str(exc).lower() and "crc" not in str(exc).lower():
            return cause
        files = sorted(self.path.glob("*.mcap")) if self.path.is_dir() else [self.path]
        damaged = [
            f"{str(path)!r}: the chunk at byte {offset} (messages received from {first} to {last} ns)"
            for path in files
            if path.suffix == ".mcap"
            for offset, first, last in ros.damaged_chunks(path)
        ]
        return f"{cause} The data fail their CRC-32 check in {'; '.join(damaged) or 'the bag'}: the file is damaged"

    def _where(self, index: int) -> str:
        window = "" if self.window is None else f" in the window {list(self.window)} s"
        return f"source: message {index}{window} of topic {self.topic!r} in {str(self.path)!r}"

    def __iter__(self) -> Iterator[np.ndarray]:
        for frame in self.stamped():
            yield frame.image

    def __repr__(self) -> str:
        return f"BagSource({str(self.path)!r}, topic={self.topic!r}, frames={self.num_frames})"


def _cause(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}" if not isinstance(exc, ValueError) else str(exc)


def write_image_bag(
    path: str | os.PathLike,
    frames: Iterable[np.ndarray],
    topic: str = "/camera/image_raw",
    encoding: str = "bgr8",
    storage: str = "mcap",
    fps: float = 30.0,
    start: int = 1_700_000_000 * ros.NS_PER_S,
    latency: int = 0,
    frame_id: str = "camera",
) -> Path:
    """Write uint8 BGR frames ``(H, W, 3)`` as one image topic of a new bag; returns its path.

    Frame ``i`` is stamped ``start + i / fps`` (ns) and received ``latency`` ns later.

    Args:
        path: the bag to create: a rosbag2 directory (``storage`` ``"mcap"`` or ``"sqlite3"``) or a ROS 1 file
            whose name ends in ``.bag`` (``"rosbag1"``). Written atomically; never overwritten.
        encoding: ``sensor_msgs/msg/Image`` encoding (``bgr8``, ``rgb8``, ``mono8``, ``bgra8``, ``rgba8``) or
            ``sensor_msgs/msg/CompressedImage`` format (``jpeg``, ``png``).

    Raises:
        FileExistsError: ``path`` exists.
        ValueError: an unknown ``storage`` or ``encoding``, a ROS 1 path not ending in ``.bag``, a frame that is
            not uint8 ``(H, W, 3)``, or ``fps <= 0``.
    """
    if storage not in STORAGES:
        raise ValueError(f"storage: expected one of {list(STORAGES)}, got {storage!r}")
    if encoding not in (*ros.RAW_ENCODINGS, *ros.COMPRESSED_FORMATS):
        raise ValueError(f"encoding: expected one of {[*ros.RAW_ENCODINGS, *ros.COMPRESSED_FORMATS]}, got {encoding!r}")
    if not isinstance(fps, (int, float)) or isinstance(fps, bool) or not fps > 0:
        raise ValueError(f"fps: expected a rate > 0, got {fps!r}")
    path = Path(path)
    ros1 = storage == "rosbag1"
    if ros1 and path.suffix != ".bag":
        raise ValueError(f"path: a ROS 1 bag is a file whose name ends in .bag, got {str(path)!r}")
    store = ros.typestore(ros1=ros1)
    msgtype = ros.COMPRESSED_IMAGE if encoding in ros.COMPRESSED_FORMATS else ros.IMAGE
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    with atomic_path(path) as staged, _bag_writer(staged, storage) as writer:
        connection = writer.add_connection(topic, msgtype, typestore=store)
        for i, frame in enumerate(frames):
            stamp = start + round(i * ros.NS_PER_S / fps)
            msg = ros.image_message(store, frame, stamp, frame_id, encoding)
            writer.write(connection, stamp + latency, serialize(msg, msgtype))
    return path


def _bag_writer(path: Path, storage: str) -> Any:
    """A ``rosbags`` writer (a context manager) of ``storage`` for a new bag at ``path``."""
    if storage == "rosbag1":
        return ros.require("rosbags.rosbag1").Writer(path)
    return ros.rosbag2_writer(path, storage)
