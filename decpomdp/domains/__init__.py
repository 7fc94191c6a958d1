"""Mission domains: package delivery (G-DICE paper) and health-aware disaster relief (ICRA 2017)."""

from decpomdp.domains.package_delivery import PackageDelivery

__all__ = ["PackageDelivery"]
