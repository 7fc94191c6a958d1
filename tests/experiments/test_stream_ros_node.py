"""The live ROS 2 node: it imports without rclpy (and ``--help`` runs without OpenCV) and says what to install;
rclpy-like image messages through its frame queue and per-frame code publish the same messages experiment=stream
writes to its output bag; the whole node, started with ``--ros-args``, against a stand-in for rclpy
(:mod:`rclpy_standin`); its launch file; its arguments and queue."""

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
from test_stream_ros import ACTIONS, COMPLETES, _compose, recorded  # noqa: F401 (recorded is a fixture)

import rclpy_standin
from experiments.launch import PARAMETERS


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


def _stream_written(tmp_path, saved, recorded, threshold):  # noqa: F811
    """What experiment=stream writes to its output bag for the recorded camera bag: (role, message) in order."""
    from rosbags.highlevel import AnyReader

    mapping = ",".join(f"{c}:saw_{c}" for c in CLASSES)
    cfg = _compose(
        saved,
        [
            f"stream.source={recorded['bag']}",
            f"stream.controller={recorded['controller']}",
            f"stream.observations={{{mapping}}}",
            COMPLETES,
            "stream.annotate=[]",
            "stream.batch=1",
            f"stream.threshold={threshold}",
        ],
    )
    run(build_settings(cfg), tmp_path)
    with AnyReader([tmp_path / "macro_observations"]) as reader:
        return [(c.topic.rsplit("/", 1)[1], reader.deserialize(raw, c.msgtype)) for c, _, raw in reader.messages()]


def _camera(recorded):  # noqa: F811
    """The recorded camera's messages as rclpy gives them, with their receive times (ns)."""
    from rosbags.highlevel import AnyReader

    with AnyReader([recorded["bag"]]) as reader:
        return [(_as_rclpy_image(reader.deserialize(raw, c.msgtype)), t) for c, t, raw in reader.messages()]


def _node_args(saved, recorded, *extra):  # noqa: F811
    return [
        f"--classifier={saved['classifier']}",
        f"--posterior={saved['posterior']}",
        f"--controller={recorded['controller']}",
        f"--classes={','.join(CLASSES)}",
        "--max-frames=6",
        "--temper=0.6",
        f"--observations={','.join(f'{c}=saw_{c}' for c in CLASSES)}",
        f"--completes={','.join(ACTIONS)}",
        *extra,
    ]


def _same_messages(published, written):
    assert [role for role, _ in published] == [role for role, _ in written]  # log-time order = publication order
    assert sum(role == "decision" for role, _ in published) >= 2
    for (role, ours), (_, theirs) in zip(published, written):
        assert ours.msgtype == theirs.__msgtype__ and ours.header.stamp.msgtype == "builtin_interfaces/msg/Time"
        assert ros.nanoseconds(ours.header.stamp) == ros.nanoseconds(theirs.header.stamp)  # the source frames' stamps
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


def test_the_per_frame_code_publishes_what_the_stream_writes_to_its_bag(tmp_path, saved, recorded, rclpy_messages):  # noqa: F811
    written = _stream_written(tmp_path, saved, recorded, 0.95)
    pipeline = ros_node.load_pipeline(ros_node.parse_args(_node_args(saved, recorded)))
    incoming = _camera(recorded)
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
    _same_messages(published, written)
    frames = list(BagSource(recorded["bag"]).stamped())
    first = ros_node.stamped_frame(incoming[0][0], 0, incoming[0][1])
    assert np.array_equal(first.image, frames[0].image) and first[1:] == frames[0][1:]


