"""Hand-written policies, written as joint finite-state controllers so the simulator runs them as is.

* :func:`package_delivery_greedy`: each robot picks up any small package it sees, carries it to
  its destination and returns to Base1; with the partner present at a large package both pick it
  up jointly, alone it waits at the base.
* :func:`disaster_relief_greedy`: see its docstring.
"""

from __future__ import annotations

import torch

from decpomdp.controller import JointController
from decpomdp.domains import package_delivery as pd


def _joint(action: list[int], next_node: list[list[int]], num_agents: int) -> JointController:
    """The same FSC for every agent, as a K = 1 joint controller."""
    act = torch.tensor(action, dtype=torch.long)
    nxt = torch.tensor(next_node, dtype=torch.long)
    return JointController(
        act.expand(1, num_agents, -1).clone(), nxt.expand(1, num_agents, -1, -1).clone()
    )


def package_delivery_greedy() -> JointController:
    """A 12-node greedy controller for :class:`decpomdp.domains.PackageDelivery` (both robots alike)."""
    names = ["dispatch", "pick", "go_d1", "go_d2", "go_r", "put", "truck", "jpick", "jgo_d1", "jgo_d2", "jput", "home"]
    node = {name: i for i, name in enumerate(names)}
    action = [pd.WAIT, pd.PICK, pd.GO_D1, pd.GO_D2, pd.GO_R, pd.PUT, pd.TRUCK, pd.JPICK, pd.JGO_D1, pd.JGO_D2, pd.JPUT, pd.GO_B1]

    def at_base(obs: str) -> str:  # what to do on seeing a package at a base
        if obs.startswith("small"):
            return "pick"
        return "jpick" if obs.startswith("large") and obs.endswith("partner") else "dispatch"

    def after_pick(obs: str) -> str:
        for dest, go in (("dest1", "go_d1"), ("dest2", "go_d2"), ("rendezvous", "go_r")):
            if obs.startswith(f"small_{dest}"):
                return go
        return at_base(obs)

    def after_joint_pick(obs: str) -> str:
        for dest, go in (("dest1", "jgo_d1"), ("dest2", "jgo_d2")):
            if obs == f"large_{dest}_partner":
                return go
        return at_base(obs)

    rule = {
        "dispatch": at_base, "home": at_base, "pick": after_pick, "jpick": after_joint_pick,
        "go_d1": lambda o: "put", "go_d2": lambda o: "put", "go_r": lambda o: "truck",
        "put": lambda o: "home", "truck": lambda o: "home", "jput": lambda o: "home",
        "jgo_d1": lambda o: "jput", "jgo_d2": lambda o: "jput",
    }
    next_node = [[node[rule[name](obs)] for obs in pd.OBS_NAMES] for name in names]
    return _joint(action, next_node, pd.PackageDelivery.num_agents)


def disaster_relief_greedy(num_agents: int = 2) -> JointController:
    """An 8-node reactive greedy controller for :class:`decpomdp.domains.DisasterRelief`.

    Each robot infers the class of the object at its base, picks it up, carries it to the
    inferred destination, puts it down and goes back to its home base (Base1 for even robots,
    Base2 for odd ones); after a put-down it goes to the repair station first when its health
    sensor reads low. It never plans ahead: no repair before a reading of low, always the same
    home base whatever the nearer one.
    """
    from decpomdp.domains import disaster_relief as dr

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

    next_node = [[node[(after_repair if name == "repair" else react)(obs)] for obs in dr.OBS_NAMES] for name in names]
    actions = []
    for a in range(num_agents):
        home = dr.GO_B1 if a % 2 == 0 else dr.GO_B2
        actions.append([dr.INFER, dr.PICK, dr.GO_HOSPITAL, dr.GO_AIRPORT, dr.GO_CRATE, dr.PUT, home, dr.REPAIR_MA])
    nxt = torch.tensor(next_node, dtype=torch.long)
    return JointController(torch.tensor([actions], dtype=torch.long), nxt.expand(1, num_agents, -1, -1).clone())
