"""ROS plumbing: times as nanoseconds, camera images to and from messages (padded rows, byte order, depth,
rclpy-like messages), the extra's import message, and atomic paths for writers that make their own files."""

import array
import os
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from hbni_infra import ros
from hbni_infra.files import atomic_path


@pytest.fixture(scope="module")
def bgr():
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)


def test_times_round_trip_through_seconds_and_nanoseconds():
    for ns in (0, 1, 999_999_999, 1_000_000_000, 1_700_000_000_123_456_789, -1):
        sec, nanosec = ros.time_fields(ns)
        assert 0 <= nanosec < ros.NS_PER_S and ros.nanoseconds(SimpleNamespace(sec=sec, nanosec=nanosec)) == ns
    assert ros.time_fields(-1) == (-1, 999_999_999)


@pytest.mark.parametrize("ros1", [False, True])
@pytest.mark.parametrize("encoding", ["bgr8", "rgb8", "bgra8", "rgba8", "mono8", "png", "jpeg"])
def test_image_messages_round_trip(bgr, encoding, ros1):
    msg = ros.image_message(ros.typestore(ros1=ros1), bgr, 1_234_000_000_005, "cam", encoding)
    assert ros.nanoseconds(msg.header.stamp) == 1_234_000_000_005 and msg.header.frame_id == "cam"
    back = ros.image_from_message(msg)
    assert back.shape == bgr.shape and back.dtype == np.uint8 and back.flags.writeable and back.flags.c_contiguous
    if encoding == "mono8":
        assert (
            np.array_equal(back[..., 0], cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)) and (back[..., 0] == back[..., 2]).all()
        )
    elif encoding == "jpeg":
        assert np.abs(back.astype(int) - bgr).mean() < 60  # lossy on random pixels
    else:
        assert np.array_equal(back, bgr)


def _raw(pixels, encoding, step=None, bigendian=False):
    """An rclpy-like Image: fields only, data as array.array (what rclpy gives)."""
    h, w = pixels.shape[:2]
    rows = pixels.reshape(h, -1).view(np.uint8)
    step = rows.shape[1] if step is None else step
    padded = np.zeros((h, step), np.uint8)
    padded[:, : rows.shape[1]] = rows
    return SimpleNamespace(
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=int(bigendian),
        step=step,
        data=array.array("B", padded.tobytes()),
    )


def test_padded_rows_byte_order_depth_and_bayer(bgr):
    assert np.array_equal(
        ros.image_from_message(_raw(bgr, "bgr8", step=32)), bgr
    )  # 21 bytes of pixels per row, 32 sent
    rgb = bgr[..., ::-1].copy()
    assert np.array_equal(ros.image_from_message(_raw(rgb, "rgb8", step=24)), bgr)
    grey16 = (np.arange(35, dtype=np.uint16).reshape(5, 7) * 1000).astype(">u2")  # big-endian 16-bit
    got = ros.image_from_message(_raw(grey16, "mono16", step=16, bigendian=True))
    expected = (grey16.astype(np.float64) * 255.0 / 65535.0).astype(np.uint8)
    assert np.array_equal(got[..., 1], expected)
    assert np.array_equal(ros.image_from_message(_raw(bgr, "8UC3")), bgr)  # a generic 3-channel encoding
    bayer = np.random.default_rng(1).integers(0, 256, (6, 8), dtype=np.uint8)
    assert np.array_equal(
        ros.image_from_message(_raw(bayer, "bayer_rggb8")), cv2.cvtColor(bayer, cv2.COLOR_BAYER_BG2BGR)
    )


def test_bad_images_are_clear_errors(bgr):
    with pytest.raises(ValueError, match=r"unknown image encoding 'weird8'; expected a sensor_msgs/image_encodings"):
        ros.image_from_message(_raw(bgr, "weird8"))
    with pytest.raises(ValueError, match="image encoding '32FC1' has no conversion to a bgr8 frame"):
        ros.image_from_message(_raw(np.zeros((2, 2), np.float32), "32FC1"))
    with pytest.raises(
        ValueError, match=r"image header: height 5, width 7, step 20 for bgr8; expected .* step >= width x 3"
    ):
        ros.image_from_message(SimpleNamespace(**{**vars(_raw(bgr, "bgr8")), "step": 20}))
    with pytest.raises(ValueError, match=r"image data: 100 bytes, expected height x step = 5 x 21 = 105"):
        ros.image_from_message(SimpleNamespace(**{**vars(_raw(bgr, "bgr8")), "data": bytes(100)}))
    with pytest.raises(ValueError, match=r"compressed image \(format 'png', 0 bytes\) could not be decoded"):
        ros.image_from_message(SimpleNamespace(format="png", data=b""))
    store = ros.typestore()
    with pytest.raises(
        ValueError, match=r"encoding: expected one of \['bgr8', 'rgb8', 'mono8', 'bgra8', 'rgba8', 'jpeg'"
    ):
        ros.image_message(store, bgr, 0, encoding="yuv422")
    with pytest.raises(
        ValueError, match=r"image: expected a uint8 BGR array \(H, W, 3\), got uint8 array of shape \(5, 7\)"
    ):
        ros.image_message(store, bgr[..., 0], 0)


def test_a_missing_extra_says_what_to_install():
    with pytest.raises(
        ImportError,
        match=r"Reading and writing ROS bags needs the package 'no_such_ros_module': pip install 'hbni-pyro\[ros\]'",
    ):
        ros.require("no_such_ros_module")


def test_atomic_path_moves_a_written_directory_into_place_or_leaves_nothing(tmp_path):
    target = tmp_path / "out" / "bag"
    with atomic_path(target) as staged:
        assert staged.name == "bag" and not target.exists()
        staged.mkdir()
        (staged / "bag.mcap").write_bytes(b"x")
    assert (target / "bag.mcap").read_bytes() == b"x" and os.listdir(target.parent) == ["bag"]
    assert oct((target / "bag.mcap").stat().st_mode & 0o777) == oct(0o666 & ~_umask())
    with pytest.raises(FileExistsError, match="exists already"), atomic_path(target):
        pass
    with pytest.raises(RuntimeError), atomic_path(tmp_path / "out" / "other.bag") as staged:
        staged.write_bytes(b"half")
        raise RuntimeError("writer failed")
    assert os.listdir(target.parent) == ["bag"]  # no staging directory and no partial file left


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask
