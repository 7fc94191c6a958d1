"""The live ROS 2 node's tested parts: it imports without rclpy and says what to install; rclpy-like image
messages through its frame queue and per-frame code publish the same messages experiment=stream writes to its
output bag; its arguments and queue."""

import array
import subprocess
import sys
import threading
import types
from types import SimpleNamespace

import numpy as np
import pytest

from classifiers.bags import BagSource
from experiments import ros_node
from experiments.schemas import build_settings
from experiments.studies.stream import run
from hbni_infra import ros
from hbni_pyro.runtime import typestore
from test_stream import CLASSES, saved  # noqa: F401 (saved is a fixture)
from test_stream_ros import _compose, recorded  # noqa: F401 (recorded is a fixture)


@pytest.fixture
def rclpy_messages(monkeypatch):
    """Stand-ins for the ROS 2 message packages (std_msgs.msg, vision_msgs.msg, hbni_msgs.msg, ...) as rclpy
    generates them: a class per type, built with keywords, which refuses a field its type does not have."""
    store = typestore()
    modules = {}
    for msgtype, (_, fields) in store.fielddefs.items():
        package, _, name = msgtype.split("/")
        names = [field for field, _ in fields]

        def init(self, _names=names, _type=msgtype, **kw):
            assert set(kw) <= set(_names), (_type, sorted(set(kw) - set(_names)))
            self.__dict__.update(kw)

        module = modules.setdefault(package, types.ModuleType(f"{package}.msg"))
        setattr(module, name, type(name, (), {"__init__": init, "msgtype": msgtype}))
    for package, module in modules.items():
        monkeypatch.setitem(sys.modules, f"{package}.msg", module)
        monkeypatch.setitem(sys.modules, package, types.ModuleType(package))
    ros_node.rclpy_class.cache_clear()
    yield
    ros_node.rclpy_class.cache_clear()


def _as_rclpy_image(msg):
    """An rclpy-like Image: its data an array.array, as rclpy gives it."""
    stamp = SimpleNamespace(sec=msg.header.stamp.sec, nanosec=msg.header.stamp.nanosec)
    return SimpleNamespace(
        header=SimpleNamespace(stamp=stamp, frame_id=msg.header.frame_id),
        height=msg.height,
        width=msg.width,
        encoding=msg.encoding,
        is_bigendian=msg.is_bigendian,
        step=msg.step,
        data=array.array("B", msg.data.tobytes()),
    )


def test_the_node_publishes_what_the_stream_writes_to_its_bag(tmp_path, saved, recorded, rclpy_messages):  # noqa: F811
    from rosbags.highlevel import AnyReader

    mapping = ",".join(f"{c}:saw_{c}" for c in CLASSES)
    cfg = _compose(
        saved,
        [
            f"stream.source={recorded['bag']}",
            f"stream.controller={recorded['controller']}",
            f"stream.observations={{{mapping}}}",
            "stream.annotate=[]",
            "stream.batch=1",
        ],
    )
    run(build_settings(cfg), tmp_path)
    with AnyReader([tmp_path / "macro_observations"]) as reader:
        written = [(c.topic.rsplit("/", 1)[1], reader.deserialize(raw, c.msgtype)) for c, _, raw in reader.messages()]

    args = ros_node.parse_args(
        [
            f"--classifier={saved['classifier']}",
            f"--posterior={saved['posterior']}",
            f"--controller={recorded['controller']}",
            f"--classes={','.join(CLASSES)}",
            "--max-frames=6",
            "--temper=0.6",
            *(f"--observation={c}=saw_{c}" for c in CLASSES),
        ]
    )
    pipeline = ros_node.load_pipeline(args)
    with AnyReader([recorded["bag"]]) as reader:  # the camera's messages, received as rclpy would give them
        incoming = [(_as_rclpy_image(reader.deserialize(raw, c.msgtype)), t) for c, t, raw in reader.messages()]
    queue = ros_node.FrameQueue(size=len(incoming))  # large enough: nothing dropped
    producer = threading.Thread(
        target=lambda: (
            [queue.put(ros_node.stamped_frame(m, i, t)) for i, (m, t) in enumerate(incoming)] and queue.close()
        )
    )
    published = []
    producer.start()
    ros_node.process_frames(
        queue, pipeline, lambda role, msg: published.append((role, ros_node.to_rclpy(msg, ros_node.rclpy_class)))
    )
    producer.join()
    assert queue.dropped == 0
    assert [role for role, _ in published] == [role for role, _ in written]  # log-time order = publication order
    assert sum(role == "decision" for role, _ in published) >= 2
    for (role, ours), (_, theirs) in zip(published, written):
        assert ours.msgtype == theirs.__msgtype__ and ours.header.stamp.msgtype == "builtin_interfaces/msg/Time"
        assert ros.nanoseconds(ours.header.stamp) == ros.nanoseconds(theirs.header.stamp)
        if role == "classification":
            assert [(h.class_id, h.score) for h in ours.results] == [(h.class_id, h.score) for h in theirs.results]
            assert {h.msgtype for h in ours.results} == {"vision_msgs/msg/ObjectHypothesis"}
        elif role == "macro_observation":
            assert (ours.label, ours.frames_used, ours.timed_out) == (
                theirs.label,
                theirs.frames_used,
                theirs.timed_out,
            )
            assert ours.confidence == pytest.approx(theirs.confidence, rel=1e-9)
            assert isinstance(ours.posterior, array.array) and ours.posterior.typecode == "d"
            assert np.allclose(np.frombuffer(ours.posterior, np.float64), theirs.posterior, rtol=1e-9)
        else:
            assert (ours.observation, ours.action, ours.node) == (theirs.observation, theirs.action, theirs.node)
    frames = list(BagSource(recorded["bag"]).stamped())
    first = ros_node.stamped_frame(incoming[0][0], 0, incoming[0][1])
    assert np.array_equal(first.image, frames[0].image) and first[1:] == frames[0][1:]


