"""Health-aware disaster relief (after Omidshafiei et al., ICRA 2017), batched over rollouts.

A team of robots (2 by default) carries objects from two bases to their destinations. One
object waits at each base at a time and is replaced when picked up; its class is uniform over
``CLASSES``. Each class has one destination (``DESTINATION``): ambulance and medical_copter go to
the Hospital, police_car and news_copter to the Airport, food_crate and medical_crate to the
Crate_zone. A robot does not see an object's class: the ``infer`` MA runs the plugged
:class:`~decpomdp.perception.PerceptionModel` on the object waiting at its base and reports
the destination of the inferred label; it lasts ``frames * frame_period``.

MAs (per robot): go to Base1, Base2, Hospital, Airport, Crate_zone; go to the repair station
(and get repaired); infer the class of the object at the base; pick up; put down.

Health: high, medium or low. Each completed MA other than a repair degrades it by one level with
probability ``degrade_prob``; moving, picking up and putting down take ``SLOWDOWN[health]`` times
longer; the repair MA restores it to high. The robot reads its health through a sensor that is
right with probability ``sensor_accuracy`` and otherwise reports one of the two other levels.

Macro-observations (30): (context, health reading), ``obs = 3 * context + reading``, where the
context (``CONTEXTS``) is what the robot knows after its MA: ``away`` (empty-handed, not at a base),
``at_base`` (empty-handed at a base), ``saw_<destination>`` (an ``infer`` just reported a label with
that destination), ``loaded_<destination>`` (carrying, at a base, an object whose class the robot
inferred there before picking it up; ``loaded_unknown`` if it did not), ``at_site_loaded``
(carrying, away from the bases). An inference stays "fresh" until the robot picks up or leaves;
an object picked up under a fresh inference is believed to have the inferred destination (wrong if
the label was wrong, or if the partner took the inferred object first).

Constants chosen here (the paper gives no numbers): mean travel times ``TRAVEL`` (symmetric, time
units), pick-up and put-down 1, repair 1 plus the trip, duration noise ``tau * (1 + 0.3 N(0, 1))``
clamped at 10 % of ``tau`` (as in package delivery), ``SLOWDOWN = (1, 1.5, 2.5)``,
``degrade_prob = 0.1``, ``sensor_accuracy = 0.8``, ``frame_period = 0.1`` (10 frames per time
unit) and, by default, perfect perception taking 10 frames. Reward 1 per object put down at its
destination; a wrong delivery earns ``-wrong_penalty`` (default 0: nothing) and is counted.
Robot ``a`` starts at base ``a % 2`` with high health; gamma = 0.99 per time unit, horizon 50.
An MA whose preconditions fail (infer or pick up away from a base, pick up while carrying, put
down with nothing or away from a destination, go to where the robot already is) does nothing
and lasts 1. Two robots picking up at one base at the same instant: the lower index takes the
waiting object, the next takes its replacement.

State (batch first): ``loc``, ``carry`` (class or -1), ``health``, ``ma``, ``ok``, ``label``,
``frames``, ``fresh`` (an unused inference of the object at the robot's base), ``belief`` (believed
destination index of the carried object, -1 unknown) (B, A); ``objects`` (B, 2) classes waiting at the bases; counters ``delivered``,
``wrong``, ``inference_frames`` (frames of completed inferences), ``inferences`` and ``repairs``,
long (B,).
"""

from __future__ import annotations


import torch
from torch import Tensor

from decpomdp.core import DecPOSMDP
from decpomdp.perception import PerceptionModel, PerfectPerception
from infra.checks import as_float, as_int, as_probability

CLASSES = ["ambulance", "police_car", "medical_copter", "news_copter", "food_crate", "medical_crate"]
LOCATIONS = ["Base1", "Base2", "Hospital", "Airport", "Crate_zone", "Repair"]
BASE1, BASE2, HOSPITAL, AIRPORT, CRATE_ZONE, REPAIR = range(6)
#: destination location of each class
DESTINATION = torch.tensor([HOSPITAL, AIRPORT, HOSPITAL, AIRPORT, CRATE_ZONE, CRATE_ZONE])
ACTION_NAMES = ["go_base1", "go_base2", "go_hospital", "go_airport", "go_crate_zone", "go_repair", "infer", "pick_up", "put_down"]
GO_B1, GO_B2, GO_HOSPITAL, GO_AIRPORT, GO_CRATE, REPAIR_MA, INFER, PICK, PUT = range(9)
HEALTH = ["high", "medium", "low"]
_SITES = ["hospital", "airport", "crate_zone"]
CONTEXTS = ["away", "at_base", *(f"saw_{d}" for d in _SITES), *(f"loaded_{d}" for d in _SITES), "loaded_unknown", "at_site_loaded"]
AWAY, AT_BASE, SAW, LOADED, LOADED_UNKNOWN, AT_SITE_LOADED = 0, 1, 2, 5, 8, 9
OBS_NAMES = [f"{context}_{reading}" for context in CONTEXTS for reading in HEALTH]
#: mean travel time between locations (rows: from, columns: to)
TRAVEL = torch.tensor(
    [
        [0, 2, 3, 4, 3, 2],
        [2, 0, 4, 3, 3, 2],
        [3, 4, 0, 4, 4, 3],
        [4, 3, 4, 0, 4, 3],
        [3, 3, 4, 4, 0, 3],
        [2, 2, 3, 3, 3, 0],
    ],
    dtype=torch.float64,
)
SLOWDOWN = torch.tensor([1.0, 1.5, 2.5], dtype=torch.float64)
HANDLING_TIME = 1.0  # pick up, put down
REPAIR_TIME = 1.0
FAIL_DURATION = 1.0
DURATION_NOISE = 0.3
MIN_NOISE_FACTOR = 0.1
COUNTERS = ("delivered", "wrong", "inference_frames", "inferences", "repairs")


