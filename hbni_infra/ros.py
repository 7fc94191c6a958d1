"""ROS plumbing shared by the bag reader (:mod:`classifiers.bags`) and the bag writer
(:mod:`hbni_pyro.runtime.ros_messages`).

* The ``ros`` extra's packages (``rosbags``, ``rosbags-image``, ``mcap``, ``mcap-ros2-support``) are imported
  on first use by :func:`require` (:func:`hbni_infra.optional.require`), which says what to install when one is
  missing: the libraries import without them, and this module without OpenCV too.
* ROS times (``builtin_interfaces/msg/Time``, ROS 1 ``time``: seconds and nanoseconds) travel through the
  project as integer nanoseconds since the epoch (:func:`nanoseconds`, :func:`time_fields`).
* Camera images: :func:`image_message` writes a uint8 BGR frame as a ``sensor_msgs/msg/Image`` (``bgr8``,
  ``rgb8``, ``mono8``, ``bgra8``, ``rgba8``) or ``sensor_msgs/msg/CompressedImage`` (``jpeg``, ``png``);
  :func:`image_from_message` reads either back as uint8 BGR, for every encoding ``rosbags-image`` knows
  (row padding, byte order and depth included). It reads fields only, so it takes ``rosbags`` messages and
  ``rclpy`` ones alike.
* Bags: :func:`rosbag2_writer` writes rosbag2 directories whose MCAP chunks carry their CRC-32, so that a reader
  (``rosbags``, the ``mcap`` library, ``ros2 bag``) refuses a damaged chunk instead of returning damaged frames.
"""

from __future__ import annotations

import functools
import struct
import zlib
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from hbni_infra.optional import require as _optional

NS_PER_S = 1_000_000_000
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
RAW_ENCODINGS = {
    "bgr8": None,
    "rgb8": "COLOR_BGR2RGB",
    "mono8": "COLOR_BGR2GRAY",
    "bgra8": "COLOR_BGR2BGRA",
    "rgba8": "COLOR_BGR2RGBA",
}
"""Encodings :func:`image_message` writes as ``sensor_msgs/msg/Image``, with the OpenCV conversion from BGR."""
COMPRESSED_FORMATS = {"jpeg": ".jpg", "png": ".png"}
"""Formats :func:`image_message` writes as ``sensor_msgs/msg/CompressedImage``, with their file suffix."""


def require(module: str) -> ModuleType:
    """``module`` of the ``ros`` extra, or an ImportError that says to install it (no ROS installation needed)."""
    return _optional(module, "ros", "Reading and writing ROS bags")


def _cv2() -> ModuleType:
    return _optional("cv2", "opencv", "Converting camera images to and from ROS messages")