def test_the_frame_queue_drops_the_oldest_frames_when_the_worker_falls_behind():
    queue = ros_node.FrameQueue(size=2)
    for i in range(5):
        queue.put(i)
    queue.close()
    assert list(queue) == [3, 4] and queue.dropped == 3
    with pytest.raises(ValueError, match="size: expected an int >= 1"):
        ros_node.FrameQueue(size=0)
    waiting = ros_node.FrameQueue()
    got = []
    consumer = threading.Thread(target=lambda: got.extend(waiting))
    consumer.start()  # blocks until frames come
    waiting.put("a")
    waiting.close()
    consumer.join(timeout=10)
    assert got == ["a"] and not consumer.is_alive()


def test_without_ros2_the_node_says_what_to_install(tmp_path, saved, recorded, repo_root):  # noqa: F811
    code = (
        "import sys\n"
        "import experiments.ros_node as node\n"
        "assert 'rclpy' not in sys.modules\n"
        f"node.main(['--classifier', {str(saved['classifier'])!r}, '--posterior', {str(saved['posterior'])!r}])\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=repo_root, capture_output=True, text=True)
    assert proc.returncode != 0 and "ImportError: rclpy is not importable" in proc.stderr
    assert "source /opt/ros/<distro>/setup.bash" in proc.stderr and "colcon build" in proc.stderr
    ros_node.main(["--write-interface-package", str(tmp_path / "src")])
    assert (tmp_path / "src" / "hbni_msgs" / "msg" / "MacroObservation.msg").is_file()
    with pytest.raises(ImportError, match="no_such_msgs/msg/Thing is not importable"):
        ros_node.rclpy_class("no_such_msgs/msg/Thing")


def test_bad_node_arguments(saved, recorded, capsys):  # noqa: F811
    with pytest.raises(SystemExit):
        ros_node.parse_args(["--classifier", "c.safetensors"])
    assert "--classifier and --posterior are required" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        ros_node.parse_args(["--classifier", "c", "--posterior", "p", "--observation", "ambulance"])
    assert "expected CLASS=OBSERVATION, got 'ambulance'" in capsys.readouterr().err
    args = ros_node.parse_args(
        [
            f"--classifier={saved['classifier']}",
            f"--posterior={saved['posterior']}",
            f"--controller={recorded['controller']}",
        ]
    )
    with pytest.raises(ValueError, match="observations: the classes .* its observations are \\['saw_police_car'"):
        ros_node.load_pipeline(args)  # the controller's observations are not the class names: refused at load


def test_the_node_module_imports_no_hydra():
    import ast

    tree = ast.parse(open(ros_node.__file__).read())
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert not {n for n in names if n.split(".")[0] in ("hydra", "omegaconf", "rclpy", "matplotlib")}
    assert not {n for n in names if n.startswith("experiments")}
