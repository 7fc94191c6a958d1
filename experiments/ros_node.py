"""A live ROS 2 node: camera images in; HBNI macro-observations and a robot controller's decisions out.

    python -m experiments.ros_node --classifier classifier.safetensors --posterior posterior.safetensors \\
        --controller controller.safetensors --topic /camera/image_raw

It subscribes to an image topic (``sensor_msgs/msg/Image``, or ``CompressedImage`` with ``--compressed``) and
publishes, under ``--namespace`` (``/hbni``), the messages ``experiment=stream`` writes to its output bag
(:mod:`hbni_pyro.runtime.ros_messages`): ``classification`` (``vision_msgs/msg/Classification``), ``macro_observation`` and,
with a controller, ``decision`` (``hbni_msgs``). It loads the same three files as the README's robot loop.

The per-frame work is the tested library code: :func:`stamped_frame` (a message to a
:class:`~classifiers.stamped.StampedFrame`), :func:`process_frames` (:func:`~classifiers.stamped.classify_stamped`,
:func:`~hbni_pyro.live_macro_observations`, :func:`~hbni_pyro.runtime.ros_messages.messages`) and :func:`to_rclpy`; the
frames go from the subscription's callback to a worker thread through a :class:`FrameQueue` that drops the
oldest frame when the classifier falls behind. Only :func:`run_node`, the ``rclpy`` glue, is not exercised by
the test suite (no ROS 2 on the machines it runs on).

Needs a ROS 2 installation (``rclpy``; ``vision_msgs``: ``apt install ros-$ROS_DISTRO-vision-msgs``) and the
``hbni_msgs`` package built in a workspace (``--write-interface-package ~/ros2_ws/src``, then ``colcon build``).
This module imports neither ``rclpy`` nor Hydra until the node starts.
"""

from __future__ import annotations

import argparse
import array
import collections
import functools
import importlib
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

import hbni_pyro
from classifiers import FrameClassifier, class_columns
from classifiers.stamped import StampedFrame, classify_stamped
from decpomdp import ControllerExecutor, JointController
from hbni_infra import ros
from hbni_pyro import live_macro_observations
from hbni_pyro.runtime import TOPICS, messages, observation_names, topic_names, typestore, write_interface_package

ROS2_MISSING = (
    "the live node needs a ROS 2 installation: source /opt/ros/<distro>/setup.bash (rclpy), install vision_msgs "
    "(apt install ros-$ROS_DISTRO-vision-msgs) and build hbni_msgs in a workspace "
    "(python -m experiments.ros_node --write-interface-package ~/ros2_ws/src; colcon build; source install/setup.bash)"
)


class Pipeline(NamedTuple):
    """What the node runs: the classifier, the macro-observation process, its class order and the controller."""

    classifier: FrameClassifier
    process: hbni_pyro.MacroObservationProcess
    classes: list[str]
    controller: ControllerExecutor | None
    observations: dict[str, str]


def load_pipeline(args: argparse.Namespace) -> Pipeline:
    """The classifier, the HBNI process and the controller's executor from the files ``args`` names."""
    clf = FrameClassifier.load(args.classifier)
    posterior = hbni_pyro.HBNIPosterior.load(args.posterior)
    posterior = posterior.match_names(args.classes or None, "--classes")
    classes = list(posterior.class_names)
    class_columns(clf, classes, "--classifier")  # its columns are read in the posterior's order
    filt = hbni_pyro.HBNIFilter(posterior, mode=args.mode, temper=args.temper)
    process = hbni_pyro.MacroObservationProcess(filt, threshold=args.threshold, max_frames=args.max_frames)
    controller, observations = None, dict(args.observation or [])
    if args.controller is not None:
        joint = JointController.load(args.controller)
        controller = ControllerExecutor(joint, args.agent, joint.action_names, joint.obs_names)
        observation_names(classes, controller.obs_names, observations)  # refused now, not at the first frame
    return Pipeline(clf, process, classes, controller, observations)


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
    """An ``Image`` or ``CompressedImage`` message (``rclpy``'s or ``rosbags``') received at ``received`` (ns)."""
    return StampedFrame(
        ros.image_from_message(msg), ros.nanoseconds(msg.header.stamp), int(received), msg.header.frame_id, index
    )


