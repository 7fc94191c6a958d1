"""experiment=stream on ROS bags the test writes with rosbags: the same macro-observations as the same frames
in a lossless image folder, the source's stamps, the controller's decisions, and the output bag read back with
rosbags and with the mcap library's ROS 2 decoder."""

import json
import os
import re
import subprocess
import sys

import cv2
import numpy as np
import pytest
import torch
from experiment_runs import run_experiment

from classifiers.bags import BagSource, write_image_bag
from decpomdp import JointController
from experiments.schemas import build_settings, compose_config
from hbni_infra import ros
from test_stream import CLASSES, PER_CLASS, _args, saved  # noqa: F401 (saved is a fixture)

FPS = 15.0
START = 1_710_000_000 * ros.NS_PER_S
LATENCY = 4_000_000
NEXT = [[1, 2, 3], [0, 0, 0], [0, 0, 0], [0, 0, 0]]  # node 0 infers; class c sends it to node 1 + c; then back
ACTIONS = ("infer", *(f"go_{c}" for c in CLASSES))


@pytest.fixture(scope="module")
def recorded(saved, tmp_path_factory):  # noqa: F811
    root = tmp_path_factory.mktemp("stream_ros")
    bag = write_image_bag(root / "flight", saved["frames"], "/camera/image_raw", "bgr8", "mcap", FPS, START, LATENCY)
    folder = root / "frames"
    folder.mkdir()
    for i, f in enumerate(saved["frames"]):
        cv2.imwrite(str(folder / f"{i}.png"), f)  # PNG: lossless
    controller = JointController(
        torch.arange(4)[None, None], torch.tensor(NEXT)[None, None], ACTIONS, tuple(f"saw_{c}" for c in CLASSES)
    ).save(root / "controller.safetensors")
    return {"bag": bag, "folder": folder, "controller": controller}


def _records(run_dir):
    return [json.loads(line) for line in (run_dir / "macro_observations.jsonl").read_text().splitlines()]