class DisasterRelief(DecPOSMDP):
    """The health-aware disaster-relief Dec-POSMDP (9 MAs, 30 macro-observations per robot).

    Args:
        perception: the model behind the ``infer`` MA (default ``PerfectPerception(6, frames=10)``).
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
            raise TypeError(f"perception: expected a PerceptionModel (num_classes and sample), got {type(perception).__name__}")
        if perception.num_classes != len(CLASSES):
            raise ValueError(f"perception: expected num_classes == {len(CLASSES)}, got {perception.num_classes}")
        self.perception, self.num_agents = perception, as_int("num_agents", num_agents, minimum=1)
        self.gamma = as_float("gamma", gamma, 0.0, 1.0, low_open=True)
        self.horizon = as_float("horizon", horizon, 0.0, low_open=True)
        self.frame_period = as_float("frame_period", frame_period, 0.0, low_open=True)
        self.degrade_prob = as_probability("degrade_prob", degrade_prob)
        self.sensor_accuracy = as_probability("sensor_accuracy", sensor_accuracy)
        self.wrong_penalty = as_float("wrong_penalty", wrong_penalty)
        self.action_names, self.obs_names = list(ACTION_NAMES), list(OBS_NAMES)

    def __repr__(self) -> str:
        return (f"DisasterRelief(perception={self.perception!r}, num_agents={self.num_agents}, gamma={self.gamma}, "
                f"horizon={self.horizon}, degrade_prob={self.degrade_prob}, sensor_accuracy={self.sensor_accuracy})")

    def reset(self, batch: int, generator: torch.Generator) -> dict[str, Tensor]:
        shape = (batch, self.num_agents)
        return {
            "loc": (torch.arange(self.num_agents) % 2).expand(shape).clone(),
            "carry": torch.full(shape, -1, dtype=torch.long),
            "health": torch.zeros(shape, dtype=torch.long),
            "ma": torch.full(shape, INFER, dtype=torch.long),
            "ok": torch.zeros(shape, dtype=torch.bool),
            "label": torch.zeros(shape, dtype=torch.long),
            "frames": torch.zeros(shape, dtype=torch.long),
            "fresh": torch.zeros(shape, dtype=torch.bool),
            "belief": torch.full(shape, -1, dtype=torch.long),
            "objects": torch.randint(0, len(CLASSES), (batch, 2), generator=generator),
            **{key: torch.zeros(batch, dtype=torch.long) for key in COUNTERS},
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
                    torch.where(actions == PICK, at_base & (carry < 0), (carry >= 0) & (loc >= HOSPITAL) & (loc <= CRATE_ZONE)),
                ),
            ),
        )

    def start(self, state, agents, actions, t, end_time, generator):
        loc, health = state["loc"], state["health"]
        ok = self._preconditions(state, actions) & agents
        slow = SLOWDOWN[health]
        trip = TRAVEL[loc, actions.clamp(max=GO_CRATE)]
        to_repair = TRAVEL[loc, REPAIR]
        mean = torch.where(
            actions <= GO_CRATE, trip * slow, torch.where(actions == REPAIR_MA, to_repair * slow + REPAIR_TIME, HANDLING_TIME * slow)
        )
        noise = (1.0 + DURATION_NOISE * torch.randn(actions.shape, generator=generator, dtype=torch.float64)).clamp(min=MIN_NOISE_FACTOR)
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
        state["belief"] = torch.where(pick, torch.where(state["fresh"], DESTINATION[state["label"]] - HOSPITAL, -1), state["belief"])
        state["fresh"] = state["fresh"] & ~(agents & ((actions <= REPAIR_MA) | pick))  # leaving or picking uses it up
        for a in range(self.num_agents):  # robots in index order: each takes what waits when it starts
            row = pick[:, a].nonzero().squeeze(1)
            if row.numel():
                base = loc[row, a]
                state["carry"][row, a] = state["objects"][row, base]
                state["objects"][row, base] = torch.randint(0, len(CLASSES), (row.numel(),), generator=generator)
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
        right = put & (DESTINATION[state["carry"].clamp(min=0)] == loc)
        wrong = put & ~right
        reward = (right.sum(dim=1) - self.wrong_penalty * wrong.sum(dim=1)).to(torch.float64)
        state["delivered"] += right.sum(dim=1)
        state["wrong"] += wrong.sum(dim=1)
        state["repairs"] += repaired.sum(dim=1)
        state["carry"] = torch.where(put, -1, state["carry"])
        inferred = effective & (ma == INFER)
        state["inferences"] += inferred.sum(dim=1)
        state["inference_frames"] += (state["frames"] * inferred).sum(dim=1)
        u = torch.rand(agents.shape + (3,), generator=generator, dtype=torch.float64)
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
            torch.where(inferred, SAW + DESTINATION[state["label"]] - HOSPITAL, torch.where(at_base, AT_BASE, AWAY)),
        )
        return reward, 3 * context + reading
