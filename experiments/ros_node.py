"""A live ROS 2 node: camera images in; HBNI macro-observations and a robot controller's decisions out.

    hbni-ros-node --ros-args -p classifier:=classifier.safetensors -p posterior:=posterior.safetensors \\
        -p controller:=controller.safetensors -r camera/image_raw:=/front/image_raw -r __ns:=/robot1
    ros2 launch $(hbni-ros-node --launch-file) classifier:=... posterior:=...

It follows ROS 2's conventions: ``--ros-args`` go to ``rclpy`` (remaps, ``__ns``, ``__node``, ``-p`` parameters,
``--params-file``, ``use_sim_time``); every setting is a declared, read-only parameter with a description and a
range (:data:`PARAMETERS`), whose default is the command-line option of the same name (``--threshold 0.9``) so the
node also runs without ROS arguments. It subscribes to ``camera/image_raw`` (``sensor_msgs/msg/Image``; with
``compressed``, ``camera/image_raw/compressed``, ``CompressedImage``) with the sensor-data QoS and publishes, under
its own name (``~``: ``/hbni`` by default, ``/robot1/hbni`` in namespace ``/robot1``), the messages
``experiment=stream`` writes to its output bag (:mod:`hbni_pyro.runtime.ros_messages`): ``classification``
(``vision_msgs/msg/Classification``), ``macro_observation`` and, with a controller, ``decision`` (``hbni_msgs``),
reliable, depth 10. Every topic's QoS is settable the ROS 2 way, ``-p qos_overrides.<topic>.<subscription|publisher>
.<history|depth|reliability>:=...``. Messages carry the header stamps of the source frames; a frame's receive time is
the node's clock (``use_sim_time``: the simulation's).

The per-frame work is tested library code: :func:`stamped_frame` (a message to a
:class:`~classifiers.stamped.StampedFrame`), :func:`process_frames` (:func:`~classifiers.stamped.classify_stamped`,
:func:`~hbni_pyro.live_macro_observations`, :func:`~hbni_pyro.runtime.ros_messages.messages`) and :func:`to_rclpy`;
the frames go from the subscription's callback to a worker thread through a :class:`FrameQueue` that drops the
oldest frame when the classifier falls behind. :func:`run_node` is the ``rclpy`` glue.

Needs a ROS 2 installation (``rclpy``; ``vision_msgs``: ``apt install ros-$ROS_DISTRO-vision-msgs``) and the
``hbni_msgs`` package built in a workspace (``--write-interface-package ~/ros2_ws/src``, then ``colcon build``).
This module imports neither ``rclpy`` nor Hydra until the node starts, nor the classifier (OpenCV) until it loads
the models, so ``--help`` runs anywhere.
"""

from __future__ import annotations

import argparse
import array
import collections
import functools
import importlib
import sys
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

import hbni_pyro
from hbni_infra import ros
from hbni_pyro import live_macro_observations
from experiments.launch import EXECUTABLE, IMAGE_TOPIC, NODE_NAME, PARAMETERS
from hbni_pyro.runtime import TOPICS, check_controller, messages, typestore, write_interface_package

if TYPE_CHECKING:
    from classifiers import FrameClassifier
    from classifiers.stamped import StampedFrame
    from decpomdp import ControllerExecutor

ROS2_MISSING = (
    "the live node needs a ROS 2 installation: source /opt/ros/<distro>/setup.bash (rclpy), install vision_msgs "
    "(apt install ros-$ROS_DISTRO-vision-msgs) and build hbni_msgs in a workspace "
    "(python -m experiments.ros_node --write-interface-package ~/ros2_ws/src; colcon build; source install/setup.bash)"
)
PUBLISHED = ("classification", "macro_observation", "decision")
"""The roles of :data:`hbni_pyro.runtime.TOPICS` the node publishes, each on ``~/<role>``."""
OUTPUT_DEPTH = 10
"""Depth of the published topics' (reliable, keep-last) QoS."""
LAUNCH_FILE = Path(__file__).with_name("launch") / "hbni.launch.py"
"""The launch file shipped with the package (``hbni-ros-node --launch-file`` prints its path)."""
STOP_SECONDS = 60.0
"""How long the node waits, when stopped, for the worker to finish the frames it has queued."""


