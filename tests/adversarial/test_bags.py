"""Bags you can trust: the project's MCAP bags carry chunk CRCs, so damaged bytes in a chunk are refused with the file
and the chunk named (never frames read back partly black); a bag whose header stamps run backwards is refused by name.
The ``mcap`` library, an independent reader, checks the same CRCs."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from classifiers.bags import BagSource, write_image_bag
from classifiers.data import render_sequence
from hbni_infra import ros
from hbni_pyro.runtime import MacroObservationBag

START = 1_700_000_000 * ros.NS_PER_S


@pytest.fixture(scope="module")
def frames():
    return render_sequence("ambulance", 16, "mission", seed=5)  # 230 KB each: four 1 MiB chunks


def _chunks(mcap_file):
    make_reader = ros.require("mcap.reader").make_reader
    with open(mcap_file, "rb") as stream:
        return make_reader(stream).get_summary().chunk_indexes


def _crc_checked_messages(mcap_file) -> int:
    make_reader = ros.require("mcap.reader").make_reader
    with open(mcap_file, "rb") as stream:
        return sum(1 for _ in make_reader(stream, validate_crcs=True).iter_messages())


def test_written_bags_carry_chunk_crcs_that_an_independent_reader_checks(tmp_path, frames):
    bag = write_image_bag(tmp_path / "bag", frames)
    mcap_file = bag / "bag.mcap"
    chunks = _chunks(mcap_file)
    assert len(chunks) >= 3
    data = mcap_file.read_bytes()
    crcs = [struct.unpack_from("<I", data, c.chunk_start_offset + ros.MCAP_CHUNK_CRC_OFFSET)[0] for c in chunks]
    assert all(crcs) and _crc_checked_messages(mcap_file) == len(frames) and ros.damaged_chunks(mcap_file) == []
    read = [f.image for f in BagSource(bag).stamped()]
    assert len(read) == len(frames) and all(np.array_equal(a, b) for a, b in zip(read, frames))


def test_a_bag_with_4_kib_zeroed_in_a_chunk_is_refused_naming_the_file_and_the_chunk(tmp_path, frames):
    bag = write_image_bag(tmp_path / "bag", frames)
    mcap_file = bag / "bag.mcap"
    second = _chunks(mcap_file)[1]
    data = bytearray(mcap_file.read_bytes())
    hole = second.chunk_start_offset + 2000  # inside the chunk's frames
    data[hole : hole + 4096] = bytes(4096)
    mcap_file.write_bytes(bytes(data))
    assert ros.damaged_chunks(mcap_file) == [
        (second.chunk_start_offset, second.message_start_time, second.message_end_time)
    ]
    with pytest.raises(
        ValueError, match=rf"could not be read: .*bag\.mcap'?: the chunk at byte {second.chunk_start_offset}"
    ):
        list(BagSource(bag))
    with pytest.raises(Exception, match="(?i)crc"):  # the mcap library refuses it as well
        _crc_checked_messages(mcap_file)


def test_a_bag_whose_stamps_run_backwards_is_refused_naming_the_frame(tmp_path, frames):
    store = ros.typestore()
    stamps = [START, START + 10**8, START + 2 * 10**8, START - 5 * 10**8, START - 4 * 10**8]  # a clock jump back
    with ros.rosbag2_writer(tmp_path / "jump") as writer:
        connection = writer.add_connection("/cam/image", ros.IMAGE, typestore=store)
        for i, stamp in enumerate(stamps):
            message = ros.image_message(store, frames[i], stamp, "cam")
            writer.write(connection, START + i * 10**8, store.serialize_cdr(message, ros.IMAGE))
    source = BagSource(tmp_path / "jump")
    with pytest.raises(
        ValueError, match=r"message 3 of topic '/cam/image' .*0\.7 s before the previous.*run backwards"
    ):
        list(source)
    assert len(list(BagSource(tmp_path / "jump", max_frames=3))) == 3  # the part before the jump reads
    assert len(list(BagSource(tmp_path / "jump", window=(0.25, None)))) == 2  # and the part after it


def test_macro_observation_bags_carry_chunk_crcs_too(tmp_path, frames):
    with MacroObservationBag(tmp_path / "out", ["ambulance", "food_crate"]) as bag:
        for i, frame in enumerate(frames[:6]):
            bag.write_frame(frame, START + i, START + i + 5)
    mcap_file = tmp_path / "out" / "out.mcap"
    data = mcap_file.read_bytes()
    chunks = _chunks(mcap_file)
    assert chunks and all(
        struct.unpack_from("<I", data, c.chunk_start_offset + ros.MCAP_CHUNK_CRC_OFFSET)[0] for c in chunks
    )
    assert _crc_checked_messages(mcap_file) == 6


def test_a_live_stream_whose_stamps_jump_back_is_warned_about_by_frame():
    """The live node's path (a robot replaying a bag with ``ros2 bag play``): not refused, but never silent."""
    from types import SimpleNamespace

    import torch

    import hbni_pyro
    from hbni_pyro.runtime import live_macro_observations

    stamps = [START + i * 10**8 for i in range(6)] + [START - 10**9 + i * 10**8 for i in range(6)]
    frames_ = [SimpleNamespace(stamp=s, received=START + i, frame_id=f"cam{i}") for i, s in enumerate(stamps)]
    outputs = torch.full((12, 2), 0.5, dtype=torch.float64)
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(2), threshold=0.99, max_frames=4)
    with pytest.warns(
        RuntimeWarning, match=r"frame 6 \(frame id 'cam6'\) is stamped .* 1\.5 s before .* run backwards"
    ):
        live = list(live_macro_observations(zip(frames_, outputs), process, ["a", "b"]))
    assert sum(o.segment.frames_used for o in live) == 12