def process_frames(
    frames: Iterable[StampedFrame], pipeline: Pipeline, publish: Callable[[str, Any], None], batch: int = 1
) -> None:
    """Run the pipeline on stamped frames and ``publish(role, message)`` each macro-observation's messages
    (``rosbags`` dataclasses; roles as in :data:`hbni_pyro.runtime.ros_messages.TOPICS`), until the frames end."""
    store = typestore()
    items = classify_stamped(frames, pipeline.classifier, pipeline.classes, batch)
    for obs in live_macro_observations(
        items, pipeline.process, pipeline.classes, pipeline.controller, pipeline.observations
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


def run_node(args: argparse.Namespace) -> None:  # the rclpy glue: not exercised by the test suite
    """Start the node and spin until Ctrl-C."""
    try:
        rclpy = importlib.import_module("rclpy")
        qos = importlib.import_module("rclpy.qos")
        executors = importlib.import_module("rclpy.executors")
    except ImportError as exc:
        raise ImportError(f"rclpy is not importable ({exc}); {ROS2_MISSING}") from exc
    pipeline = load_pipeline(args)
    names = topic_names(args.namespace)
    image_type = rclpy_class(ros.COMPRESSED_IMAGE if args.compressed else ros.IMAGE)
    rclpy.init()
    node = rclpy.create_node(args.name)
    publishers = {role: node.create_publisher(rclpy_class(t), names[role], 10) for role, (_, t) in TOPICS.items()}
    frames = FrameQueue(args.queue)
    counter = iter(range(1 << 62))

    def on_image(msg: Any) -> None:
        frames.put(stamped_frame(msg, next(counter), node.get_clock().now().nanoseconds))

    def publish(role: str, message: Any) -> None:
        publishers[role].publish(to_rclpy(message, rclpy_class))

    def work() -> None:
        try:
            process_frames(frames, pipeline, publish, args.batch)
        except Exception as exc:  # a failed worker stops the node instead of dying silently
            node.get_logger().error(f"{type(exc).__name__}: {exc}")
            rclpy.try_shutdown()

    node.create_subscription(image_type, args.topic, on_image, qos.qos_profile_sensor_data)
    worker = threading.Thread(target=work, daemon=True)
    worker.start()
    node.get_logger().info(f"classifying {args.topic}; publishing under {args.namespace}")
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, executors.ExternalShutdownException):
        pass
    finally:
        frames.close()
        worker.join(timeout=5.0)
        node.get_logger().info(f"stopped; {frames.dropped} frames dropped while the classifier was busy")
        node.destroy_node()
        rclpy.try_shutdown()


def _observation(text: str) -> tuple[str, str]:
    name, sep, observation = text.partition("=")
    if not sep or not name or not observation:
        raise argparse.ArgumentTypeError(f"expected CLASS=OBSERVATION, got {text!r}")
    return name, observation


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m experiments.ros_node", description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--write-interface-package",
        type=Path,
        metavar="WORKSPACE_SRC",
        help="write the hbni_msgs package into a ROS 2 workspace's src folder and exit",
    )
    parser.add_argument("--classifier", type=Path, help="a saved FrameClassifier (classifier.safetensors)")
    parser.add_argument("--posterior", type=Path, help="a saved HBNIPosterior (posterior.safetensors)")
    parser.add_argument("--controller", type=Path, help="a saved JointController (optional)")
    parser.add_argument("--agent", type=int, default=0, help="which robot's controller (default 0)")
    parser.add_argument(
        "--observation",
        type=_observation,
        action="append",
        metavar="CLASS=OBSERVATION",
        help="the controller's observation for a class (repeat; default: the class name)",
    )
    parser.add_argument(
        "--classes",
        type=lambda s: s.split(","),
        help="the posterior's classes in column order, a,b,c (for a posterior without names; else its names)",
    )
    parser.add_argument("--topic", default="/camera/image_raw", help="the image topic (default /camera/image_raw)")
    parser.add_argument("--compressed", action="store_true", help="the topic carries CompressedImage messages")
    parser.add_argument("--namespace", default="/hbni", help="namespace of the published topics (default /hbni)")
    parser.add_argument("--name", default="hbni", help="the node's name (default hbni)")
    parser.add_argument("--threshold", type=float, default=0.95, help="macro-observation threshold (default 0.95)")
    parser.add_argument("--max-frames", type=int, default=30, help="frame budget per macro-observation (30)")
    parser.add_argument("--temper", type=float, default=1.0, help="HBNI temper of a frame-level model (1)")
    parser.add_argument("--mode", default="marginal", choices=hbni_pyro.HBNIFilter.MODES, help="HBNI filter mode")
    parser.add_argument("--batch", type=int, default=1, help="frames per classifier call (default 1)")
    parser.add_argument("--queue", type=int, default=2, help="frames waiting at most; older ones dropped (2)")
    args = parser.parse_args(argv)
    if args.write_interface_package is None and (args.classifier is None or args.posterior is None):
        parser.error("--classifier and --posterior are required (or --write-interface-package)")
    return args


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    if args.write_interface_package is not None:
        package = write_interface_package(args.write_interface_package)
        print(f"[ros_node] wrote {package}; build it with colcon build --packages-select hbni_msgs")
        return
    run_node(args)


if __name__ == "__main__":
    main()
