"""Health-aware disaster relief (after Omidshafiei et al., ICRA 2017): the rules, for the compiled engine.

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
and lasts 1. MAs started at the same instant see the state as it was before any of them started;
two robots picking up at one base at the same instant: the lower index takes the waiting object,
the next takes its replacement.

The rules below are what the compiled engine runs (:mod:`decpomdp.engine.loop`), one rollout at a
time. One rollout's state: team entries ``TEAM`` (the counters ``delivered``, ``wrong``,
``inference_frames`` (frames of completed inferences), ``inferences``, ``repairs``, and the class
waiting at each base) and, per robot, ``ROBOT`` (location, carried class or -1, health, current MA,
whether its preconditions held, the last inferred label and its frames, whether that inference is
fresh, and the believed destination index of the carried object or -1).
:class:`~decpomdp.domains.disaster_relief.domain.DisasterRelief` is the domain object; its batched
torch methods are the test oracle of these rules.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from decpomdp.engine import EngineDomain, StateLayout, below, normal, sample_outcome, uniform
from decpomdp.engine.loop import chunk_function, event_loop

CLASSES = ["ambulance", "police_car", "medical_copter", "news_copter", "food_crate", "medical_crate"]
LOCATIONS = ["Base1", "Base2", "Hospital", "Airport", "Crate_zone", "Repair"]
BASE1, BASE2, HOSPITAL, AIRPORT, CRATE_ZONE, REPAIR = range(6)
#: destination location of each class
DESTINATION = np.array([HOSPITAL, AIRPORT, HOSPITAL, AIRPORT, CRATE_ZONE, CRATE_ZONE], dtype=np.int64)
ACTION_NAMES = [
    "go_base1",
    "go_base2",
    "go_hospital",
    "go_airport",
    "go_crate_zone",
    "go_repair",
    "infer",
    "pick_up",
    "put_down",
]
GO_B1, GO_B2, GO_HOSPITAL, GO_AIRPORT, GO_CRATE, REPAIR_MA, INFER, PICK, PUT = range(9)
HEALTH = ["high", "medium", "low"]
_SITES = ["hospital", "airport", "crate_zone"]
CONTEXTS = [
    "away",
    "at_base",
    *(f"saw_{d}" for d in _SITES),
    *(f"loaded_{d}" for d in _SITES),
    "loaded_unknown",
    "at_site_loaded",
]
AWAY, AT_BASE, SAW, LOADED, LOADED_UNKNOWN, AT_SITE_LOADED = 0, 1, 2, 5, 8, 9
OBS_NAMES = [f"{context}_{reading}" for context in CONTEXTS for reading in HEALTH]
#: mean travel time between locations (rows: from, columns: to)
TRAVEL = np.array(
    [
        [0, 2, 3, 4, 3, 2],
        [2, 0, 4, 3, 3, 2],
        [3, 4, 0, 4, 4, 3],
        [4, 3, 4, 0, 4, 3],
        [3, 3, 4, 4, 0, 3],
        [2, 2, 3, 3, 3, 0],
    ],
    dtype=np.float64,
)
SLOWDOWN = np.array([1.0, 1.5, 2.5])
HANDLING_TIME = 1.0  # pick up, put down
REPAIR_TIME = 1.0
FAIL_DURATION = 1.0
DURATION_NOISE = 0.3
MIN_NOISE_FACTOR = 0.1
COUNTERS = ("delivered", "wrong", "inference_frames", "inferences", "repairs")

TEAM = COUNTERS + ("object_base1", "object_base2")
ROBOT = ("loc", "carry", "health", "ma", "ok", "label", "frames", "fresh", "belief")
DELIVERED, WRONG, INFERENCE_FRAMES, INFERENCES, REPAIRS, OBJECT = range(6)  # OBJECT + base: the class waiting there
LOC, CARRY, HEALTH_LEVEL, MA, OK, LABEL, FRAMES, FRESH, BELIEF = range(len(ROBOT))
_T, _R = len(TEAM), len(ROBOT)
#: entries of the parameter vector (see :func:`params`)
P_DEGRADE, P_SENSOR, P_PENALTY, P_FRAME_PERIOD, P_NOISE, P_MIN_NOISE = range(6)


def params(degrade_prob: float, sensor_accuracy: float, wrong_penalty: float, frame_period: float) -> np.ndarray:
    """The parameter vector of one domain instance (module constants read now, so a test may patch them)."""
    return np.array([degrade_prob, sensor_accuracy, wrong_penalty, frame_period, DURATION_NOISE, MIN_NOISE_FACTOR])


def tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The constant tables the rules read: ``(TRAVEL, SLOWDOWN, DESTINATION)``."""
    return TRAVEL.copy(), SLOWDOWN.copy(), DESTINATION.copy()


@njit
def at(a, field):
    """Index of robot ``a``'s entry ``field`` in the int state."""
    return _T + _R * a + field


@njit(inline="always")
def reset(si, sf, p, tab, perception, num_agents, rng):
    """Robot ``a`` at base ``a % 2``, empty-handed, high health; a random object at each base."""
    si[OBJECT] = below(rng, 6)
    si[OBJECT + 1] = below(rng, 6)
    for a in range(num_agents):
        si[at(a, LOC)] = a % 2
        si[at(a, CARRY)] = -1
        si[at(a, MA)] = INFER
        si[at(a, BELIEF)] = -1


