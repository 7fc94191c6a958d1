"""Health-aware disaster relief as a :class:`~decpomdp.core.DecPOSMDP`: the domain object.

:mod:`.rules` states the domain and holds its rules for the compiled engine, which
:func:`decpomdp.simulate` runs by default. The batched torch methods below (``reset``, ``start``,
``complete``, over a batch of rollouts) implement the same rules a second time, as the test oracle of
the engine (``backend="torch"``); perception models without an outcome table (``outcomes()``) run
on them too. They run on the generator's device (the perception model's ``sample`` must keep
the device of ``true_class``, as :class:`~decpomdp.perception.PerfectPerception` does).

State of the torch oracle (batch first): ``loc``, ``carry`` (class or -1), ``health``, ``ma``,
``ok``, ``label``, ``frames``, ``fresh``, ``belief`` (B, A); ``objects`` (B, 2) classes waiting at
the bases; counters ``delivered``, ``wrong``, ``inference_frames``, ``inferences`` and ``repairs``,
long (B,).
"""

from __future__ import annotations

import torch
from torch import Tensor

from decpomdp.core import DecPOSMDP
from decpomdp.domains.disaster_relief import rules
from decpomdp.domains.disaster_relief.rules import (
    ACTION_NAMES,
    AT_BASE,
    AT_SITE_LOADED,
    AWAY,
    BASE2,
    CLASSES,
    COUNTERS,
    CRATE_ZONE,
    FAIL_DURATION,
    GO_CRATE,
    HANDLING_TIME,
    HOSPITAL,
    INFER,
    LOADED,
    LOADED_UNKNOWN,
    OBS_NAMES,
    PICK,
    PUT,
    REPAIR,
    REPAIR_MA,
    REPAIR_TIME,
    SAW,
)
from decpomdp.engine import EngineModel, outcome_table
from decpomdp.perception import PerceptionModel, PerfectPerception, check_class_names
from hbni_infra.checks import as_float, as_int, as_probability

_DESTINATION = torch.as_tensor(rules.DESTINATION)
_TRAVEL = torch.as_tensor(rules.TRAVEL)
_SLOWDOWN = torch.as_tensor(rules.SLOWDOWN)
_PLACED: dict[torch.device, tuple[Tensor, Tensor, Tensor]] = {}


def _tables(device: torch.device) -> tuple[Tensor, Tensor, Tensor]:
    """``(destination, travel, slowdown)`` on ``device`` (the module tables on the CPU, copies made once elsewhere)."""
    if device.type == "cpu":
        return _DESTINATION, _TRAVEL, _SLOWDOWN
    if device not in _PLACED:
        _PLACED[device] = (_DESTINATION.to(device), _TRAVEL.to(device), _SLOWDOWN.to(device))
    return _PLACED[device]


