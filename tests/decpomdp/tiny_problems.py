"""Small problems built inside the tests: Dec-Tiger (Nair et al., 2003) in the MADP ``.dpomdp`` format."""

from __future__ import annotations

from decpomdp.dpomdp import TabularDecPOSMDP, parse_dpomdp

DEC_TIGER = """\
agents: 2
discount: 1
values: reward
states: tiger-left tiger-right
start:
uniform
actions:
listen open-left open-right
listen open-left open-right
observations:
hear-left hear-right
hear-left hear-right
T: * :
uniform
T: listen listen :
identity
O: * :
uniform
O: listen listen : tiger-left : hear-left hear-left : 0.7225
O: listen listen : tiger-left : hear-left hear-right : 0.1275
O: listen listen : tiger-left : hear-right hear-left : 0.1275
O: listen listen : tiger-left : hear-right hear-right : 0.0225
O: listen listen : tiger-right : hear-right hear-right : 0.7225
O: listen listen : tiger-right : hear-left hear-right : 0.1275
O: listen listen : tiger-right : hear-right hear-left : 0.1275
O: listen listen : tiger-right : hear-left hear-left : 0.0225
R: listen listen: * : * : * : -2
R: open-left open-left : tiger-left : * : * : -50
R: open-right open-right : tiger-right : * : * : -50
R: open-left open-left : tiger-right : * : * : +20
R: open-right open-right : tiger-left : * : * : 20
R: open-left open-right: tiger-left : * : * : -100
R: open-left open-right: tiger-right : * : * : -100
R: open-right open-left: tiger-left : * : * : -100
R: open-right open-left: tiger-right : * : * : -100
R: open-left listen: tiger-left : * : * : -101
R: listen open-right: tiger-right : * : * : -101
R: listen open-left: tiger-left : * : * : -101
R: open-right listen: tiger-right : * : * : -101
R: listen open-right: tiger-left : * : * : 9
R: listen open-left: tiger-right : * : * : 9
R: open-right listen: tiger-left : * : * : 9
R: open-left listen: tiger-right : * : * : 9
"""

#: optimal finite-horizon values of Dec-Tiger (Szer, Charpillet and Zilberstein, 2005)
DEC_TIGER_OPTIMUM = {2: -4.0, 3: 5.190802, 4: 4.802755}


def dec_tiger(horizon: int, gamma: float = 1.0) -> TabularDecPOSMDP:
    """Dec-Tiger with ``horizon`` steps."""
    return TabularDecPOSMDP(parse_dpomdp(DEC_TIGER), gamma=gamma, horizon=horizon)
