"""ROS bags as a frame source: bags written here with rosbags from rendered frames, in every storage and
encoding, and every way a bag can be wrong."""

import shutil

import cv2
import numpy as np
import pytest

from classifiers.bags import BagSource, is_bag, write_image_bag
from classifiers.data import render_sequence
from classifiers.sources import FrameFolder, open_source
from hbni_infra import ros

N = 6
FPS = 10.0
START = 1_700_000_000 * ros.NS_PER_S
LATENCY = 3_000_000  # each frame is received 3 ms after its stamp


@pytest.fixture(scope="module")
def frames():
    return render_sequence("police_car", N, "mission", seed=3)


def _name(tmp_path, storage, stem="bag"):
    return tmp_path / (f"{stem}.bag" if storage == "rosbag1" else stem)


def _write(tmp_path, frames, storage="mcap", encoding="bgr8", stem="bag"):
    return write_image_bag(
        _name(tmp_path, storage, stem), frames, "/cam/image", encoding, storage, FPS, START, LATENCY, "cam_optical"
    )


def _raw_bag(path, messages, storage="mcap"):
    """A bag of ``(topic, msgtype, message or raw bytes, log time)`` as given (the test's own mistakes included)."""
    ros1 = storage == "rosbag1"
    store = ros.typestore(ros1=ros1)
    rosbag1, rosbag2 = ros.require("rosbags.rosbag1"), ros.require("rosbags.rosbag2")
    if ros1:
        writer = rosbag1.Writer(path)
    else:
        plugin = rosbag2.StoragePlugin.MCAP if storage == "mcap" else rosbag2.StoragePlugin.SQLITE3
        writer = rosbag2.Writer(path, version=9, storage_plugin=plugin)
    connections = {}
    with writer:
        for topic, msgtype, msg, log_time in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            raw = (
                msg if isinstance(msg, bytes) else (store.serialize_ros1 if ros1 else store.serialize_cdr)(msg, msgtype)
            )
            writer.write(connections[topic], log_time, raw)
    return path


def _image(frame, i, encoding="bgr8", ros1=False):
    return ros.image_message(ros.typestore(ros1=ros1), frame, START + i, "cam", encoding)


