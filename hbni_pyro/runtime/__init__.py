"""The robot-side runtime after the classifier: a classified stream cut into macro-observations, recorded streams
replayed as perception, the live loop with stamps and a controller, and the ROS 2 messages and bag.

- :mod:`.segments`: :func:`macro_observations`, consecutive macro-observations of a classified stream.
- :mod:`.live`: :func:`live_macro_observations`, with frame stamps, the filter's posterior and a controller's
  decision.
- :mod:`.replay`: :class:`StreamReplay`, recorded streams run through a process as a planner's perception model.
- :mod:`.ros_messages`: the macro-observations as ROS 2 messages and the MCAP bag that records them (the ``ros``
  extra, imported on first use).
"""

from hbni_pyro.runtime.live import Decision, LiveMacroObservation, live_macro_observations, observation_names
from hbni_pyro.runtime.replay import StreamReplay
from hbni_pyro.runtime.ros_messages import (
    DEFINITIONS,
    TOPICS,
    MacroObservationBag,
    messages,
    topic_names,
    typestore,
    write_interface_package,
)
from hbni_pyro.runtime.segments import Segment, macro_observations

__all__ = [
    "DEFINITIONS",
    "TOPICS",
    "Decision",
    "LiveMacroObservation",
    "MacroObservationBag",
    "Segment",
    "StreamReplay",
    "live_macro_observations",
    "macro_observations",
    "messages",
    "observation_names",
    "topic_names",
    "typestore",
    "write_interface_package",
]
