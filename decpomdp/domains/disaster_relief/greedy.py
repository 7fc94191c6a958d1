"""A hand-written reactive greedy controller for disaster relief, written as a finite-state controller."""

from __future__ import annotations

import torch

from decpomdp.controller import JointController
from decpomdp.domains.disaster_relief.rules import (
    ACTION_NAMES,
    GO_AIRPORT,
    GO_B1,
    GO_B2,
    GO_CRATE,
    GO_HOSPITAL,
    INFER,
    OBS_NAMES,
    PICK,
    PUT,
    REPAIR_MA,
)


def greedy_controller(num_agents: int = 2) -> JointController:
    """An 8-node reactive greedy controller for :class:`decpomdp.domains.DisasterRelief`.

    Each robot infers the class of the object at its base, picks it up, carries it to the
    inferred destination, puts it down and goes back to its home base (Base1 for even robots,
    Base2 for odd ones); after a put-down it goes to the repair station first when its health
    sensor reads low. It never plans ahead: no repair before a reading of low, always the same
    home base whatever the nearer one.
    """
    names = ["infer", "pick", "go_hospital", "go_airport", "go_crate_zone", "put", "home", "repair"]
    node = {name: i for i, name in enumerate(names)}

    def react(obs: str) -> str:
        context, reading = obs.rsplit("_", 1)
        if context == "at_base":
            return "infer"
        if context.startswith("saw_"):
            return "pick"
        if context.startswith("loaded_"):
            site = context.removeprefix("loaded_")
            return f"go_{site}" if site != "unknown" else "go_hospital"
        if context == "at_site_loaded":
            return "put"
        return "repair" if reading == "low" else "home"  # away, empty-handed

    def after_repair(obs: str) -> str:
        return "home" if obs.startswith("away_") else react(obs)

    next_node = [[node[(after_repair if name == "repair" else react)(obs)] for obs in OBS_NAMES] for name in names]
    actions = []
    for a in range(num_agents):
        home = GO_B1 if a % 2 == 0 else GO_B2
        actions.append([INFER, PICK, GO_HOSPITAL, GO_AIRPORT, GO_CRATE, PUT, home, REPAIR_MA])
    nxt = torch.tensor(next_node, dtype=torch.long)
    return JointController(
        torch.tensor([actions], dtype=torch.long), nxt.expand(1, num_agents, -1, -1).clone(), ACTION_NAMES, OBS_NAMES
    )