LOSSLESS = ["bgr8", "rgb8", "bgra8", "rgba8", "png"]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "rosbag1"])
@pytest.mark.parametrize("encoding", LOSSLESS + ["mono8", "jpeg"])
def test_every_storage_and_encoding_gives_the_frames_and_their_times(tmp_path, frames, storage, encoding):
    path = _write(tmp_path, frames, storage, encoding)
    assert is_bag(path)
    source = open_source(path)
    assert isinstance(source, BagSource) and source.topic == "/cam/image" and source.num_frames == N
    assert source.msgtype == (ros.COMPRESSED_IMAGE if encoding in ("jpeg", "png") else ros.IMAGE)
    assert source.fps == pytest.approx(FPS)
    got = list(source.stamped())
    assert [f.index for f in got] == list(range(N))
    for i, (f, ref) in enumerate(zip(got, frames)):
        assert f.stamp == START + round(i * ros.NS_PER_S / FPS) and f.received == f.stamp + LATENCY
        assert f.frame_id == "cam_optical"
        assert f.image.dtype == np.uint8 and f.image.shape == ref.shape and f.image.flags.writeable
        if encoding in LOSSLESS:
            assert np.array_equal(f.image, ref)
        elif encoding == "mono8":
            assert np.array_equal(f.image, cv2.cvtColor(cv2.cvtColor(ref, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR))
        else:  # JPEG: lossy, and the decoded frame is the reference's own JPEG decoding
            assert np.array_equal(f.image, cv2.imdecode(cv2.imencode(".jpg", ref)[1], cv2.IMREAD_COLOR))
    assert all(np.array_equal(a, f.image) for a, f in zip(source, got))  # iterating again starts again


@pytest.mark.parametrize("storage, suffix", [("mcap", ".mcap"), ("sqlite3", ".db3")])
def test_a_rosbag2_storage_file_alone_is_a_bag(tmp_path, frames, storage, suffix):
    """A recording's storage file without its metadata.yaml (copied off a robot) reads the same."""
    bag = _write(tmp_path, frames, storage)
    alone = tmp_path / f"alone{suffix}"
    shutil.copy(bag / f"bag{suffix}", alone)
    assert is_bag(alone) and not is_bag(tmp_path)
    assert all(np.array_equal(a, b) for a, b in zip(open_source(alone), frames))


def test_max_frames_and_a_time_window(tmp_path, frames):
    path = _write(tmp_path, frames)
    assert [f.index for f in open_source(path, max_frames=4).stamped()] == [0, 1, 2, 3]
    assert open_source(path, max_frames=4).num_frames == 4
    # receive times are START + LATENCY + i / FPS: the window [0.15, 0.35) s from the first holds frames 2 and 3
    source = open_source(path, window=(0.15, 0.35))
    got = list(source.stamped())
    assert source.num_frames is None and [f.index for f in got] == [0, 1]
    assert [f.stamp for f in got] == [START + 2 * ros.NS_PER_S // 10, START + 3 * ros.NS_PER_S // 10]
    assert np.array_equal(got[0].image, frames[2])
    assert len(list(open_source(path, window=(0.25, None)))) == N - 3
    assert len(list(open_source(path, window=(0.15, None), max_frames=1))) == 1
    with pytest.raises(ValueError, match=r"window: expected 0 <= start < stop seconds from the bag's start"):
        BagSource(path, window=(0.3, 0.1))
    with pytest.raises(TypeError, match=r"window: expected \(start, stop\) in seconds"):
        BagSource(path, window=0.3)
    with pytest.raises(ValueError, match="window: only a ROS bag source has topics and receive times"):
        open_source(tmp_path, window=(0, 1))


def test_topics_two_image_topics_a_wrong_name_and_a_topic_without_images(tmp_path, frames):
    store = ros.typestore()
    string = store.types["std_msgs/msg/String"]
    path = _raw_bag(
        tmp_path / "two",
        [
            ("/left/image", ros.IMAGE, _image(frames[0], 0), START),
            ("/right/image/compressed", ros.COMPRESSED_IMAGE, _image(frames[1], 1, "png"), START + 1),
            ("/chatter", "std_msgs/msg/String", string(data="hello"), START + 2),
        ],
    )
    with pytest.raises(ValueError, match=r"has 2 image topics, \['/left/image', '/right/image/compressed'\]: pick one"):
        open_source(path)
    assert np.array_equal(next(iter(open_source(path, topic="/right/image/compressed"))), frames[1])
    assert np.array_equal(next(iter(open_source(path, topic="/left/image"))), frames[0])
    with pytest.raises(ValueError, match=r"topic: .* has no topic '/front/image'; its image topics: \['/left/image'"):
        open_source(path, topic="/front/image")
    with pytest.raises(ValueError, match=r"topic: '/chatter' of .* carries std_msgs/msg/String, not images"):
        open_source(path, topic="/chatter")
    only_text = _raw_bag(tmp_path / "text", [("/chatter", "std_msgs/msg/String", string(data="x"), START)])
    with pytest.raises(ValueError, match=r"has no image topic .*; its topics: /chatter \(std_msgs/msg/String\)"):
        open_source(only_text)
    with pytest.raises(ValueError, match="topic: only a ROS bag source"):
        open_source(tmp_path, topic="/left/image")
    with pytest.raises(TypeError, match="topic: expected a topic name"):
        BagSource(path, topic=3)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "rosbag1"])
def test_bad_messages_name_the_topic_and_the_message_index(tmp_path, frames, storage):
    ros1 = storage == "rosbag1"
    weird = _image(frames[1], 1, ros1=ros1)
    weird.encoding = "weird8"
    short = _image(frames[2], 2, ros1=ros1)
    short.data = short.data[:-5]
    garbled = _image(frames[3], 3, "jpeg", ros1=ros1)
    garbled.data = garbled.data[:40]
    cases = {"weird": (weird, ros.IMAGE), "short": (short, ros.IMAGE), "garbled": (garbled, ros.COMPRESSED_IMAGE)}
    expected = {
        "weird": r"message 1 of topic '/cam' in .* could not be decoded: unknown image encoding 'weird8'",
        "short": r"message 1 of topic '/cam' .*image data: 230395 bytes, expected height x step = 240 x 960",
        "garbled": r"message 1 of topic '/cam' .*compressed image \(format 'jpeg', 40 bytes\) could not be decoded",
    }
    for name, (bad, msgtype) in cases.items():
        good = _image(frames[0], 0, "jpeg" if msgtype == ros.COMPRESSED_IMAGE else "bgr8", ros1=ros1)
        path = _raw_bag(
            _name(tmp_path, storage, name),
            [("/cam", msgtype, m, START + i) for i, m in enumerate([good, bad])],
            storage,
        )
        source = open_source(path)
        frames_read = source.stamped()
        assert next(frames_read).index == 0  # the frames before a bad message are read
        with pytest.raises(ValueError, match=expected[name] + r".*"):
            next(frames_read)
    corrupt = _raw_bag(
        _name(tmp_path, storage, "corrupt"),
        [
            ("/cam", ros.IMAGE, _image(frames[0], 0, ros1=ros1), START),
            ("/cam", ros.IMAGE, b"\x00\x01\x00\x00\xff", START + 1),
        ],
        storage,
    )
    with pytest.raises(ValueError, match=r"message 1 of topic '/cam' .*\(receive time \d+ ns\) could not be decoded"):
        list(open_source(corrupt))


