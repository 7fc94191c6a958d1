"""Macro-observations as ROS 2 messages, and the MCAP bag that records them.

Each :class:`~hbni_pyro.runtime.live.LiveMacroObservation` becomes, on topics under a namespace (``/hbni`` by default):

* ``<ns>/classification``, ``vision_msgs/msg/Classification``: one ``ObjectHypothesis`` per class, in the
  posterior's order, ``class_id`` the class name and ``score`` its posterior probability;
* ``<ns>/macro_observation``, ``hbni_msgs/msg/MacroObservation`` (:data:`MACRO_OBSERVATION`): label,
  confidence, frames used, first and last stamps, timed out;
* ``<ns>/decision``, ``hbni_msgs/msg/MacroActionDecision`` (:data:`MACRO_ACTION_DECISION`): the controller's
  next macro-action, when it made one;

and annotated frames go to ``<ns>/annotated`` as ``sensor_msgs/msg/Image`` (``bgr8``) when asked.

Every header carries the stamp of the last frame the macro-observation used and that frame's ``frame_id``; in a
bag, its messages are logged at that frame's receive time, so the output bag lines up with the input bag.
The ``hbni_msgs`` types are registered in the bag (any ROS 2 bag reader decodes them without the package);
:func:`write_interface_package` writes the ``hbni_msgs`` package a ROS 2 workspace builds to publish them live.
The ``ros`` extra (``rosbags``) is imported on first use.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hbni_infra import ros
from hbni_infra.files import atomic_path, atomic_write_text
from hbni_pyro.runtime.live import LiveMacroObservation

OBJECT_HYPOTHESIS = """\
# An object hypothesis that contains no pose information (vision_msgs 4, ROS 2 Humble and later).
string class_id   # the class name
float64 score     # its probability
"""
CLASSIFICATION = """\
# A classification result (vision_msgs 4, ROS 2 Humble and later).
std_msgs/Header header
vision_msgs/ObjectHypothesis[] results
"""
MACRO_OBSERVATION = """\
# An HBNI macro-observation: consecutive frames of one object filtered until the class posterior's maximum
# reached the threshold or the frame budget ran out.
# header.stamp: the header stamp of the last frame used; header.frame_id: that frame's frame id.
std_msgs/Header header
uint32 index                         # 0, 1, ... in the stream
string label                         # the decided class (the posterior's argmax, the lowest index on ties)
uint32 label_index                   # its index in class_names
float64 confidence                   # the posterior's maximum
uint32 frames_used                   # frames filtered for it
builtin_interfaces/Time first_stamp  # header stamp of the first frame used
builtin_interfaces/Time last_stamp   # header stamp of the last frame used
bool timed_out                       # the frame budget (or the stream) ran out before the threshold was reached
bool stream_ended                    # the stream ended first (timed_out is true as well)
string[] class_names                 # the classes, in the posterior's order
float64[] posterior                  # the class posterior at the decision, in class_names order
"""
MACRO_ACTION_DECISION = """\
# A robot's controller picked its next macro-action (MA): a macro-observation completed its current one.
# header.stamp: the header stamp of the last frame of that macro-observation.
std_msgs/Header header
uint32 agent              # the robot's index in the team's joint controller
uint32 macro_observation  # index of the MacroObservation that completed the MA
string completed          # the MA that completed
string observation        # the observation the controller received
string action             # the MA it picks next
uint32 action_index       # its index in the domain's MA list
uint32 node               # the controller's node after the decision
"""

DEFINITIONS = (
    ("vision_msgs/msg/ObjectHypothesis", OBJECT_HYPOTHESIS),
    ("vision_msgs/msg/Classification", CLASSIFICATION),
    ("hbni_msgs/msg/MacroObservation", MACRO_OBSERVATION),
    ("hbni_msgs/msg/MacroActionDecision", MACRO_ACTION_DECISION),
)
"""The message types this module adds to ROS 2's standard ones: ``(type name, .msg text)``."""