@dataclass(frozen=True)
class NodeSettings:
    """The node's settings, from the command line (:func:`parse_args`) or its declared parameters
    (:meth:`from_parameters`); :data:`PARAMETERS` says what each means."""

    classifier: Path | None
    posterior: Path | None
    controller: Path | None
    agent: int
    classes: list[str] | None
    observations: dict[str, str]
    completes: list[str]
    threshold: float
    max_frames: int
    temper: float
    mode: str
    batch: int
    queue: int
    compressed: bool

    def parameters(self) -> dict[str, Any]:
        """Parameter name -> its value as ROS holds it (paths and lists as strings)."""
        return {
            "classifier": _text(self.classifier),
            "posterior": _text(self.posterior),
            "controller": _text(self.controller),
            "agent": self.agent,
            "classes": ",".join(self.classes or []),
            "observations": ",".join(f"{c}={o}" for c, o in self.observations.items()),
            "completes": ",".join(self.completes),
            "threshold": self.threshold,
            "max_frames": self.max_frames,
            "temper": self.temper,
            "mode": self.mode,
            "batch": self.batch,
            "queue": self.queue,
            "compressed": self.compressed,
        }

    @classmethod
    def from_parameters(cls, values: dict[str, Any]) -> NodeSettings:
        """The settings from parameter values (:meth:`parameters`' form); a malformed list is a ``ValueError``."""
        return cls(
            classifier=_path(values["classifier"]),
            posterior=_path(values["posterior"]),
            controller=_path(values["controller"]),
            agent=int(values["agent"]),
            classes=_names(values["classes"]) or None,
            observations=dict(_observation(item) for item in _names(values["observations"])),
            completes=_names(values["completes"]),
            threshold=float(values["threshold"]),
            max_frames=int(values["max_frames"]),
            temper=float(values["temper"]),
            mode=str(values["mode"]),
            batch=int(values["batch"]),
            queue=int(values["queue"]),
            compressed=bool(values["compressed"]),
        )


def _text(path: Path | None) -> str:
    return "" if path is None else str(path)


def _path(text: str) -> Path | None:
    return Path(text) if str(text).strip() else None


def _names(text: str) -> list[str]:
    return [part.strip() for part in str(text).split(",") if part.strip()]


def _observation(text: str) -> tuple[str, str]:
    name, sep, observation = text.partition("=")
    if not sep or not name.strip() or not observation.strip():
        raise ValueError(f"observations: expected CLASS=OBSERVATION, got {text!r}")
    return name.strip(), observation.strip()


class Pipeline(NamedTuple):
    """What the node runs: the classifier, the macro-observation process, its class order and the controller."""

    classifier: FrameClassifier
    process: hbni_pyro.MacroObservationProcess
    classes: list[str]
    controller: ControllerExecutor | None
    observations: dict[str, str]
    completes: list[str]


def load_pipeline(settings: NodeSettings) -> Pipeline:
    """The classifier, the HBNI process and the controller's executor from the files ``settings`` names; the
    controller is checked (:func:`hbni_pyro.runtime.check_controller`) before the classifier loads."""
    from classifiers import FrameClassifier, class_columns
    from decpomdp import ControllerExecutor, JointController

    for name in ("classifier", "posterior"):
        if getattr(settings, name) is None:
            raise ValueError(f"{name}: expected a saved file (--{name} PATH, or -p {name}:=PATH after --ros-args)")
    posterior = hbni_pyro.HBNIPosterior.load(settings.posterior)
    posterior = posterior.match_names(settings.classes, "classes")
    classes = list(posterior.class_names)
    controller = None
    if settings.controller is not None:
        joint = JointController.load(settings.controller)
        controller = ControllerExecutor(joint, settings.agent, joint.action_names, joint.obs_names)
        check_controller(controller, classes, settings.observations, settings.completes)  # now, not at a frame
    clf = FrameClassifier.load(settings.classifier)
    class_columns(clf, classes, "classifier")  # its columns are read in the posterior's order
    filt = hbni_pyro.HBNIFilter(posterior, mode=settings.mode, temper=settings.temper)
    process = hbni_pyro.MacroObservationProcess(filt, threshold=settings.threshold, max_frames=settings.max_frames)
    return Pipeline(clf, process, classes, controller, dict(settings.observations), list(settings.completes))


class FrameQueue:
    """Frames from a subscription's callback to the worker: :meth:`put` never blocks, and when ``size`` frames wait
    the oldest is dropped (a robot acts on what it sees now); iterating yields frames until :meth:`close`.

    Attributes:
        dropped: frames dropped so far.
    """

    def __init__(self, size: int = 2) -> None:
        if isinstance(size, bool) or not isinstance(size, int) or size < 1:
            raise ValueError(f"size: expected an int >= 1, got {size!r}")
        self._frames: collections.deque = collections.deque(maxlen=size)
        self._ready = threading.Condition()
        self._closed = False
        self.dropped = 0

    def put(self, frame: Any) -> None:
        with self._ready:
            if len(self._frames) == self._frames.maxlen:
                self.dropped += 1
            self._frames.append(frame)
            self._ready.notify()

    def close(self) -> None:
        """End the iteration once the waiting frames are taken."""
        with self._ready:
            self._closed = True
            self._ready.notify_all()

    def __iter__(self) -> Iterator[Any]:
        while True:
            with self._ready:
                self._ready.wait_for(lambda: self._frames or self._closed)
                if not self._frames:
                    return
                frame = self._frames.popleft()
            yield frame


