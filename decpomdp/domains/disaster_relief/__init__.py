"""Health-aware disaster relief (after Omidshafiei et al., ICRA 2017).

* :mod:`.rules`: the domain's description, constants and its rules for the compiled engine;
* :mod:`.domain`: :class:`DisasterRelief`, the domain object (and the batched torch oracle of the rules);
* :mod:`.greedy`: a hand-written reactive greedy controller.
"""

from decpomdp.domains.disaster_relief import rules
from decpomdp.domains.disaster_relief.domain import DisasterRelief
from decpomdp.domains.disaster_relief.greedy import greedy_controller
from decpomdp.domains.disaster_relief.rules import (
    CLASSES, LOCATIONS, BASE1, BASE2, HOSPITAL, AIRPORT, CRATE_ZONE, REPAIR, DESTINATION, ACTION_NAMES, GO_B1,
    GO_B2, GO_HOSPITAL, GO_AIRPORT, GO_CRATE, REPAIR_MA, INFER, PICK, PUT, HEALTH, CONTEXTS, AWAY, AT_BASE,
    SAW, LOADED, LOADED_UNKNOWN, AT_SITE_LOADED, OBS_NAMES, TRAVEL, SLOWDOWN, HANDLING_TIME, REPAIR_TIME,
    FAIL_DURATION, DURATION_NOISE, MIN_NOISE_FACTOR, COUNTERS,
)

__all__ = [
    "DisasterRelief", "greedy_controller", "rules", "CLASSES", "LOCATIONS", "BASE1", "BASE2", "HOSPITAL", "AIRPORT",
    "CRATE_ZONE", "REPAIR", "DESTINATION", "ACTION_NAMES", "GO_B1", "GO_B2", "GO_HOSPITAL", "GO_AIRPORT",
    "GO_CRATE", "REPAIR_MA", "INFER", "PICK", "PUT", "HEALTH", "CONTEXTS", "AWAY", "AT_BASE", "SAW", "LOADED",
    "LOADED_UNKNOWN", "AT_SITE_LOADED", "OBS_NAMES", "TRAVEL", "SLOWDOWN", "HANDLING_TIME", "REPAIR_TIME",
    "FAIL_DURATION", "DURATION_NOISE", "MIN_NOISE_FACTOR", "COUNTERS",
]