def nanoseconds(stamp: Any) -> int:
    """A ROS time (``sec``, ``nanosec`` fields) as integer nanoseconds since the epoch."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def time_fields(ns: int) -> tuple[int, int]:
    """Integer nanoseconds as ROS time fields ``(sec, nanosec)``, ``0 <= nanosec < 10**9``."""
    sec, nanosec = divmod(int(ns), NS_PER_S)
    return sec, nanosec


@functools.lru_cache(maxsize=8)
def typestore(ros1: bool = False, definitions: tuple[tuple[str, str], ...] = ()) -> Any:
    """A ``rosbags`` typestore: ROS 2 Humble's types (ROS 1 Noetic's with ``ros1``) plus ``definitions``,
    ``(type name, .msg text)`` pairs such as ``("vision_msgs/msg/Classification", "...")``. Cached: do not
    register more types in it."""
    typesys = require("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS1_NOETIC if ros1 else typesys.Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name, text in definitions:
        types.update(typesys.get_types_from_msg(text, name))
    store.register(types)
    return store


def header(store: Any, stamp: int, frame_id: str = "") -> Any:
    """A ``std_msgs/msg/Header`` of ``store`` (ROS 1's has a ``seq``, left 0)."""
    types = store.types
    time = types["builtin_interfaces/msg/Time"](*time_fields(stamp))
    cls = types["std_msgs/msg/Header"]
    if "seq" in cls.__dataclass_fields__:
        return cls(seq=0, stamp=time, frame_id=frame_id)
    return cls(stamp=time, frame_id=frame_id)


def image_message(store: Any, image: np.ndarray, stamp: int, frame_id: str = "", encoding: str = "bgr8") -> Any:
    """A uint8 BGR frame ``(H, W, 3)`` as a ``sensor_msgs/msg/Image`` (a :data:`RAW_ENCODINGS` key) or a
    ``sensor_msgs/msg/CompressedImage`` (a :data:`COMPRESSED_FORMATS` key) of ``store``, stamped ``stamp`` (ns).

    Raises:
        ValueError: ``image`` is not uint8 ``(H, W, 3)``, or an unknown ``encoding``.
    """
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image: expected a uint8 BGR array (H, W, 3), got {_describe(image)}")
    cv2 = _cv2()
    head = header(store, stamp, frame_id)
    if encoding in COMPRESSED_FORMATS:
        ok, buffer = cv2.imencode(COMPRESSED_FORMATS[encoding], image)
        if not ok:
            raise ValueError(f"image: OpenCV could not encode it as {encoding}")
        return store.types[COMPRESSED_IMAGE](header=head, format=encoding, data=buffer.reshape(-1))
    if encoding not in RAW_ENCODINGS:
        raise ValueError(f"encoding: expected one of {[*RAW_ENCODINGS, *COMPRESSED_FORMATS]}, got {encoding!r}")
    code = RAW_ENCODINGS[encoding]
    pixels = np.ascontiguousarray(image if code is None else cv2.cvtColor(image, getattr(cv2, code)))
    h, w = pixels.shape[:2]
    return store.types[IMAGE](
        header=head,
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=pixels.size // h,
        data=pixels.reshape(-1),
    )


def image_from_message(msg: Any) -> np.ndarray:
    """The uint8 BGR frame ``(H, W, 3)`` of an ``Image`` or ``CompressedImage`` message (its fields are read).

    A raw image may have padded rows (``step``), either byte order and any encoding ``rosbags-image``
    converts to ``bgr8`` (mono, colour with or without alpha, Bayer, YUV, 16-bit); a compressed one any
    format OpenCV decodes (JPEG, PNG, ...). The frame owns its pixels (writable).

    Raises:
        ValueError: an unknown encoding, data shorter than its header says, or bytes that do not decode.
    """
    cv2 = _cv2()
    data = np.frombuffer(msg.data, np.uint8)
    if hasattr(msg, "format"):  # a CompressedImage
        frame = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
        if frame is None:
            raise ValueError(f"compressed image (format {msg.format!r}, {data.size} bytes) could not be decoded")
        return frame
    image = require("rosbags.image.image")  # its encoding table and colour conversions
    try:
        _, _, typestr, channels = image.to_cvtype(msg.encoding)
    except image.ImageFormatError:
        raise ValueError(
            f"unknown image encoding {msg.encoding!r}; expected a sensor_msgs/image_encodings name such as "
            f"{list(RAW_ENCODINGS)}"
        ) from None
    dtype = np.dtype(typestr).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row = w * channels * dtype.itemsize
    if h < 1 or w < 1 or step < row:
        raise ValueError(
            f"image header: height {h}, width {w}, step {step} for {msg.encoding}; expected height, width >= 1 "
            f"and step >= width x {channels * dtype.itemsize} bytes = {row}"
        )
    if data.size < h * step:
        raise ValueError(f"image data: {data.size} bytes, expected height x step = {h} x {step} = {h * step}")
    rows = data[: h * step].reshape(h, step)[:, :row]
    pixels = np.ascontiguousarray(rows).view(dtype).reshape((h, w) if channels == 1 else (h, w, channels))
    pixels = pixels.astype(dtype.newbyteorder("="), copy=False)
    try:
        frame = np.asarray(image.convert_color(pixels, msg.encoding, "bgr8"))
    except (image.ImageConversionError, cv2.error):
        frame = None
    if frame is None or frame.dtype != np.uint8 or frame.shape != (h, w, 3):
        raise ValueError(f"image encoding {msg.encoding!r} has no conversion to a bgr8 frame")
    return frame if frame.flags.writeable and frame.flags.c_contiguous else frame.copy()


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"{value.dtype} array of shape {value.shape}"
    return type(value).__name__


MCAP_CHUNK_CRC_OFFSET = 1 + 8 + 24
"""Byte offset of ``uncompressed_crc`` in an MCAP Chunk record: opcode, record length, then message start time,
message end time and uncompressed size (MCAP specification, Chunk record)."""


@functools.cache
def _rosbag2_writer_class() -> type:
    """``rosbags``' rosbag2 ``Writer`` whose MCAP storage writes every chunk's CRC-32 (``rosbags`` writes 0, which
    readers take as "not checked")."""
    rosbag2 = require("rosbags.rosbag2")
    storage = require("rosbags.rosbag2.storage_mcap")

    class ChunkCrcMcapWriter(storage.McapWriter):
        def close_chunk(self) -> None:
            crc = zlib.crc32(self.chunk.bio.getbuffer())
            super().close_chunk()
            chunk_start = struct.unpack_from("<Q", self.chunks[-1].getbuffer(), 16)[0]  # ChunkIndex.chunk_start_offset
            end = self.bio.tell()
            self.bio.seek(chunk_start + MCAP_CHUNK_CRC_OFFSET)
            self.bio.write(struct.pack("<I", crc))
            self.bio.seek(end)

    class Writer(rosbag2.Writer):
        STORAGE_PLUGINS = {**rosbag2.Writer.STORAGE_PLUGINS, rosbag2.StoragePlugin.MCAP: ChunkCrcMcapWriter}

    return Writer


def rosbag2_writer(path: str | Path, storage: str = "mcap") -> Any:
    """A ``rosbags`` rosbag2 writer (a context manager) of a new bag directory ``path`` with ``"mcap"`` or
    ``"sqlite3"`` storage, in the latest rosbag2 version. MCAP chunks carry their CRC-32 and are not compressed:
    camera frames barely compress, and decompressing costs more reading time than the bytes saved (see
    ``docs/ros.md``)."""
    rosbag2 = require("rosbags.rosbag2")
    plugin = rosbag2.StoragePlugin.MCAP if storage == "mcap" else rosbag2.StoragePlugin.SQLITE3
    return _rosbag2_writer_class()(path, version=rosbag2.Writer.VERSION_LATEST, storage_plugin=plugin)


def damaged_chunks(path: str | Path) -> list[tuple[int, int, int]]:
    """``(byte offset, first log time, last log time)`` (ns) of every chunk of the MCAP file ``path`` whose data does
    not match its CRC-32 (chunks written without one, CRC 0, are not checked), from its summary's chunk index."""
    make_reader = require("mcap.reader").make_reader
    decompressors = require("rosbags.rosbag2.storage_mcap").DECOMPRESSORS
    damaged = []
    with open(path, "rb") as stream:
        summary = make_reader(stream).get_summary()
        for index in [] if summary is None else summary.chunk_indexes:
            stream.seek(index.chunk_start_offset + MCAP_CHUNK_CRC_OFFSET)
            (crc,) = struct.unpack("<I", stream.read(4))
            (name_length,) = struct.unpack("<I", stream.read(4))
            compression = stream.read(name_length).decode()
            (size,) = struct.unpack("<Q", stream.read(8))
            try:
                data = decompressors[compression](stream.read(size), index.uncompressed_size)
                intact = not crc or zlib.crc32(data) == crc
            except Exception:  # noqa: BLE001 - undecodable data is damage too
                intact = False
            if not intact:
                damaged.append((index.chunk_start_offset, index.message_start_time, index.message_end_time))
    return damaged