TOPICS = {
    "classification": ("classification", "vision_msgs/msg/Classification"),
    "macro_observation": ("macro_observation", "hbni_msgs/msg/MacroObservation"),
    "decision": ("decision", "hbni_msgs/msg/MacroActionDecision"),
    "annotated": ("annotated", ros.IMAGE),
}
"""Role -> (topic name under the namespace, message type)."""


def typestore() -> Any:
    """A ``rosbags`` typestore of ROS 2 Humble's types plus :data:`DEFINITIONS`."""
    return ros.typestore(definitions=DEFINITIONS)


def topic_names(namespace: str = "/hbni") -> dict[str, str]:
    """Role -> full topic name, e.g. ``{"classification": "/hbni/classification", ...}``.

    Raises:
        ValueError: ``namespace`` is not ``/`` or an absolute name without a trailing ``/``.
    """
    if not isinstance(namespace, str) or not namespace.startswith("/") or (len(namespace) > 1 and namespace[-1] == "/"):
        raise ValueError(f"namespace: expected an absolute ROS name such as '/hbni', got {namespace!r}")
    return {role: f"{namespace.rstrip('/')}/{name}" for role, (name, _) in TOPICS.items()}


def messages(obs: LiveMacroObservation, classes: Sequence[str], store: Any = None) -> dict[str, Any]:
    """Role -> message (``rosbags`` dataclasses of ``store``, default :func:`typestore`) for one macro-observation:
    ``classification`` and ``macro_observation``, and ``decision`` when it has one."""
    store = store or typestore()
    types = store.types
    seg = obs.segment
    posterior = [float(p) for p in obs.posterior]
    if len(posterior) != len(classes):
        raise ValueError(f"classes: expected {len(posterior)} names (the posterior's width), got {list(classes)}")
    head = ros.header(store, obs.last_stamp, obs.frame_id)
    time = types["builtin_interfaces/msg/Time"]
    hypothesis = types["vision_msgs/msg/ObjectHypothesis"]
    out = {
        "classification": types["vision_msgs/msg/Classification"](
            header=head, results=[hypothesis(class_id=str(c), score=p) for c, p in zip(classes, posterior)]
        ),
        "macro_observation": types["hbni_msgs/msg/MacroObservation"](
            header=head,
            index=seg.index,
            label=seg.name,
            label_index=seg.label,
            confidence=float(seg.confidence),
            frames_used=seg.frames_used,
            first_stamp=time(*ros.time_fields(obs.first_stamp)),
            last_stamp=time(*ros.time_fields(obs.last_stamp)),
            timed_out=bool(seg.timed_out),
            stream_ended=bool(seg.stream_ended),
            class_names=[str(c) for c in classes],
            posterior=np.asarray(posterior, dtype=np.float64),
        ),
    }
    if obs.decision is not None:
        d = obs.decision
        out["decision"] = types["hbni_msgs/msg/MacroActionDecision"](
            header=head,
            agent=d.agent,
            macro_observation=seg.index,
            completed=d.completed,
            observation=d.observation,
            action=d.action,
            action_index=d.action_index,
            node=d.node,
        )
    return out