@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "rosbag1"])
@pytest.mark.parametrize("keep", [0.0, 0.5, 0.97])
def test_a_truncated_bag_is_a_clear_error(tmp_path, frames, storage, keep):
    bag = _write(tmp_path, frames, storage)
    data_file = bag if storage == "rosbag1" else next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
    data = data_file.read_bytes()
    data_file.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(
        ValueError, match=r"could not be read as a ROS bag|message \d+ of topic '/cam/image' in .* could not be read"
    ):
        list(open_source(bag))


def test_missing_bag_and_frame_folders_are_unchanged(tmp_path, frames):
    with pytest.raises(FileNotFoundError, match="source: no such bag"):
        BagSource(tmp_path / "nothing")
    (tmp_path / "metadata.yaml").write_text("not: a bag\n")  # a rosbag2 directory without its storage
    with pytest.raises(ValueError, match="could not be read as a ROS bag"):
        open_source(tmp_path)
    folder = tmp_path / "frames"
    folder.mkdir()
    cv2.imwrite(str(folder / "0.png"), frames[0])
    source = open_source(folder, max_frames=1)
    assert isinstance(source, FrameFolder) and not is_bag(folder)
    (stamped,) = list(source.stamped())  # no frame rate: stamped and received when read
    assert stamped.stamp == stamped.received > START and stamped.index == 0


def test_other_sources_stamp_frames_on_their_own_timeline(tmp_path, frames):
    for i, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"{i}.png"), f)
    got = list(FrameFolder(tmp_path, fps=FPS).stamped())
    assert [f.stamp for f in got] == [round(i * ros.NS_PER_S / FPS) for i in range(N)]
    assert all(np.array_equal(f.image, ref) for f, ref in zip(got, frames))


def test_write_image_bag_rejects_bad_arguments(tmp_path, frames):
    with pytest.raises(ValueError, match=r"storage: expected one of \['mcap', 'sqlite3', 'rosbag1'\]"):
        write_image_bag(tmp_path / "x", frames, storage="zip")
    with pytest.raises(ValueError, match="encoding: expected one of"):
        write_image_bag(tmp_path / "x", frames, encoding="yuv")
    with pytest.raises(ValueError, match="path: a ROS 1 bag is a file whose name ends in .bag"):
        write_image_bag(tmp_path / "x.mcap", frames, storage="rosbag1")
    with pytest.raises(ValueError, match="fps: expected a rate > 0"):
        write_image_bag(tmp_path / "x", frames, fps=0)
    with pytest.raises(ValueError, match=r"image: expected a uint8 BGR array \(H, W, 3\), got float64 array"):
        write_image_bag(tmp_path / "x", [frames[0] / 255.0])
    assert not (tmp_path / "x").exists() and not list(tmp_path.iterdir())  # nothing left behind
    _write(tmp_path, frames)
    with pytest.raises(FileExistsError, match="exists already"):
        _write(tmp_path, frames)


def test_bag_support_imports_lazily_and_says_what_to_install(tmp_path, frames, repo_root):
    """Without the ros extra the libraries import, and opening a bag says what to install."""
    import subprocess
    import sys

    path = _write(tmp_path, frames)
    code = f"""
import sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("rosbags", "mcap", "mcap_ros2", "rclpy"):
            raise ImportError(f"No module named {{name!r}} (blocked)")
sys.meta_path.insert(0, Block())
import classifiers, classifiers.bags, classifiers.sources, hbni_pyro, hbni_pyro.runtime.ros_messages, hbni_pyro.runtime.live, hbni_infra.ros
import experiments.studies.stream
try:
    classifiers.sources.open_source({str(path)!r})
except ImportError as exc:
    print(exc)
"""
    proc = subprocess.run([sys.executable, "-c", code], cwd=repo_root, capture_output=True, text=True, check=True)
    assert "Reading and writing ROS bags needs the package 'rosbags': pip install 'hbni-pyro[ros]'" in proc.stdout


@pytest.mark.parametrize("encoding", ["bgr8", "png"])
def test_mcap_bags_are_written_with_chunk_crcs_the_mcap_library_checks(tmp_path, frames, encoding):
    """Every chunk carries its CRC-32 (rosbags writes 0, "unchecked"); the mcap library, checking them, reads every
    frame, and rosbags (checking them too) reads the same frames back."""
    make_reader = ros.require("mcap.reader").make_reader
    bag = _write(tmp_path, frames, encoding=encoding)
    with open(bag / "bag.mcap", "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        chunks = reader.get_summary().chunk_indexes
        assert sum(1 for _ in reader.iter_messages()) == N
    data = (bag / "bag.mcap").read_bytes()
    assert chunks and all(
        int.from_bytes(data[c.chunk_start_offset + ros.MCAP_CHUNK_CRC_OFFSET :][:4], "little") for c in chunks
    )
    assert ros.damaged_chunks(bag / "bag.mcap") == [] and len(list(BagSource(bag))) == N
