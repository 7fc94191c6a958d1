"""The live ROS 2 node's interface, shared by the node (:mod:`experiments.ros_node`) and its launch file
(``hbni.launch.py`` beside this module): its executable, name, image topic and parameters. It imports nothing, so
``ros2 launch`` reads it without loading torch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

EXECUTABLE = "hbni-ros-node"
"""The node's console script (``[project.scripts]``), what the launch file's ``Node`` action runs."""
NODE_NAME = "hbni"
"""The node's default name (``-r __node:=...`` renames it); its topics are published under it (``~/``)."""
IMAGE_TOPIC = "camera/image_raw"
"""The image topic, relative to the node's namespace (remap it: ``-r camera/image_raw:=/front/image_raw``)."""


@dataclass(frozen=True)
class Parameter:
    """A setting of the node, declared as a read-only ROS parameter.

    ``kind`` is ``"string"``, ``"double"``, ``"integer"`` or ``"bool"``; ``bounds`` the closed range of a number.
    """

    name: str
    kind: str
    default: Any
    description: str
    bounds: tuple[float, float] | None = None


PARAMETERS = (
    Parameter("classifier", "string", "", "path of a saved FrameClassifier (classifier.safetensors); required"),
    Parameter("posterior", "string", "", "path of a saved HBNIPosterior (posterior.safetensors); required"),
    Parameter("controller", "string", "", "path of a saved JointController ('': no decisions)"),
    Parameter("agent", "integer", 0, "which robot's controller", (0, 1023)),
    Parameter("classes", "string", "", "the posterior's classes in column order, a,b,c ('': its own names)"),
    Parameter(
        "observations",
        "string",
        "",
        "the controller's observation of each class, CLASS=OBSERVATION,... ('': the names)",
    ),
    Parameter(
        "completes",
        "string",
        "infer",
        "the controller's MAs that a macro-observation completes, a,b; a controller that can pick another is refused",
    ),
    Parameter("threshold", "double", 0.95, "a macro-observation ends when max_m P(m) reaches it ...", (0.0, 1.0)),
    Parameter("max_frames", "integer", 30, "... or after this many frames (timed out)", (1, 100_000)),
    Parameter("temper", "double", 1.0, "HBNI likelihood temper of a frame-level noise model", (0.0, 1.0)),
    Parameter("mode", "string", "marginal", "HBNI filter mode: marginal or plugin"),
    Parameter("batch", "integer", 1, "frames per classifier call (1: the lowest latency)", (1, 1024)),
    Parameter("queue", "integer", 2, "frames waiting at most; the oldest is dropped when the queue is full", (1, 1024)),
    Parameter("compressed", "bool", False, "subscribe to camera/image_raw/compressed (CompressedImage)"),
)
"""The node's parameters, in declaration order."""