class MacroObservationBag:
    """A new rosbag2 directory with MCAP storage recording macro-observations (a context manager).

    The topics of :data:`TOPICS` under ``namespace``: each :meth:`write` logs the classification and the
    macro-observation (and the decision, if any) at the last frame's receive time; :meth:`write_frame` logs an
    annotated frame on ``<ns>/annotated``. The bag is written to a staging directory and moved to ``path`` by
    :meth:`close`; leaving the ``with`` block on an error removes it.

    Args:
        path: the bag directory to create (its storage file is ``<name>.mcap`` inside).
        classes: class names in the posterior's order.
        namespace: the topics' namespace.

    Attributes:
        counts: role -> messages written.

    Raises:
        FileExistsError: ``path`` exists.
        ImportError: the ``ros`` extra is not installed.
    """

    def __init__(self, path: str | os.PathLike, classes: Sequence[str], namespace: str = "/hbni") -> None:
        self.path, self.classes = Path(path), [str(c) for c in classes]
        self.topics = topic_names(namespace)
        self._store = typestore()
        self._stack = contextlib.ExitStack()
        staged = self._stack.enter_context(atomic_path(self.path))
        self._writer = self._stack.enter_context(ros.rosbag2_writer(staged))
        self._connections: dict[str, Any] = {}
        self.counts = {role: 0 for role in TOPICS}

    def _write(self, role: str, message: Any, log_time: int) -> None:
        msgtype = TOPICS[role][1]
        if role not in self._connections:
            self._connections[role] = self._writer.add_connection(self.topics[role], msgtype, typestore=self._store)
        self._writer.write(self._connections[role], int(log_time), self._store.serialize_cdr(message, msgtype))
        self.counts[role] += 1

    def write(self, obs: LiveMacroObservation) -> None:
        """Log one macro-observation's messages (:func:`messages`) at its last frame's receive time."""
        for role, message in messages(obs, self.classes, self._store).items():
            self._write(role, message, obs.received)

    def write_frame(self, image: np.ndarray, stamp: int, received: int, frame_id: str = "") -> None:
        """Log a uint8 BGR frame ``(H, W, 3)`` as a ``bgr8`` Image stamped ``stamp``, at ``received`` (ns)."""
        self._write("annotated", ros.image_message(self._store, image, stamp, frame_id), received)

    def close(self) -> Path:
        """Finish the bag and move it into place; returns its path."""
        self._stack.close()
        return self.path

    def __enter__(self) -> MacroObservationBag:
        return self

    def __exit__(self, *exc: Any) -> None:
        if exc[0] is None:
            self.close()
        else:
            self._stack.__exit__(*exc)


INTERFACE_PACKAGE = "hbni_msgs"

_PACKAGE_XML = """\
<?xml version="1.0"?>
<?xml-model href="http://download.ros.org/schema/package_format3.xsd" schematypens="http://www.w3.org/2001/XMLSchema"?>
<package format="3">
  <name>hbni_msgs</name>
  <version>0.1.0</version>
  <description>Messages of hbni-pyro: HBNI macro-observations and a robot controller's macro-action decisions.</description>
  <maintainer email="hbni-pyro@users.noreply.github.com">hbni-pyro</maintainer>
  <license>MIT</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>builtin_interfaces</depend>
  <depend>std_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export>
    <build_type>ament_cmake</build_type>
  </export>
</package>
"""

_CMAKELISTS = """\
cmake_minimum_required(VERSION 3.8)
project(hbni_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(builtin_interfaces REQUIRED)
find_package(std_msgs REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME}
  {files}
  DEPENDENCIES builtin_interfaces std_msgs
)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""


def write_interface_package(workspace_src: str | os.PathLike) -> Path:
    """Write the ``hbni_msgs`` ROS 2 interface package (``package.xml``, ``CMakeLists.txt``, ``msg/*.msg``, the
    :data:`DEFINITIONS` of ``hbni_msgs``) into a workspace's ``src`` folder; returns the package folder.

    ``colcon build --packages-select hbni_msgs`` in the workspace builds it (needs a ROS 2 installation).

    Raises:
        FileExistsError: the package folder exists.
    """
    package = Path(workspace_src) / INTERFACE_PACKAGE
    if package.exists():
        raise FileExistsError(f"workspace_src: {str(package)!r} exists already")
    msgs = [(name.rsplit("/", 1)[1], text) for name, text in DEFINITIONS if name.startswith(f"{INTERFACE_PACKAGE}/")]
    for name, text in msgs:
        atomic_write_text(package / "msg" / f"{name}.msg", text)
    atomic_write_text(package / "package.xml", _PACKAGE_XML)
    files = "\n  ".join(f'"msg/{name}.msg"' for name, _ in msgs)
    atomic_write_text(package / "CMakeLists.txt", _CMAKELISTS.replace("{files}", files))
    return package