@njit
def may_start(si, a, ma):
    """Whether robot ``a`` may start ``ma``: the preconditions."""
    loc, carry = si[at(a, LOC)], si[at(a, CARRY)]
    if ma <= GO_CRATE:
        return loc != ma  # a go-to MA's index is its location's
    if ma == REPAIR_MA:
        return True
    if ma == INFER:
        return loc <= BASE2
    if ma == PICK:
        return loc <= BASE2 and carry < 0
    return carry >= 0 and HOSPITAL <= loc <= CRATE_ZONE  # put down


@njit
def mean_duration(si, tab, a, ma):
    """Mean duration of ``ma`` for robot ``a``: travel or handling time, slowed down by its health."""
    travel, slowdown, _ = tab
    loc, slow = si[at(a, LOC)], slowdown[si[at(a, HEALTH_LEVEL)]]
    if ma <= GO_CRATE:
        return travel[loc, ma] * slow
    if ma == REPAIR_MA:
        return travel[loc, REPAIR] * slow + REPAIR_TIME
    return HANDLING_TIME * slow


@njit(inline="always")
def start(si, sf, p, tab, perception, agents, actions, t, end, rng):
    """Flagged robots begin ``actions``; all of them see the state before any of them started, then
    the pick-ups take the objects in robot order."""
    destination = tab[2]
    for a in range(len(agents)):
        if not agents[a]:
            continue
        ma = actions[a]
        ok = may_start(si, a, ma)
        duration = FAIL_DURATION
        if ok and ma == INFER:
            label, frames = sample_outcome(perception, si[OBJECT + si[at(a, LOC)]], rng)
            si[at(a, LABEL)], si[at(a, FRAMES)] = label, frames
            duration = frames * p[P_FRAME_PERIOD]
        elif ok:
            duration = mean_duration(si, tab, a, ma) * max(1.0 + p[P_NOISE] * normal(rng), p[P_MIN_NOISE])
        if ok and ma == PICK:  # what the robot believes it carries
            fresh = si[at(a, FRESH)] == 1
            si[at(a, BELIEF)] = destination[si[at(a, LABEL)]] - HOSPITAL if fresh else -1
        if ma <= REPAIR_MA or (ok and ma == PICK):  # leaving or picking up uses the inference up
            si[at(a, FRESH)] = 0
        si[at(a, MA)], si[at(a, OK)] = ma, ok
        end[a] = t + duration
    for a in range(len(agents)):
        if agents[a] and si[at(a, OK)] == 1 and si[at(a, MA)] == PICK:
            base = OBJECT + si[at(a, LOC)]
            si[at(a, CARRY)] = si[base]
            si[base] = below(rng, 6)


@njit(inline="always")
def complete(si, sf, p, tab, perception, agents, actions, t, obs, rng):
    """Flagged robots finish their MAs: move, deliver, count; health degrades; each reads its context."""
    destination = tab[2]
    reward = 0.0
    for a in range(len(agents)):
        if not agents[a]:
            continue
        ma, effective = si[at(a, MA)], si[at(a, OK)] == 1
        repaired = effective and ma == REPAIR_MA
        if effective and ma <= GO_CRATE:
            si[at(a, LOC)] = ma
        elif repaired:
            si[at(a, LOC)] = REPAIR
            si[REPAIRS] += 1
        loc = si[at(a, LOC)]
        if effective and ma == PUT:
            if destination[si[at(a, CARRY)]] == loc:
                reward += 1.0
                si[DELIVERED] += 1
            else:
                reward -= p[P_PENALTY]
                si[WRONG] += 1
            si[at(a, CARRY)] = -1
        inferred = effective and ma == INFER
        if inferred:
            si[INFERENCES] += 1
            si[INFERENCE_FRAMES] += si[at(a, FRAMES)]
            si[at(a, FRESH)] = 1
        health = si[at(a, HEALTH_LEVEL)]
        if repaired:
            health = 0
        elif uniform(rng) < p[P_DEGRADE]:
            health = min(health + 1, 2)
        si[at(a, HEALTH_LEVEL)] = health
        reading = health
        if uniform(rng) >= p[P_SENSOR]:  # a wrong reading is one of the two other levels
            reading = (health + 1 + (uniform(rng) < 0.5)) % 3
        at_base = loc <= BASE2
        if si[at(a, CARRY)] >= 0:
            belief = si[at(a, BELIEF)]
            context = (LOADED + belief if belief >= 0 else LOADED_UNKNOWN) if at_base else AT_SITE_LOADED
        elif inferred:
            context = SAW + destination[si[at(a, LABEL)]] - HOSPITAL
        else:
            context = AT_BASE if at_base else AWAY
        obs[a] = 3 * context + reading
    return reward


@chunk_function
def chunk(args, out, scratch, index, lo, hi):
    """The engine's event loop with these rules, on rollouts ``lo .. hi - 1``."""
    return event_loop(reset, start, complete, args, out, scratch, index, lo, hi)


ENGINE = EngineDomain(chunk, StateLayout(team=TEAM, robot=ROBOT), COUNTERS)
