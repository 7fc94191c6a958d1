"""The small problems the decpomdp tests share: the shipped ``.dpomdp`` files at a chosen horizon and discount,
Dec-Tiger (Nair et al., 2003) and its optimal values."""

from __future__ import annotations

import math

from decpomdp.dpomdp import TabularDecPOSMDP

#: optimal finite-horizon values of Dec-Tiger (Szer, Charpillet and Zilberstein, 2005)
DEC_TIGER_OPTIMUM = {2: -4.0, 3: 5.190812, 4: 4.802755}


def problem(name: str, horizon: float = math.inf, gamma: float = 1.0) -> TabularDecPOSMDP:
    """The shipped problem ``name`` with ``horizon`` steps (``inf``: infinite) and discount ``gamma``."""
    return TabularDecPOSMDP.from_problem(name, gamma=gamma, horizon=horizon)


def dec_tiger(horizon: float, gamma: float = 1.0) -> TabularDecPOSMDP:
    """Dec-Tiger with ``horizon`` steps."""
    return problem("dectiger", horizon, gamma)
