"""What a domain hands the compiled engine: its rules, its state layout and its numbers.

A domain written for the engine (:class:`EngineDomain`) is three compiled scalar rules on one
rollout's state, compiled together with the event loop into one chunk function (see :mod:`decpomdp.engine.loop`),
and a :class:`StateLayout` naming the entries of that state. A :class:`~decpomdp.core.DecPOSMDP` instance plugs into the engine by returning an
:class:`EngineModel` from ``engine_model()``: the domain, its parameters (float64 vector), its
constant tables (a tuple of arrays) and its perception's :class:`~decpomdp.engine.outcomes.OutcomeTable`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from decpomdp.engine.outcomes import OutcomeTable


@dataclass(frozen=True)
class StateLayout:
    """Names of one rollout's int64 state entries: ``team`` entries first, then one block of ``robot``
    entries per robot (entry ``f`` of robot ``a`` at ``len(team) + a * len(robot) + f``, named
    ``f"{field}[{a}]"``); likewise for the float64 state."""

    team: tuple[str, ...] = ()
    robot: tuple[str, ...] = ()
    team_float: tuple[str, ...] = ()
    robot_float: tuple[str, ...] = ()

    def int_names(self, num_agents: int) -> tuple[str, ...]:
        return self.team + tuple(f"{f}[{a}]" for a in range(num_agents) for f in self.robot)

    def float_names(self, num_agents: int) -> tuple[str, ...]:
        return self.team_float + tuple(f"{f}[{a}]" for a in range(num_agents) for f in self.robot_float)


@dataclass(frozen=True)
class EngineDomain:
    """A domain for the engine: its compiled chunk function (``chunk(args, out, index, lo, hi)``, the event loop
    with the domain's rules inlined, see :mod:`decpomdp.engine.loop`), its state layout, and which int entries
    are its per-rollout counters (team entries)."""

    chunk: Any
    layout: StateLayout
    counters: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        missing = [c for c in self.counters if c not in self.layout.team]
        if missing:
            raise ValueError(f"counters: {missing} are not team entries of the layout {self.layout.team}")


class EngineModel(NamedTuple):
    """One instance of a domain for the engine: rules, parameters, tables and perception."""

    domain: EngineDomain
    params: np.ndarray
    tables: tuple
    perception: OutcomeTable
