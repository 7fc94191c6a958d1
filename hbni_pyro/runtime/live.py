"""The robot-side loop after the classifier: stamped, classified frames in; macro-observations with their times,
the filter's posterior and, given a controller, the macro-action (MA) it picks next, out.

:func:`live_macro_observations` runs :func:`~hbni_pyro.macro_observations` on ``(frame, output)`` pairs whose
frames carry their times (``stamp``, ``received`` and ``frame_id`` attributes, integer nanoseconds:
:class:`classifiers.stamped.StampedFrame`), and hands each completed macro-observation to a robot's
controller (an object with ``action``, ``observe(observation)``, ``obs_names``, ``node`` and ``agent``:
:class:`decpomdp.ControllerExecutor`). It is the per-frame code of ``experiment=stream``, of its ROS output
bag (:mod:`hbni_pyro.runtime.ros_messages`) and of the live ROS 2 node; this package imports neither the
classifier's nor the controller's.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any, NamedTuple

from torch import Tensor

from hbni_pyro.filters.macro import MacroObservationProcess
from hbni_pyro.runtime.segments import Segment, macro_observations


class Decision(NamedTuple):
    """What a robot's controller did when a macro-observation completed its current MA."""

    agent: int  # the robot's index in the team's joint controller
    completed: str  # the MA that completed
    observation: str  # the observation the controller received
    action_index: int  # the MA it picks next: its index in the domain's MA list ...
    action: str  # ... and its name
    node: int  # the controller's node after the decision


class LiveMacroObservation(NamedTuple):
    """One macro-observation of a stamped stream.

    Attributes:
        segment: the :class:`~hbni_pyro.Segment` (its frames kept only when asked).
        running: ``(frames_used, M)`` the filter's class posterior after each of its frames, on the CPU; the
            last row is the posterior at the decision (its argmax the label, its maximum the confidence).
        first_stamp, last_stamp: header stamps of its first and last frames (ns).
        received: receive time of its last frame (ns): when the decision could be made.
        frame_id: its last frame's frame id.
        decision: the controller's :class:`Decision` (``None`` without a controller, or when the stream ended
            before this macro-observation was complete).
    """

    segment: Segment
    running: Tensor
    first_stamp: int
    last_stamp: int
    received: int
    frame_id: str
    decision: Decision | None

    @property
    def posterior(self) -> Tensor:
        """``(M,)`` the class posterior at the decision."""
        return self.running[-1]

    def record(self) -> dict[str, Any]:
        """The segment's JSON-lines record with the stamps and, when there is one, the decision."""
        record = self.segment.record()
        record.update(first_stamp=self.first_stamp, last_stamp=self.last_stamp, received=self.received)
        if self.decision is not None:
            record["decision"] = self.decision._asdict()
        return record


def observation_names(
    classes: Sequence[str], controller_observations: Sequence[str], observations: Mapping[str, str] | None = None
) -> list[str]:
    """The controller observation each class's macro-observation is reported as, in ``classes`` order.

    Args:
        classes: the process's class names.
        controller_observations: the controller's observation names (``ControllerExecutor.obs_names``).
        observations: class name -> observation name; ``None``: each class is reported by its own name.

    Raises:
        ValueError: a mapping key that is not a class, or an observation the controller does not know (the
            message lists the classes, the observations asked for and the controller's).
    """
    mapping = dict(observations or {})
    unknown = sorted(set(mapping) - set(classes))
    if unknown:
        raise ValueError(f"observations: {unknown} are not classes; the classes are {list(classes)}")
    names = [str(mapping.get(name, name)) for name in classes]
    missing = [name for name in names if name not in controller_observations]
    if missing:
        raise ValueError(
            f"observations: the classes {list(classes)} are reported to the controller as {names}, but it has "
            f"no observation {missing}; its observations are {list(controller_observations)} (map each class "
            "to one of them)"
        )
    return names


def live_macro_observations(
    items: Iterable[tuple[Any, Tensor]],
    process: MacroObservationProcess,
    classes: Sequence[str],
    controller: Any = None,
    observations: Mapping[str, str] | None = None,
    keep_frames: bool = False,
) -> Iterator[LiveMacroObservation]:
    """Consecutive macro-observations of a classified stream of stamped frames, with the controller's decisions.

    Args:
        items: ``(frame, output)`` pairs, frames with ``stamp``, ``received`` and ``frame_id`` attributes.
        process: the macro-observation process (restarted after each macro-observation).
        classes: class names in the process's order.
        controller: a robot's controller executor, or ``None``. Each complete macro-observation is the
            observation that completes its current MA; one cut short by the end of the stream is not.
        observations: class name -> controller observation name (:func:`observation_names`).
        keep_frames: keep each segment's frames (for annotation).

    A frame stamped before the frame before it (a clock jump: a replayed bag restarting, a simulation reset) is
    warned about (``RuntimeWarning`` naming the frame and both stamps): the macro-observation spanning it has its
    ``first_stamp`` after its ``last_stamp``. A bag read with :class:`classifiers.bags.BagSource` refuses such stamps.
    """
    names = None if controller is None else observation_names(classes, controller.obs_names, observations)
    for segment in macro_observations(_watch_stamps(items), process, classes, keep_frames=True):
        first, last = segment.frames[0], segment.frames[-1]
        if not all(hasattr(first, name) for name in ("stamp", "received", "frame_id")):
            raise TypeError(
                "items: expected frames with stamp, received and frame_id attributes (a stamped source's "
                f"frames, classifiers.stamped.StampedFrame), got {type(first).__name__}"
            )
        running = process.filter.run(segment.outputs.unsqueeze(0))[0].cpu()
        decision = None
        if names is not None and not segment.stream_ended:
            completed = controller.action.name
            action = controller.observe(names[segment.label])
            decision = Decision(
                int(controller.agent), completed, names[segment.label], int(action.index), action.name, controller.node
            )
        yield LiveMacroObservation(
            segment if keep_frames else segment._replace(frames=[]),
            running,
            int(first.stamp),
            int(last.stamp),
            int(last.received),
            str(last.frame_id),
            decision,
        )


def _watch_stamps(items: Iterable[tuple[Any, Tensor]]) -> Iterator[tuple[Any, Tensor]]:
    """``items`` unchanged, with a ``RuntimeWarning`` for every frame stamped before the frame before it."""
    previous = None
    for index, (frame, output) in enumerate(items):
        stamp = getattr(frame, "stamp", None)
        if previous is not None and stamp is not None and stamp < previous:
            warnings.warn(
                f"items: frame {index} (frame id {getattr(frame, 'frame_id', '')!r}) is stamped {stamp} ns, "
                f"{(previous - stamp) / 1e9:g} s before the frame before it ({previous} ns): the stamps run backwards "
                "(a clock jump), so the macro-observation spanning it ends before it starts",
                RuntimeWarning,
                stacklevel=3,
            )
        previous = stamp if stamp is not None else previous
        yield frame, output
