"""Macro-observations as ROS 2 messages and the MCAP bag that records them, read back with rosbags and,
independently, with the mcap library's ROS 2 decoder; the hbni_msgs interface package."""

import xml.etree.ElementTree as ET

import numpy as np
import pytest
import torch
import yaml

from hbni_pyro import LiveMacroObservation, Segment
from hbni_pyro.runtime import (
    DEFINITIONS,
    TOPICS,
    Decision,
    MacroObservationBag,
    messages,
    topic_names,
    typestore,
    write_interface_package,
)
from hbni_infra import ros

CLASSES = ["ambulance", "food_crate", "police_car"]
T0 = 1_700_000_000_000_000_000


def _obs(index, label, frames_used, timed_out=False, decision=True):
    start = 3 * index
    running = torch.full((frames_used, 3), 0.1, dtype=torch.float64)
    running[:, label] = 0.8
    seg = Segment(
        index,
        start,
        start + frames_used - 1,
        label,
        CLASSES[label],
        0.8,
        frames_used,
        timed_out,
        False,
        torch.zeros(frames_used, 3),
        [],
    )
    first, last = T0 + start * 10**8 + 11, T0 + (start + frames_used - 1) * 10**8 + 11
    made = Decision(0, "infer", f"saw_{CLASSES[label]}", label + 1, f"go_{label}", label + 1) if decision else None
    return LiveMacroObservation(seg, running, first, last, last + 5_000_000, "cam_optical", made)


OBSERVATIONS = [_obs(0, 2, 3), _obs(1, 0, 2, timed_out=True), _obs(2, 1, 4, decision=False)]


def _write(path, frames=2):
    with MacroObservationBag(path, CLASSES) as bag:
        for obs in OBSERVATIONS:
            bag.write(obs)
        for k in range(frames):
            bag.write_frame(np.full((4, 6, 3), k, np.uint8), T0 + k, T0 + k + 1, "cam_optical")
    return bag


