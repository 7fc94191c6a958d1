"""Mission domains: package delivery (G-DICE paper) and health-aware disaster relief (ICRA 2017),
each with its hand-written greedy controller; running controllers on them (counters, shared controllers)."""

from decpomdp.domains.disaster_relief import DisasterRelief
from decpomdp.domains.package_delivery import PackageDelivery
from decpomdp.domains.rollouts import rollout_counters, shared

__all__ = ["DisasterRelief", "PackageDelivery", "rollout_counters", "shared"]