def test_the_node_launched_with_ros_args_against_an_rclpy_stand_in(
    tmp_path, saved, recorded, rclpy_messages, monkeypatch
):  # noqa: F811
    """``hbni-ros-node ... --ros-args -r __ns:=/robot1 -p threshold:=0.9 -p use_sim_time:=true``: rclpy gets the ROS
    arguments; the node's name and topics follow the namespace; every setting is a declared, described, read-only
    parameter, the ``-p`` values override the command line's; the camera topic has the sensor-data QoS (its depth
    overridden the ROS 2 way), the outputs are reliable; the frames' receive times are the simulation's clock;
    and it publishes what experiment=stream writes at that threshold."""
    written = _stream_written(tmp_path, saved, recorded, 0.9)
    world = rclpy_standin.install(monkeypatch)
    incoming = _camera(recorded)
    sim_start = 5_000_000_000
    world.script = [
        ("/robot1/camera/image_raw", msg, sim_start + 10_000_000 * i) for i, (msg, _) in enumerate(incoming)
    ]
    received = []
    stamp = ros_node.stamped_frame
    monkeypatch.setattr(ros_node, "stamped_frame", lambda m, i, t: received.append(t) or stamp(m, i, t))
    ros_args = [
        "--ros-args",
        "-r",
        "__ns:=/robot1",
        "-p",
        "threshold:=0.9",
        "-p",
        "use_sim_time:=true",
        "-p",
        "qos_overrides./robot1/camera/image_raw.subscription.depth:=7",
    ]
    argv = _node_args(saved, recorded, "--queue=64", "--threshold=0.5", *ros_args)
    ros_node.main(argv)

    assert world.inits == [["hbni-ros-node", *argv]]  # rclpy parses the ROS arguments itself
    (node,) = world.nodes
    assert node.get_fully_qualified_name() == "/robot1/hbni" and node.destroyed
    declared = {name: p.value for name, p in node.parameters.items()}
    assert [n for n in declared if not n.startswith("qos_overrides.")] == [
        "use_sim_time",
        *(p.name for p in PARAMETERS),
    ]
    assert declared["threshold"] == 0.9 and declared["use_sim_time"] is True  # -p beats --threshold=0.5
    assert declared["max_frames"] == 6 and declared["completes"] == ",".join(ACTIONS)  # the command line's
    for p in PARAMETERS:
        descriptor = node.descriptors[p.name]
        assert descriptor.read_only and descriptor.description == p.description
        if p.kind == "double":
            (span,) = descriptor.floating_point_range
            assert (span.from_value, span.to_value) == p.bounds
        if p.kind == "integer":
            (span,) = descriptor.integer_range
            assert (span.from_value, span.to_value, span.step) == (*p.bounds, 1)
    (sub,) = node.subscriptions
    assert sub.topic_name == "/robot1/camera/image_raw" and sub.msg_type.msgtype == "sensor_msgs/msg/Image"
    qos = rclpy_standin
    assert (sub.qos_profile.reliability, sub.qos_profile.history, sub.qos_profile.depth) == (
        qos.ReliabilityPolicy.BEST_EFFORT,
        qos.HistoryPolicy.KEEP_LAST,
        7,
    )
    topics = {pub.topic_name.rsplit("/", 1)[1]: pub for pub in node.publishers}
    assert {pub.topic_name for pub in node.publishers} == {f"/robot1/hbni/{role}" for role in ros_node.PUBLISHED}
    assert all(p.qos_profile.reliability == qos.ReliabilityPolicy.RELIABLE for p in node.publishers)
    assert received == [t for _, _, t in world.script]  # the node's clock: simulation time
    published = sorted(
        ((pub_role, i, msg) for pub_role, pub in topics.items() for i, msg in enumerate(pub.messages)),
        key=lambda x: (ros.nanoseconds(x[2].header.stamp), ros_node.PUBLISHED.index(x[0])),
    )
    _same_messages([(role, msg) for role, _, msg in published], written)
    assert not [m for level, m in node.logger.records if level == "error"]
    logged = [message for _, message in node.logger.records]
    assert any("classifying /robot1/camera/image_raw; publishing /robot1/hbni/classification" in m for m in logged)
    assert any("0 frames dropped" in m for m in logged)


@pytest.mark.parametrize(
    "override, error",
    [
        ("threshold:=1.5", "InvalidParameterValueException"),
        ("max_frames:=2.5", "InvalidParameterTypeException"),
        ("observations:=ambulance", "ValueError"),
    ],
)
def test_bad_parameters_stop_the_node_before_it_subscribes(
    saved, recorded, rclpy_messages, monkeypatch, override, error
):  # noqa: F811
    world = rclpy_standin.install(monkeypatch)
    with pytest.raises(Exception) as raised:
        ros_node.main(_node_args(saved, recorded, "--ros-args", "-p", override))
    assert type(raised.value).__name__ == error
    (node,) = world.nodes
    assert not node.subscriptions and node.destroyed and not rclpy_standin.ok()