def test_the_bag_reads_back_with_rosbags(tmp_path):
    from rosbags.highlevel import AnyReader

    bag = _write(tmp_path / "out")
    assert bag.counts == {"classification": 3, "macro_observation": 3, "decision": 2, "annotated": 2}
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["metadata.yaml", "out.mcap"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no staging directory left
    meta = yaml.safe_load((tmp_path / "out" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["storage_identifier"] == "mcap"
    counts = {
        t["topic_metadata"]["name"]: (t["topic_metadata"]["type"], t["message_count"])
        for t in meta["topics_with_message_count"]
    }
    assert counts == {
        "/hbni/classification": ("vision_msgs/msg/Classification", 3),
        "/hbni/macro_observation": ("hbni_msgs/msg/MacroObservation", 3),
        "/hbni/decision": ("hbni_msgs/msg/MacroActionDecision", 2),
        "/hbni/annotated": ("sensor_msgs/msg/Image", 2),
    }
    with AnyReader([tmp_path / "out"]) as reader:  # the types come from the bag itself
        read = {}
        for connection, log_time, raw in reader.messages():
            read.setdefault(connection.topic, []).append((log_time, reader.deserialize(raw, connection.msgtype)))
    for k, (log_time, msg) in enumerate(read["/hbni/classification"]):
        obs = OBSERVATIONS[k]
        assert log_time == obs.received and ros.nanoseconds(msg.header.stamp) == obs.last_stamp
        assert msg.header.frame_id == "cam_optical"
        assert [(h.class_id, h.score) for h in msg.results] == list(zip(CLASSES, obs.posterior.tolist()))
    for k, (log_time, msg) in enumerate(read["/hbni/macro_observation"]):
        obs, seg = OBSERVATIONS[k], OBSERVATIONS[k].segment
        assert log_time == obs.received
        assert (msg.index, msg.label, msg.label_index, msg.confidence, msg.frames_used, msg.timed_out) == (
            seg.index,
            seg.name,
            seg.label,
            seg.confidence,
            seg.frames_used,
            seg.timed_out,
        )
        assert ros.nanoseconds(msg.first_stamp) == obs.first_stamp and ros.nanoseconds(msg.last_stamp) == obs.last_stamp
        assert list(msg.class_names) == CLASSES and np.array_equal(msg.posterior, obs.posterior.numpy())
    decisions = [
        (m.macro_observation, m.completed, m.observation, m.action, m.action_index, m.node)
        for _, m in read["/hbni/decision"]
    ]
    assert decisions == [(0, "infer", "saw_police_car", "go_2", 3, 3), (1, "infer", "saw_ambulance", "go_0", 1, 1)]
    images = [
        (t, ros.nanoseconds(m.header.stamp), m.encoding, m.data.reshape(4, 6, 3)) for t, m in read["/hbni/annotated"]
    ]
    assert [(t, s, e) for t, s, e, _ in images] == [(T0 + 1, T0, "bgr8"), (T0 + 2, T0 + 1, "bgr8")]
    assert (images[1][3] == 1).all()


def test_the_bag_reads_back_with_the_mcap_ros2_decoder(tmp_path):
    """The mcap library's own reader and ROS 2 decoder: nothing of rosbags on this side."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    _write(tmp_path / "out")
    with open(tmp_path / "out" / "out.mcap", "rb") as fh:  # with its chunk CRCs checked
        reader = make_reader(fh, decoder_factories=[DecoderFactory()], validate_crcs=True)
        rows = [
            (ch.topic, schema.name, schema.encoding, m.log_time, d)
            for schema, ch, m, d in reader.iter_decoded_messages()
        ]
    by_topic = {}
    for topic, name, encoding, log_time, decoded in rows:
        assert encoding == "ros2msg" and name == dict((f"/hbni/{n}", t) for n, t in TOPICS.values())[topic]
        by_topic.setdefault(topic, []).append((log_time, decoded))
    assert {t: len(v) for t, v in by_topic.items()} == {
        "/hbni/classification": 3,
        "/hbni/macro_observation": 3,
        "/hbni/decision": 2,
        "/hbni/annotated": 2,
    }
    for (log_time, msg), obs in zip(by_topic["/hbni/macro_observation"], OBSERVATIONS):
        assert log_time == obs.received and msg.label == obs.segment.name and msg.frames_used == obs.segment.frames_used
        assert msg.first_stamp.sec * ros.NS_PER_S + msg.first_stamp.nanosec == obs.first_stamp
        assert msg.header.stamp.sec * ros.NS_PER_S + msg.header.stamp.nanosec == obs.last_stamp
        assert msg.timed_out == obs.segment.timed_out and list(msg.posterior) == obs.posterior.tolist()
    for (_, msg), obs in zip(by_topic["/hbni/classification"], OBSERVATIONS):
        assert [(h.class_id, h.score) for h in msg.results] == list(zip(CLASSES, obs.posterior.tolist()))
    assert [m.action for _, m in by_topic["/hbni/decision"]] == ["go_2", "go_0"]


def test_messages_namespaces_and_errors(tmp_path):
    out = messages(OBSERVATIONS[2], CLASSES)
    assert set(out) == {"classification", "macro_observation"}  # no decision without one
    assert out["macro_observation"].__msgtype__ == "hbni_msgs/msg/MacroObservation"
    assert topic_names("/robot1/hbni")["decision"] == "/robot1/hbni/decision"
    assert topic_names("/")["classification"] == "/classification"
    for bad in ("hbni", "/hbni/", 3):
        with pytest.raises(ValueError, match="namespace: expected an absolute ROS name"):
            topic_names(bad)
    with pytest.raises(ValueError, match=r"classes: expected 3 names \(the posterior's width\)"):
        messages(OBSERVATIONS[0], CLASSES[:2])
    with pytest.raises(RuntimeError), MacroObservationBag(tmp_path / "broken", CLASSES) as bag:
        bag.write(OBSERVATIONS[0])
        raise RuntimeError("the stream failed")
    assert list(tmp_path.iterdir()) == []  # an aborted bag leaves nothing
    _write(tmp_path / "once", frames=0)
    with pytest.raises(FileExistsError):
        MacroObservationBag(tmp_path / "once", CLASSES)


def test_the_interface_package_matches_the_registered_types(tmp_path):
    from rosbags.typesys import get_types_from_msg

    package = write_interface_package(tmp_path / "src")
    assert sorted(p.name for p in (package / "msg").iterdir()) == ["MacroActionDecision.msg", "MacroObservation.msg"]
    store = typestore()
    for path in (package / "msg").iterdir():
        name = f"hbni_msgs/msg/{path.stem}"
        assert get_types_from_msg(path.read_text(), name)[name] == store.fielddefs[name]
        assert dict(DEFINITIONS)[name] == path.read_text()
    root = ET.parse(package / "package.xml").getroot()
    assert root.find("name").text == "hbni_msgs" and root.find("member_of_group").text == "rosidl_interface_packages"
    cmake = (package / "CMakeLists.txt").read_text()
    assert '"msg/MacroObservation.msg"' in cmake and '"msg/MacroActionDecision.msg"' in cmake
    with pytest.raises(FileExistsError):
        write_interface_package(tmp_path / "src")


def test_vision_msgs_definitions_have_the_released_fields():
    """vision_msgs 4 (ROS 2 Humble and later): Classification is a header and a sequence of ObjectHypothesis, each a
    string class_id and a float64 score; same fields, types and names, so the same type hash."""
    store = typestore()
    header, results = store.fielddefs["vision_msgs/msg/Classification"][1]
    assert header == ("header", (header[1][0], "std_msgs/msg/Header"))
    assert results[0] == "results" and results[1][1][0][1] == "vision_msgs/msg/ObjectHypothesis"
    class_id, score = store.fielddefs["vision_msgs/msg/ObjectHypothesis"][1]
    assert (class_id[0], class_id[1][1][0], score[0], score[1][1][0]) == ("class_id", "string", "score", "float64")