class DisasterRelief(DecPOSMDP):
    """The health-aware disaster-relief Dec-POSMDP (9 MAs, 30 macro-observations per robot).

    Args:
        perception: the model behind the ``infer`` MA (default ``PerfectPerception(6, frames=10)``); one with
            ``class_names`` must name :data:`CLASSES` in that order.
        num_agents: robots in the team (>= 1).
        gamma, horizon: discount per time unit and simulation length.
        frame_period: time units per perception frame.
        degrade_prob: probability that an MA (other than a repair) lowers health by one level.
        sensor_accuracy: probability that the health reading is right.
        wrong_penalty: reward lost for an object put down at the wrong destination.
    """

    num_actions = len(ACTION_NAMES)
    num_obs = len(OBS_NAMES)
    counters = COUNTERS

    def __init__(
        self,
        perception: PerceptionModel | None = None,
        num_agents: int = 2,
        gamma: float = 0.99,
        horizon: float = 50.0,
        frame_period: float = 0.1,
        degrade_prob: float = 0.1,
        sensor_accuracy: float = 0.8,
        wrong_penalty: float = 0.0,
    ) -> None:
        perception = PerfectPerception(len(CLASSES), frames=10) if perception is None else perception
        if not isinstance(perception, PerceptionModel):
            raise TypeError(
                f"perception: expected a PerceptionModel (num_classes and sample), got {type(perception).__name__}"
            )
        if perception.num_classes != len(CLASSES):
            raise ValueError(f"perception: expected num_classes == {len(CLASSES)}, got {perception.num_classes}")
        check_class_names(perception, CLASSES)
        self.perception, self.num_agents = perception, as_int("num_agents", num_agents, minimum=1)
        self.gamma = as_float("gamma", gamma, 0.0, 1.0, low_open=True)
        self.horizon = as_float("horizon", horizon, 0.0, low_open=True)
        self.frame_period = as_float("frame_period", frame_period, 0.0, low_open=True)
        self.degrade_prob = as_probability("degrade_prob", degrade_prob)
        self.sensor_accuracy = as_probability("sensor_accuracy", sensor_accuracy)
        self.wrong_penalty = as_float("wrong_penalty", wrong_penalty)
        self.action_names, self.obs_names = list(ACTION_NAMES), list(OBS_NAMES)

    def __repr__(self) -> str:
        return (
            f"DisasterRelief(perception={self.perception!r}, num_agents={self.num_agents}, gamma={self.gamma}, "
            f"horizon={self.horizon}, degrade_prob={self.degrade_prob}, sensor_accuracy={self.sensor_accuracy})"
        )

    def engine_model(self) -> EngineModel | None:
        """The domain for the compiled engine (``None`` when the perception model has no outcome table)."""
        table = outcome_table(self.perception)
        if table is None:
            return None
        p = rules.params(self.degrade_prob, self.sensor_accuracy, self.wrong_penalty, self.frame_period)
        return EngineModel(rules.ENGINE, p, rules.tables(), table)

    def reset(self, batch: int, generator: torch.Generator) -> dict[str, Tensor]:
        shape, dev = (batch, self.num_agents), generator.device
        return {
            "loc": (torch.arange(self.num_agents, device=dev) % 2).expand(shape).clone(),
            "carry": torch.full(shape, -1, dtype=torch.long, device=dev),
            "health": torch.zeros(shape, dtype=torch.long, device=dev),
            "ma": torch.full(shape, INFER, dtype=torch.long, device=dev),
            "ok": torch.zeros(shape, dtype=torch.bool, device=dev),
            "label": torch.zeros(shape, dtype=torch.long, device=dev),
            "frames": torch.zeros(shape, dtype=torch.long, device=dev),
            "fresh": torch.zeros(shape, dtype=torch.bool, device=dev),
            "belief": torch.full(shape, -1, dtype=torch.long, device=dev),
            "objects": torch.randint(0, len(CLASSES), (batch, 2), generator=generator, device=dev),
            **{key: torch.zeros(batch, dtype=torch.long, device=dev) for key in COUNTERS},
        }

    def _preconditions(self, state: dict[str, Tensor], actions: Tensor) -> Tensor:
        loc, carry = state["loc"], state["carry"]
        at_base = loc <= BASE2
        go = actions <= GO_CRATE
        return torch.where(
            go,
            loc != actions,  # go-to MA index equals its location index
            torch.where(
                actions == REPAIR_MA,
                True,
                torch.where(
                    actions == INFER,
                    at_base,
                    torch.where(
                        actions == PICK, at_base & (carry < 0), (carry >= 0) & (loc >= HOSPITAL) & (loc <= CRATE_ZONE)
                    ),
                ),
            ),
        )

    def start(self, state, agents, actions, t, end_time, generator):
        loc, health = state["loc"], state["health"]
        ok = self._preconditions(state, actions) & agents
        destination, travel, slowdown = _tables(loc.device)
        slow = slowdown[health]
        trip = travel[loc, actions.clamp(max=GO_CRATE)]
        to_repair = travel[loc, REPAIR]
        mean = torch.where(
            actions <= GO_CRATE,
            trip * slow,
            torch.where(actions == REPAIR_MA, to_repair * slow + REPAIR_TIME, HANDLING_TIME * slow),
        )
        noise = (
            1.0
            + rules.DURATION_NOISE
            * torch.randn(actions.shape, generator=generator, dtype=torch.float64, device=generator.device)
        ).clamp(min=rules.MIN_NOISE_FACTOR)
        duration = torch.where(ok, mean * noise, FAIL_DURATION)
        infer = ok & (actions == INFER)
        if bool(infer.any()):
            row, col = infer.nonzero(as_tuple=True)
            true_class = state["objects"][row, loc[row, col]]
            label, frames = self.perception.sample(true_class, generator)
            state["label"][row, col] = label.long()
            state["frames"][row, col] = frames.long()
            duration[row, col] = frames.to(torch.float64) * self.frame_period
        pick = ok & (actions == PICK)
        state["belief"] = torch.where(
            pick, torch.where(state["fresh"], destination[state["label"]] - HOSPITAL, -1), state["belief"]
        )
        state["fresh"] = state["fresh"] & ~(agents & ((actions <= REPAIR_MA) | pick))  # leaving or picking uses it up
        for a in range(self.num_agents):  # robots in index order: each takes what waits when it starts
            row = pick[:, a].nonzero().squeeze(1)
            if row.numel():
                base = loc[row, a]
                state["carry"][row, a] = state["objects"][row, base]
                state["objects"][row, base] = torch.randint(
                    0, len(CLASSES), (row.numel(),), generator=generator, device=generator.device
                )
        state["ma"] = torch.where(agents, actions, state["ma"])
        state["ok"] = torch.where(agents, ok, state["ok"])
        return torch.where(agents, t[:, None] + duration, end_time)

    def complete(self, state, agents, actions, t, generator):
        effective = agents & state["ok"]
        ma, loc = state["ma"], state["loc"]
        moves = effective & (ma <= GO_CRATE)
        repaired = effective & (ma == REPAIR_MA)
        loc = state["loc"] = torch.where(moves, ma.clamp(max=GO_CRATE), torch.where(repaired, REPAIR, loc))
        put = effective & (ma == PUT)
        destination = _tables(loc.device)[0]
        right = put & (destination[state["carry"].clamp(min=0)] == loc)
        wrong = put & ~right
        reward = (right.sum(dim=1) - self.wrong_penalty * wrong.sum(dim=1)).to(torch.float64)
        state["delivered"] += right.sum(dim=1)
        state["wrong"] += wrong.sum(dim=1)
        state["repairs"] += repaired.sum(dim=1)
        state["carry"] = torch.where(put, -1, state["carry"])
        inferred = effective & (ma == INFER)
        state["inferences"] += inferred.sum(dim=1)
        state["inference_frames"] += (state["frames"] * inferred).sum(dim=1)
        u = torch.rand(agents.shape + (3,), generator=generator, dtype=torch.float64, device=generator.device)
        degrade = agents & ~repaired & (u[..., 0] < self.degrade_prob)
        health = state["health"] = torch.where(repaired, 0, (state["health"] + degrade.long()).clamp(max=2))
        shift = 1 + (u[..., 2] < 0.5).long()  # a wrong reading is one of the two other levels
        reading = torch.where(u[..., 1] < self.sensor_accuracy, health, (health + shift) % 3)
        state["fresh"] = state["fresh"] | inferred
        at_base, carrying = loc <= BASE2, state["carry"] >= 0
        loaded = torch.where(state["belief"] >= 0, LOADED + state["belief"], LOADED_UNKNOWN)
        context = torch.where(
            carrying,
            torch.where(at_base, loaded, AT_SITE_LOADED),
            torch.where(inferred, SAW + destination[state["label"]] - HOSPITAL, torch.where(at_base, AT_BASE, AWAY)),
        )
        return reward, 3 * context + reading