def test_the_launch_file_declares_every_parameter_and_runs_the_node_executable(monkeypatch, repo_root):
    """The shipped launch file, read as ``ros2 launch`` reads it (by path), against stand-ins of ``launch`` and
    ``launch_ros``: a launch argument per parameter with the node's default, the node's console script as the
    ``Node`` action's executable, its parameters, namespace and image remaps."""
    import importlib.util
    import tomllib

    made = {}

    def recorder(kind):
        def make(*args, **kwargs):
            made.setdefault(kind, []).append((args, kwargs))
            return SimpleNamespace(kind=kind, args=args, kwargs=kwargs)

        return make

    for name, attrs in {
        "launch": {"LaunchDescription": recorder("LaunchDescription")},
        "launch.actions": {"DeclareLaunchArgument": recorder("DeclareLaunchArgument")},
        "launch.substitutions": {"LaunchConfiguration": lambda name: ("config", name)},
        "launch_ros": {},
        "launch_ros.actions": {"Node": recorder("Node")},
        "launch_ros.parameter_descriptions": {"ParameterValue": lambda value, value_type=None: (value, value_type)},
    }.items():
        module = types.ModuleType(name)
        module.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, module)
    path = ros_node.LAUNCH_FILE
    assert path.is_file() and path.parent.joinpath("__init__.py").is_file()  # inside a package: in the wheel
    spec = importlib.util.spec_from_file_location("hbni_launch", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    (node,) = made["Node"]
    kwargs = node[1]
    scripts = tomllib.loads((repo_root / "pyproject.toml").read_text())["project"]["scripts"]
    assert kwargs["executable"] == "hbni-ros-node" and scripts["hbni-ros-node"] == "experiments.ros_node:main"
    assert kwargs["name"] == "hbni" and kwargs["namespace"] == ("config", "namespace")
    (values,) = kwargs["parameters"]
    types_ = {"string": str, "double": float, "integer": int, "bool": bool}
    assert values == {
        **{p.name: (("config", p.name), types_[p.kind]) for p in PARAMETERS},
        "use_sim_time": (("config", "use_sim_time"), bool),
    }
    assert kwargs["remappings"][0] == ("camera/image_raw", ("config", "image"))
    arguments = {a[0][0]: a[1]["default_value"] for a in made["DeclareLaunchArgument"]}
    assert arguments == {
        **{p.name: str(p.default).lower() if p.kind == "bool" else str(p.default) for p in PARAMETERS},
        "namespace": "",
        "image": "camera/image_raw",
        "use_sim_time": "false",
    }
    assert description.args[0][-1].kwargs is kwargs and len(description.args[0]) == len(arguments) + 1
    out = subprocess.run(
        [sys.executable, "-m", "experiments.ros_node", "--launch-file"], cwd=repo_root, capture_output=True, text=True
    )
    assert out.stdout.strip() == str(path)


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
    with pytest.raises(ImportError, match="rclpy is not importable .*the live node needs a ROS 2 installation"):
        ros_node.main(["--ros-args", "-r", "__ns:=/robot1"])
    blocked = (
        "import importlib.abc, sys\n"
        "class Blocker(importlib.abc.MetaPathFinder):\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] in ('cv2', 'rclpy', 'hydra', 'omegaconf'):\n"
        "            raise ImportError(f'{name} is blocked')\n"
        "sys.meta_path.insert(0, Blocker())\n"
        "sys.argv = ['hbni-ros-node', '--help']\n"
        "import runpy; runpy.run_module('experiments.ros_node', run_name='__main__')\n"
    )
    helped = subprocess.run([sys.executable, "-c", blocked], cwd=repo_root, capture_output=True, text=True)
    assert helped.returncode == 0 and "--ros-args -p NAME:=VALUE" in " ".join(helped.stdout.split()), helped.stderr
    assert all(f"--{p.name.replace('_', '-')}" in helped.stdout for p in PARAMETERS)
    ros_node.main(["--write-interface-package", str(tmp_path / "src")])
    assert (tmp_path / "src" / "hbni_msgs" / "msg" / "MacroObservation.msg").is_file()
    with pytest.raises(ImportError, match="no_such_msgs/msg/Thing is not importable"):
        ros_node.rclpy_class("no_such_msgs/msg/Thing")


def test_bad_node_arguments(saved, recorded, capsys):  # noqa: F811
    with pytest.raises(ValueError, match=r"posterior: expected a saved file \(--posterior PATH, or -p posterior:=PATH"):
        ros_node.load_pipeline(ros_node.parse_args(["--classifier", "c.safetensors"]))
    with pytest.raises(SystemExit):
        ros_node.parse_args(["--classifier", "c", "--posterior", "p", "--observations", "ambulance"])
    assert "observations: expected CLASS=OBSERVATION, got 'ambulance'" in capsys.readouterr().err
    files = [
        f"--{name}={path}" for name, path in (("classifier", saved["classifier"]), ("posterior", saved["posterior"]))
    ]
    files.append(f"--controller={recorded['controller']}")
    args = ros_node.parse_args([*files, f"--completes={','.join(ACTIONS)}"])
    with pytest.raises(ValueError, match="observations: the classes .* its observations are \\['saw_police_car'"):
        ros_node.load_pipeline(args)  # the controller's observations are not the class names: refused at load
    mission_like = ros_node.parse_args([*files, f"--observations={','.join(f'{c}=saw_{c}' for c in CLASSES)}"])
    with pytest.raises(ValueError, match="completes: robot 0's controller picks 'track_"):
        ros_node.load_pipeline(mission_like)  # completes=infer: the controller's track_* MAs are refused


def test_the_node_module_imports_no_hydra():
    import ast

    tree = ast.parse(open(ros_node.__file__).read())
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert not {n for n in names if n.split(".")[0] in ("hydra", "omegaconf", "rclpy", "matplotlib")}
    assert {n for n in names if n.startswith("experiments")} == {"experiments.launch"}  # which imports nothing
    launch = ast.parse(open(ros_node.LAUNCH_FILE.with_name("__init__.py")).read())
    assert {a.name for n in ast.walk(launch) if isinstance(n, ast.Import) for a in n.names} == set()
    assert {n.module for n in ast.walk(launch) if isinstance(n, ast.ImportFrom)} == {
        "__future__",
        "dataclasses",
        "typing",
    }
