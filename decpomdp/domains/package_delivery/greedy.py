"""A hand-written greedy controller for package delivery, written as a finite-state controller."""

from __future__ import annotations

import torch

from decpomdp.controller import JointController
from decpomdp.domains.package_delivery.domain import PackageDelivery
from decpomdp.domains.package_delivery.rules import (
    ACTION_NAMES,
    GO_B1,
    GO_D1,
    GO_D2,
    GO_R,
    JGO_D1,
    JGO_D2,
    JPICK,
    JPUT,
    OBS_NAMES,
    PICK,
    PUT,
    TRUCK,
    WAIT,
)
from decpomdp.domains.rollouts import shared


def greedy_controller() -> JointController:
    """A 12-node greedy controller for :class:`PackageDelivery`, the same FSC for both robots.

    Each robot picks up any small package it sees, carries it to its destination and returns to
    Base1; with the partner present at a large package both pick it up jointly, alone it waits at
    the base.
    """
    names = ["dispatch", "pick", "go_d1", "go_d2", "go_r", "put", "truck", "jpick", "jgo_d1", "jgo_d2", "jput", "home"]
    node = {name: i for i, name in enumerate(names)}
    action = [WAIT, PICK, GO_D1, GO_D2, GO_R, PUT, TRUCK, JPICK, JGO_D1, JGO_D2, JPUT, GO_B1]

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
        "dispatch": at_base,
        "home": at_base,
        "pick": after_pick,
        "jpick": after_joint_pick,
        "go_d1": lambda o: "put",
        "go_d2": lambda o: "put",
        "go_r": lambda o: "truck",
        "put": lambda o: "home",
        "truck": lambda o: "home",
        "jput": lambda o: "home",
        "jgo_d1": lambda o: "jput",
        "jgo_d2": lambda o: "jput",
    }
    next_node = [[node[rule[name](obs)] for obs in OBS_NAMES] for name in names]
    one = JointController(torch.tensor([[action]]), torch.tensor([[next_node]]))
    return shared(one, PackageDelivery.num_agents).named(ACTION_NAMES, OBS_NAMES)
