"""Package delivery, the reference Dec-POSMDP of the G-DICE paper (Omidshafiei et al., ICRA 2016).

* :mod:`.rules`: the domain's rules and constants (read this to know what the domain does);
* :mod:`.batched`: :class:`PackageDelivery`, those rules on a batch of rollouts;
* :mod:`.greedy`: a hand-written greedy controller.
"""

from decpomdp.domains.package_delivery import rules
from decpomdp.domains.package_delivery.batched import PackageDelivery
from decpomdp.domains.package_delivery.greedy import greedy_controller
from decpomdp.domains.package_delivery.rules import (
    NODE_NAMES, BASE1, BASE2, RENDEZVOUS, DEST1, DEST2, ACTION_NAMES, GO_B1, GO_B2, GO_R, GO_D1, GO_D2,
    JGO_D1, JGO_D2, PICK, JPICK, PUT, JPUT, TRUCK, WAIT, SMALL, LARGE, OBS_NAMES, MEAN_DURATION, TARGET_NODE,
    PACKAGES, ARRIVAL, DURATION_NOISE, MIN_NOISE_FACTOR, FAIL_DURATION, JOINT_MAS, DROP_MAS, COUNTERS,
    REFERENCE_SUCCESSORS, Rewards, preconditions_hold,
)

__all__ = [
    "PackageDelivery", "greedy_controller", "rules", "NODE_NAMES", "BASE1", "BASE2", "RENDEZVOUS", "DEST1",
    "DEST2", "ACTION_NAMES", "GO_B1", "GO_B2", "GO_R", "GO_D1", "GO_D2", "JGO_D1", "JGO_D2", "PICK", "JPICK",
    "PUT", "JPUT", "TRUCK", "WAIT", "SMALL", "LARGE", "OBS_NAMES", "MEAN_DURATION", "TARGET_NODE", "PACKAGES",
    "ARRIVAL", "DURATION_NOISE", "MIN_NOISE_FACTOR", "FAIL_DURATION", "JOINT_MAS", "DROP_MAS", "COUNTERS",
    "REFERENCE_SUCCESSORS", "Rewards", "preconditions_hold",
]