def stamped_frame(msg: Any, index: int, received: int) -> StampedFrame:
    """An ``Image`` or ``CompressedImage`` message (``rclpy``'s or ``rosbags``') received at ``received`` (ns): its
    image, its header stamp and frame id."""
    from classifiers.stamped import StampedFrame

    return StampedFrame(
        ros.image_from_message(msg), ros.nanoseconds(msg.header.stamp), int(received), msg.header.frame_id, index
    )


def process_frames(
    frames: Iterable[StampedFrame], pipeline: Pipeline, publish: Callable[[str, Any], None], batch: int = 1
) -> None:
    """Run the pipeline on stamped frames and ``publish(role, message)`` each macro-observation's messages
    (``rosbags`` dataclasses; roles as in :data:`hbni_pyro.runtime.ros_messages.TOPICS`), until the frames end."""
    from classifiers.stamped import classify_stamped

    store = typestore()
    items = classify_stamped(frames, pipeline.classifier, pipeline.classes, batch)
    for obs in live_macro_observations(
        items, pipeline.process, pipeline.classes, pipeline.controller, pipeline.observations, False, pipeline.completes
    ):
        for role, message in messages(obs, pipeline.classes, store).items():
            publish(role, message)


_TYPECODES = {np.dtype(np.uint8): "B", np.dtype(np.int8): "b", np.dtype(np.float64): "d", np.dtype(np.float32): "f"}


def to_rclpy(msg: Any, resolve: Callable[[str], type]) -> Any:
    """A ``rosbags`` message as an instance of ``resolve(msgtype)`` (an ``rclpy`` message class), field by field:
    nested messages converted, numeric arrays as ``array.array`` (what ``rclpy`` stores), the rest as is."""

    def convert(value: Any) -> Any:
        if hasattr(value, "__msgtype__"):
            return to_rclpy(value, resolve)
        if isinstance(value, np.ndarray):
            return array.array(_TYPECODES[value.dtype], value.tobytes())
        if isinstance(value, list):
            return [convert(v) for v in value]
        return value

    fields = {name: convert(getattr(msg, name)) for name in msg.__dataclass_fields__ if name != "__msgtype__"}
    return resolve(msg.__msgtype__)(**fields)


@functools.cache
def rclpy_class(msgtype: str) -> type:
    """The ``rclpy`` class of ``pkg/msg/Name`` (its Python package must be importable)."""
    package, _, name = msgtype.split("/")
    try:
        return getattr(importlib.import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError) as exc:
        raise ImportError(f"{msgtype} is not importable ({exc}); {ROS2_MISSING}") from exc


def _ros_module(name: str) -> Any:
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        raise ImportError(f"{name.split('.')[0]} is not importable ({exc}); {ROS2_MISSING}") from exc


def declare_parameters(node: Any, settings: NodeSettings) -> NodeSettings:
    """Declare :data:`PARAMETERS` on ``node`` (read-only, described, ranged; ``settings`` the defaults, which
    ``-p`` overrides replace) and return the settings their values give."""
    msg = _ros_module("rcl_interfaces.msg")
    kinds = {
        "string": msg.ParameterType.PARAMETER_STRING,
        "double": msg.ParameterType.PARAMETER_DOUBLE,
        "integer": msg.ParameterType.PARAMETER_INTEGER,
        "bool": msg.ParameterType.PARAMETER_BOOL,
    }
    defaults = settings.parameters()
    values = {}
    for p in PARAMETERS:
        descriptor = msg.ParameterDescriptor(name=p.name, type=kinds[p.kind], description=p.description, read_only=True)
        if p.kind == "double":
            descriptor.floating_point_range = [msg.FloatingPointRange(from_value=p.bounds[0], to_value=p.bounds[1])]
        elif p.kind == "integer":
            low, high = p.bounds
            descriptor.integer_range = [msg.IntegerRange(from_value=int(low), to_value=int(high), step=1)]
        values[p.name] = node.declare_parameter(p.name, defaults[p.name], descriptor).value
    return NodeSettings.from_parameters(values)