def test_a_bag_streams_like_its_frames_and_records_a_ros_bag(tmp_path, saved, recorded, repo_root):  # noqa: F811
    mapping = ",".join(f"{c}:saw_{c}" for c in CLASSES)
    on_bag = tmp_path / "bag_run"
    proc = run_experiment(
        _args(
            saved,
            on_bag,
            f"stream.source={recorded['bag']}",
            f"stream.controller={recorded['controller']}",
            f"stream.observations={{{mapping}}}",
            "stream.annotate=[bag]",
        ),
        repo_root,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (
        f"wrote {on_bag / 'macro_observations.jsonl'}" in proc.stdout
        and str(on_bag / "macro_observations") in proc.stdout
    )
    on_folder = tmp_path / "folder_run"
    run_experiment(_args(saved, on_folder, f"stream.source={recorded['folder']}", "stream.annotate=[]"), repo_root)
    from_bag, from_folder = _records(on_bag), _records(on_folder)
    keys = ("index", "start_frame", "end_frame", "label", "label_index", "confidence", "frames_used", "timed_out")
    assert [[r[k] for k in keys] for r in from_bag] == [[r[k] for k in keys] for r in from_folder]  # exactly
    assert from_bag[-1]["end_frame"] == 3 * PER_CLASS - 1 and not (on_folder / "macro_observations").exists()

    # each macro-observation's first and last stamps are the bag's header stamps of those frames
    frames = list(BagSource(recorded["bag"]).stamped())
    for r in from_bag:
        assert r["first_stamp"] == frames[r["start_frame"]].stamp == START + round(r["start_frame"] * 1e9 / FPS)
        assert r["last_stamp"] == frames[r["end_frame"]].stamp and r["received"] == frames[r["end_frame"]].received
    # the controller's decisions: a replay of its table on the labels (none for a macro-observation cut short)
    node = 0
    for r in from_bag:
        if r["stream_ended"]:
            assert "decision" not in r
            continue
        node = NEXT[node][r["label_index"]]
        assert r["decision"]["observation"] == f"saw_{r['label']}" and r["decision"]["action"] == ACTIONS[node]
    decided = [r for r in from_bag if "decision" in r]

    metrics = json.loads((on_bag / "metrics.json").read_text())
    expected = {
        "/hbni/classification": len(from_bag),
        "/hbni/macro_observation": len(from_bag),
        "/hbni/decision": len(decided),
        "/hbni/annotated": 3 * PER_CLASS,
    }
    assert metrics["bag_topics"] == expected and metrics["decisions"] == len(decided)
    _check_with_rosbags(on_bag / "macro_observations", from_bag, decided, frames, expected)
    _check_with_mcap(on_bag / "macro_observations" / "macro_observations.mcap", from_bag, expected)


def _check_with_rosbags(bag, records, decided, frames, expected):
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == {
            "/hbni/classification": "vision_msgs/msg/Classification",
            "/hbni/macro_observation": "hbni_msgs/msg/MacroObservation",
            "/hbni/decision": "hbni_msgs/msg/MacroActionDecision",
            "/hbni/annotated": "sensor_msgs/msg/Image",
        }
        read = {}
        for connection, log_time, raw in reader.messages():
            read.setdefault(connection.topic, []).append((log_time, reader.deserialize(raw, connection.msgtype)))
    assert {t: len(v) for t, v in read.items()} == expected
    for (log_time, msg), (_, cls), r in zip(read["/hbni/macro_observation"], read["/hbni/classification"], records):
        assert log_time == r["received"] and ros.nanoseconds(msg.header.stamp) == r["last_stamp"]
        assert (msg.label, msg.confidence, msg.frames_used, msg.timed_out) == (
            r["label"],
            r["confidence"],
            r["frames_used"],
            r["timed_out"],
        )
        assert (
            ros.nanoseconds(msg.first_stamp) == r["first_stamp"] and ros.nanoseconds(msg.last_stamp) == r["last_stamp"]
        )
        scores = {h.class_id: h.score for h in cls.results}
        assert list(scores) == CLASSES and max(scores, key=scores.get) == r["label"]
        assert scores[r["label"]] == pytest.approx(r["confidence"], abs=1e-9)
        assert ros.nanoseconds(cls.header.stamp) == r["last_stamp"]
    assert [(m.observation, m.action) for _, m in read["/hbni/decision"]] == [
        (r["decision"]["observation"], r["decision"]["action"]) for r in decided
    ]
    for (log_time, img), frame in zip(read["/hbni/annotated"], frames):  # annotated: the source frame's times
        assert log_time == frame.received and ros.nanoseconds(img.header.stamp) == frame.stamp
        assert img.encoding == "bgr8" and (img.height, img.width) == frame.image.shape[:2]
    first = read["/hbni/annotated"][0][1].data.reshape(frames[0].image.shape)
    assert np.abs(first[:20].astype(int) - frames[0].image[:20]).mean() > 20  # the annotation panel is drawn


def _check_with_mcap(path, records, expected):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        decoded = [(c.topic, s.name, m.log_time, d) for s, c, m, d in reader.iter_decoded_messages()]
    assert {t: sum(1 for d in decoded if d[0] == t) for t in expected} == expected
    macro = [(log_time, d) for topic, _, log_time, d in decoded if topic == "/hbni/macro_observation"]
    for (log_time, msg), r in zip(macro, records):
        assert log_time == r["received"] and msg.label == r["label"] and msg.frames_used == r["frames_used"]
        assert msg.first_stamp.sec * ros.NS_PER_S + msg.first_stamp.nanosec == r["first_stamp"]
        assert msg.last_stamp.sec * ros.NS_PER_S + msg.last_stamp.nanosec == r["last_stamp"]


def test_a_wrong_topic_fails_naming_the_bags_image_topics(tmp_path, saved, recorded):  # noqa: F811
    from experiments.studies.stream import run

    settings = build_settings(_compose(saved, [f"stream.source={recorded['bag']}", "stream.topic=/camera/depth"]))
    with pytest.raises(
        ValueError, match=re.escape("has no topic '/camera/depth'; its image topics: ['/camera/image_raw']")
    ):
        run(settings, tmp_path)
    assert not (tmp_path / "macro_observations").exists()


def _compose(saved, extra):  # noqa: F811
    return compose_config(_args(saved, "unused")[:-2] + ["progress=false", *extra])


@pytest.mark.parametrize(
    "extra, message",
    [
        (["stream.topic=/camera/image_raw"], "stream.topic: only a ROS bag source has topics and receive times"),
        (["stream.window=[0,1]"], "stream.window: only a ROS bag source has topics and receive times"),
        (["stream.source=BAG", "stream.window=[2,1]"], "stream.window: expected [start, stop] seconds"),
        (["stream.source=BAG", "stream.window=[1]"], "stream.window: expected [start, stop] seconds"),
        (["stream.annotate=[bag]"], "stream.annotate: 'bag' puts the annotated frames into the output bag"),
        (["stream.source=BAG", "stream.bag=false", "stream.annotate=[bag]"], "stream.annotate: 'bag' puts"),
        (["stream.controller=/no/such.safetensors"], "stream.controller: no such file or directory"),
        (["stream.observations={a:b}"], "stream.observations: maps classes to a controller's observations"),
        (["stream.controller=CONTROLLER", "stream.agent=-1"], "stream.agent: expected an int >= 0"),
    ],
)
def test_bad_ros_settings_are_clear_errors(saved, recorded, extra, message):  # noqa: F811
    extra = [e.replace("BAG", str(recorded["bag"])).replace("CONTROLLER", str(recorded["controller"])) for e in extra]
    cfg = _compose(saved, extra)
    with pytest.raises(ValueError, match=re.escape(message)):
        build_settings(cfg)


def test_the_ros_page_runs_as_written(tmp_path, saved, repo_root):  # noqa: F811
    """docs/ros.md: its Python blocks run as a reader pastes them (the second after experiment=stream on the bag
    the first writes), and the message definitions it shows are the registered ones."""
    from hbni_pyro.runtime import DEFINITIONS

    page = (repo_root / "docs" / "ros.md").read_text()
    for name, text in DEFINITIONS:
        if name.startswith("hbni_msgs/"):
            assert text in page, name
    write_bag, read_output = re.findall(r"```python\n(.*?)```", page, re.S)
    env = {**os.environ, "PYTHONPATH": str(repo_root), "HBNI_PYRO_ROOT": str(tmp_path)}
    first = subprocess.run([sys.executable, "-c", write_bag], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert first.returncode == 0, first.stderr[-2000:]
    assert first.stdout.splitlines()[0] == "/camera/image_raw sensor_msgs/msg/Image 40 10.0 fps"
    assert first.stdout.splitlines()[2] == "15"
    run_dir = tmp_path / "outputs" / "stream" / "2026-01-01_00-00-00"
    run_experiment(
        _args(saved, run_dir, "stream.source=flight"), tmp_path, env=os.environ | {"HBNI_PYRO_ROOT": str(tmp_path)}
    )
    second = subprocess.run([sys.executable, "-c", read_output], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert second.returncode == 0, second.stderr[-2000:]
    records = _records(run_dir)
    lines = second.stdout.splitlines()
    assert len(lines) == 2 * len(records) and lines[0].startswith(
        f"{records[0]['label']} {records[0]['confidence']:.2f}"
    )
