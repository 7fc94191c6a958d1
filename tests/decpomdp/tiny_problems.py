"""Dec-Tiger (Nair et al., 2003), the shipped ``dectiger.dpomdp``, at a finite horizon, and its optimal values."""

from __future__ import annotations

from decpomdp.dpomdp import TabularDecPOSMDP

#: optimal finite-horizon values of Dec-Tiger (Szer, Charpillet and Zilberstein, 2005)
DEC_TIGER_OPTIMUM = {2: -4.0, 3: 5.190812, 4: 4.802755}


def dec_tiger(horizon: int, gamma: float = 1.0) -> TabularDecPOSMDP:
    """Dec-Tiger with ``horizon`` steps."""
    return TabularDecPOSMDP.from_problem("dectiger", gamma=gamma, horizon=horizon)