def run_node(settings: NodeSettings, ros_args: Sequence[str] = ()) -> None:
    """Start the node with ``ros_args`` (the command line, ``--ros-args`` included) and spin until Ctrl-C or
    shutdown; the command-line ``settings`` are the parameters' defaults."""
    rclpy = _ros_module("rclpy")
    qos = _ros_module("rclpy.qos")
    executors = _ros_module("rclpy.executors")
    overriding = _ros_module("rclpy.qos_overriding_options").QoSOverridingOptions.with_default_policies
    rclpy.init(args=[EXECUTABLE, *ros_args])
    node = rclpy.create_node(NODE_NAME)
    frames, worker = None, None
    try:
        settings = declare_parameters(node, settings)
        pipeline = load_pipeline(settings)
        frames = FrameQueue(settings.queue)
        publishers = {
            role: node.create_publisher(
                rclpy_class(TOPICS[role][1]),
                f"~/{TOPICS[role][0]}",
                qos.QoSProfile(depth=OUTPUT_DEPTH),
                qos_overriding_options=overriding(),
            )
            for role in PUBLISHED
        }
        image_type = rclpy_class(ros.COMPRESSED_IMAGE if settings.compressed else ros.IMAGE)
        counter = iter(range(1 << 62))
        clock = node.get_clock()  # ROS time: the simulation's when use_sim_time is true

        def on_image(msg: Any) -> None:
            frames.put(stamped_frame(msg, next(counter), clock.now().nanoseconds))

        def publish(role: str, message: Any) -> None:
            publishers[role].publish(to_rclpy(message, rclpy_class))

        def work() -> None:
            try:
                process_frames(frames, pipeline, publish, settings.batch)
            except Exception as exc:  # a failed worker stops the node instead of dying silently
                node.get_logger().error(f"{type(exc).__name__}: {exc}")
                rclpy.try_shutdown()

        topic = f"{IMAGE_TOPIC}/compressed" if settings.compressed else IMAGE_TOPIC
        subscription = node.create_subscription(
            image_type, topic, on_image, qos.qos_profile_sensor_data, qos_overriding_options=overriding()
        )
        worker = threading.Thread(target=work, daemon=True)
        worker.start()
        node.get_logger().info(
            f"classifying {subscription.topic_name}; publishing {', '.join(p.topic_name for p in publishers.values())}"
        )
        rclpy.spin(node)
    except (KeyboardInterrupt, executors.ExternalShutdownException):
        pass
    finally:
        if frames is not None:
            frames.close()
        if worker is not None:
            worker.join(timeout=STOP_SECONDS)
            if worker.is_alive():
                node.get_logger().warning(f"stopped with frames still queued after {STOP_SECONDS:g} s")
            node.get_logger().info(f"stopped; {frames.dropped} frames dropped while the classifier was busy")
        node.destroy_node()
        rclpy.try_shutdown()


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=EXECUTABLE,
        description=__doc__.split("\n\n")[0]
        + " Options set the parameters' defaults; --ros-args -p NAME:=VALUE overrides them.",
    )
    parser.add_argument(
        "--write-interface-package",
        type=Path,
        metavar="WORKSPACE_SRC",
        help="write the hbni_msgs package into a ROS 2 workspace's src folder and exit",
    )
    parser.add_argument("--launch-file", action="store_true", help="print the path of the launch file and exit")
    for p in PARAMETERS:
        flag = f"--{p.name.replace('_', '-')}"
        if p.kind == "bool":
            parser.add_argument(flag, action="store_true", help=p.description)
            continue
        kind = {"string": str, "double": float, "integer": int}[p.kind]
        parser.add_argument(flag, type=kind, default=p.default, help=f"{p.description} (default {p.default!r})")
    return parser


def parse_args(argv: Sequence[str] | None = None) -> NodeSettings:
    """The settings from a command line without ROS arguments (``--classes a,b`` or ``--observations c=o,...``)."""
    args = _parser().parse_args(argv)
    try:
        return NodeSettings.from_parameters({p.name: getattr(args, p.name) for p in PARAMETERS})
    except ValueError as exc:
        _parser().error(str(exc))


def main(argv: Sequence[str] | None = None) -> None:
    """The command: ``--ros-args`` are ``rclpy``'s, the rest the node's options."""
    argv = list(sys.argv[1:] if argv is None else argv)
    own = argv
    if "--ros-args" in argv:
        remove_ros_args = _ros_module("rclpy.utilities").remove_ros_args
        own = remove_ros_args(args=[EXECUTABLE, *argv])[1:]
    args = _parser().parse_args(own)
    if args.write_interface_package is not None:
        package = write_interface_package(args.write_interface_package)
        print(f"[ros_node] wrote {package}; build it with colcon build --packages-select hbni_msgs")
        return
    if args.launch_file:
        print(LAUNCH_FILE)
        return
    run_node(parse_args(own), argv)


if __name__ == "__main__":
    main()
