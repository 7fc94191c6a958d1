"""Package delivery, the reference Dec-POSMDP of the G-DICE paper (Omidshafiei et al., ICRA 2016).

Two robots move between five belief nodes, Base1, Base2, Rendezvous, Dest1 and Dest2. A package
always waits at each base; small packages are carried by one robot, large ones need a joint
pick-up and a joint put-down by both robots at the same place.

Constants taken from the reference simulator (the MATLAB ``Domain`` class that accompanies the
paper, after Amato et al., ICRA 2015):

* mean durations ``MEAN_DURATION[ma, start node]`` (NaN: the MA cannot start there); joint MAs
  last 1.5 times their solo counterparts; duration noise ``tau * (1 + 0.3 N(0, 1))``;
* package arrival: a package always waits at each base and is replaced the moment it is picked
  up; its destination is uniform over {Dest1, Dest2, Rendezvous}; packages bound for the
  Rendezvous are small, the others small or large with probability 1/2 each;
* rewards 1 (small) and 3 (large) for a package put down at its destination, the large-package
  reward credited to *each* robot of the joint put-down (the reference adds it once per robot, so
  a large package is worth 6 to the team; ``large_reward_per_robot=False`` credits it once);
* 13 macro-observations: ``none`` away from the bases, otherwise (size, destination, partner
  present) of the package waiting at the base, or of the package just picked up;
* both robots start at Base1; gamma = 0.99 per time unit; horizon 50.

Choices where the paper and reference are silent or differ (documented constants):

* time is continuous: durations are not rounded, and the noise factor is clamped at
  ``MIN_NOISE_FACTOR`` so durations stay positive; ``wait`` lasts exactly 1;
* an MA whose preconditions fail (wrong place, wrong load, solo pick-up of a large package, a
  joint MA without the partner, ...) does nothing and lasts ``FAIL_DURATION`` (the reference makes
  a failed MA end at the next time step);
* a joint MA needs both robots at the same node with the same load (both empty for a joint
  pick-up, the same large package otherwise). A robot starting one drafts its partner, as the
  reference's "forced partner" rule does: a partner starting an MA at the same instant, or
  finishing its MA there while the first robot waits (up to ``joint_wait`` time units), runs the
  joint MA instead of its own choice (robot 0 leads when both start joint MAs at once); the two
  run it with one sampled duration and finish at the same instant. A joint MA whose wait runs
  out fails. The reference also let a single robot run a joint MA alone (and forced the partner
  only when both decided in the same step); ``solo_joint=True`` restores the first rule: a joint
  MA without its partner then runs at once with the robot alone (it still drafts a partner that
  is there);
* preconditions: go-to MAs need a defined mean duration from the current node and no large load;
  joint go-to MAs need a large load; pick-up needs an empty robot at a base holding a small
  package (joint pick-up: a large one); put-down needs a small load at Dest1/Dest2 (joint
  put-down: a large load); place on truck needs a small load at the Rendezvous;
* truck semantics: a small package bound for the Rendezvous and placed on the truck there counts
  as delivered right and earns ``truck_reward`` (default 1, the small-package reward; the
  reference awards 0);
* a package put down (or placed on the truck) at the wrong destination earns nothing, is gone,
  and increments the ``wrong`` counter;
* MAs started at the same instant see the state as it was before any of them started, except
  that two robots cannot take one package: when both start a pick-up at the same base at once,
  robot 0 takes the package and robot 1's pick-up fails;
* the partner is "present" at a base when it is located there and not travelling away;
* the first MA is chosen in controller node 0 before any observation;
* ``successor_rule=True`` (off by default) adds two rules of the reference simulator: an MA that is
  not an allowed successor of the robot's previous MA (``REFERENCE_SUCCESSORS``; the previous MA is the
  one last started, failed or not, and go-to-Base1 at the start) fails, and a put-down or joint
  put-down that fails by this rule alone (its own preconditions hold) still delivers and pays when it
  ends, as in the reference, which pays any put-down whose robot holds a package of the right size at
  its destination when the MA ends, failed or not (repository 7thStringofZhef/G-DICE, file
  "Original G-DICE/@Domain/Domain.m", lines 269, 286-300 and 415-416);
* ``reference_pickup=True`` (off by default) adds the reference's loading rules: a pick-up or joint
  pick-up takes whatever package waits at the robot's base, whatever its size, replacing anything the
  robot carried, and go-to MAs accept any load. The reference loads the base's package into the robot
  when it chooses a pick-up, overwriting its load, before it checks the size, and a size mismatch only
  fails the MA (the package stays loaded; Domain.m lines 351-356 and 366-367); the base gets a new
  package when the robot next starts an MA other than wait (line 369), here at once; and it has no
  load preconditions on moves.

State (batch first): ``loc`` (B, 2) node of each robot (updated when a go-to MA completes);
``load`` (B, 2) carried package (0: none, else ``1 + package code``); ``base`` (B, 2) package code
waiting at Base1/Base2; ``ma``, ``ok``, ``waiting`` (B, 2) each robot's current MA, whether its
preconditions held, and whether it still waits for its partner. Package codes (``PACKAGES``):
0 small->Dest1, 1 small->Dest2, 2 small->Rendezvous, 3 large->Dest1, 4 large->Dest2.
Per-rollout counters: ``delivered`` (packages delivered right), ``delivered_large`` and ``wrong``
(wrong deliveries), all long (B,).

This module states the rules and holds them for the compiled engine (:func:`start` and
:func:`complete` below, over lookup tables of the preconditions, durations and drop rewards built from
:func:`preconditions_hold` and :class:`Rewards`); :mod:`decpomdp.domains.package_delivery.domain`
runs the same rules on a batch of rollouts in torch, the test oracle of the engine. One rollout's
state for the engine: team entries ``TEAM`` (the counters, then the package codes waiting at
Base1 and Base2) and, per robot, ``ROBOT`` (node, load, current MA, whether its preconditions held,
whether it waits for its partner, whether a failed put-down still pays).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch
from numba import njit

from decpomdp.engine import EngineDomain, StateLayout, below, normal
from decpomdp.engine.loop import chunk_function, event_loop_two_agents

NODE_NAMES = ["Base1", "Base2", "Rendezvous", "Dest1", "Dest2"]
BASE1, BASE2, RENDEZVOUS, DEST1, DEST2 = range(5)
ACTION_NAMES = [
    "go_base1",
    "go_base2",
    "go_rendezvous",
    "go_dest1",
    "go_dest2",
    "joint_go_dest1",
    "joint_go_dest2",
    "pick_up",
    "joint_pick_up",
    "put_down",
    "joint_put_down",
    "place_on_truck",
    "wait",
]
(GO_B1, GO_B2, GO_R, GO_D1, GO_D2, JGO_D1, JGO_D2, PICK, JPICK, PUT, JPUT, TRUCK, WAIT) = range(13)
SMALL, LARGE = 1, 2
_SIZES, _DESTS = ("small", "large"), ("dest1", "dest2", "rendezvous")
OBS_NAMES = ["none"] + [f"{size}_{dest}_{who}" for who in ("alone", "partner") for size in _SIZES for dest in _DESTS]

_nan = math.nan
#: mean duration of each MA (rows, ACTION_NAMES order) from each start node (columns, NODE_NAMES order)
MEAN_DURATION = torch.tensor(
    [
        [_nan, 2, 4, 3, 2],
        [2, _nan, 4, 2, 4],
        [3, 4, _nan, _nan, _nan],
        [3, 2, _nan, _nan, _nan],
        [2, 4, _nan, _nan, _nan],
        [4.5, 3, _nan, _nan, _nan],
        [3, 6, _nan, _nan, _nan],
        [1, 1, _nan, _nan, _nan],
        [1.5, 1.5, _nan, _nan, _nan],
        [_nan, _nan, _nan, 1, 1],
        [_nan, _nan, _nan, 1.5, 1.5],
        [_nan, _nan, 1, _nan, _nan],
        [1, 1, 1, 1, 1],
    ],
    dtype=torch.float64,
)
#: node each go-to MA ends at (-1: the MA does not move the robot)
TARGET_NODE = [BASE1, BASE2, RENDEZVOUS, DEST1, DEST2, DEST1, DEST2, -1, -1, -1, -1, -1, -1]
#: (size, destination node) of each package code
PACKAGES = [(SMALL, DEST1), (SMALL, DEST2), (SMALL, RENDEZVOUS), (LARGE, DEST1), (LARGE, DEST2)]
#: package codes drawn uniformly from this list: destination uniform, Rendezvous-bound ones small,
#: the others small or large with probability 1/2
ARRIVAL = torch.tensor([0, 1, 2, 2, 3, 4], dtype=torch.int32)
DURATION_NOISE = 0.3
MIN_NOISE_FACTOR = 0.1
FAIL_DURATION = 1.0
JOINT_MAS = (JGO_D1, JGO_D2, JPICK, JPUT)
DROP_MAS = (PUT, JPUT, TRUCK)
#: per-rollout counters kept in the state, long (B,)
COUNTERS = ("delivered", "delivered_large", "wrong")
#: MAs allowed to follow each MA in the reference simulator (its ``allowableChildTMAsIdxsTemp``, repository
#: 7thStringofZhef/G-DICE, file "Original G-DICE/@Domain/Domain.m", lines 60, 68, 76, 84, 92, 104, 112,
#: 125, 133, 146, 154, 166 and 178); used by ``successor_rule``
REFERENCE_SUCCESSORS = {
    GO_B1: (GO_B2, GO_R, PICK, JPICK),
    GO_B2: (GO_B1, GO_R, PICK, JPICK),
    GO_R: (GO_B1, GO_B2, TRUCK),
    GO_D1: (GO_B1, GO_B2, PUT),
    GO_D2: (GO_B1, GO_B2, PUT),
    JGO_D1: (JPUT,),
    JGO_D2: (JPUT,),
    PICK: (GO_R, GO_D1, GO_D2),
    JPICK: (JGO_D1, JGO_D2),
    PUT: (GO_B1, GO_B2),
    JPUT: (GO_B1, GO_B2),
    TRUCK: (GO_B1, GO_B2),
    WAIT: (WAIT,),
}


def preconditions_hold(loc: int, load: int, here: int, ma: int, reference_pickup: bool = False) -> bool:
    """Whether a robot at ``loc`` with ``load``, seeing package ``here`` at its base, may start ``ma``.

    Only the robot's own state is checked; a joint MA also needs its partner (see the module doc).
    With ``reference_pickup`` (see the module doc) go-to MAs accept any load, and a (joint) pick-up any
    package by a robot carrying anything.
    """
    if ma == WAIT:
        return True
    if math.isnan(float(MEAN_DURATION[ma, loc])):
        return False
    size = PACKAGES[load - 1][0] if load else 0
    if ma <= GO_D2:
        return reference_pickup or size != LARGE
    if ma in (JGO_D1, JGO_D2, JPUT):
        return size == LARGE
    if ma in (PICK, JPICK):
        return reference_pickup or (size == 0 and PACKAGES[here][0] == (SMALL if ma == PICK else LARGE))
    return size == SMALL  # put down, place on truck


@dataclass(frozen=True)
class Rewards:
    """What a package delivered right earns.

    Attributes:
        small, large, truck: reward of a small package put down at its destination, a large one
            (joint put-down), and a Rendezvous-bound one placed on the truck.
        large_per_robot: credit ``large`` to each robot of the joint put-down (the reference's
            accounting) instead of once per package.
    """

    small: float = 1.0
    large: float = 3.0
    truck: float = 1.0
    large_per_robot: bool = True

    def for_drop(self, ma: int, load: int, loc: int, robots: int = 2) -> tuple[float, bool]:
        """(reward credited to one robot, delivered right?) when ``ma`` in ``DROP_MAS`` completes at
        ``loc`` carrying ``load``; ``robots`` run a joint put-down together (1 only with ``solo_joint``)."""
        size, dest = PACKAGES[load - 1]
        if dest != loc:
            return 0.0, False
        if ma == JPUT:
            return (self.large if self.large_per_robot else self.large / robots), True
        return (self.truck if ma == TRUCK else self.small), True


# ---- the rules for the compiled engine -------------------------------------------------------------

TEAM = COUNTERS + ("base1", "base2")
ROBOT = ("loc", "load", "ma", "ok", "waiting", "pays")
DELIVERED, DELIVERED_LARGE, WRONG, BASE = range(4)  # BASE + base index: the package code waiting there
LOC, LOAD, MA, OK, WAITING, PAYS = range(len(ROBOT))
_T, _R = len(TEAM), len(ROBOT)
_N_LOC, _N_LOAD, _N_PKG, _N_MA = 5, 6, 5, 13
NOISY, OK_BIT, JOINT_OK, SOLO_PICK_OK = 1, 2, 4, 8  # bits of the start table's flags
GO_KIND, DROP_KIND, PICK_KIND, JPUT_KIND = 1, 2, 4, 8  # bits of MA_KIND
#: entries of the parameter vector (see :func:`params`)
P_JOINT_WAIT, P_NOISE, P_MIN_NOISE, P_SOLO_JOINT, P_SUCCESSOR_RULE, P_LARGE_PER_ROBOT = range(6)


@functools.cache  # once per setting: a planner asks for the tables at every batch of rollouts
def start_tables(reference_pickup: bool) -> tuple[np.ndarray, np.ndarray]:
    """``(flags, mean)`` over ``((loc * 6 + load) * 5 + here) * 13 + ma`` (``here``: the package waiting at the
    robot's base): int64 bits ``OK_BIT`` (preconditions hold), ``JOINT_OK`` (a joint MA whose preconditions
    hold), ``SOLO_PICK_OK`` (a pick-up whose preconditions hold) and ``NOISY`` (its duration is noisy:
    preconditions hold and the MA is not ``wait``); float64 mean durations (``FAIL_DURATION`` where they fail)."""
    n = _N_LOC * _N_LOAD * _N_PKG * _N_MA
    flags, mean = np.zeros(n, dtype=np.int64), np.zeros(n)
    i = 0
    for loc in range(_N_LOC):
        for load in range(_N_LOAD):
            for here in range(_N_PKG):
                for ma in range(_N_MA):
                    ok = preconditions_hold(loc, load, here, ma, reference_pickup)
                    flags[i] = ok * (
                        OK_BIT + JOINT_OK * (ma in JOINT_MAS) + SOLO_PICK_OK * (ma == PICK) + NOISY * (ma != WAIT)
                    )
                    mean[i] = float(MEAN_DURATION[ma, loc]) if ok else FAIL_DURATION
                    i += 1
    return flags, mean


@functools.cache  # once per setting: a planner asks for the tables at every batch of rollouts
def drop_tables(rewards: Rewards) -> tuple[np.ndarray, np.ndarray]:
    """``(reward, counts)`` over ``(ma * 5 + loc) * 6 + load`` for a drop MA completing: float64 reward credited
    to one robot, int64 (n, 3) increments of (delivered, delivered_large, wrong)."""
    n = _N_MA * _N_LOC * _N_LOAD
    reward, counts = np.zeros(n), np.zeros((n, 3), dtype=np.int64)
    i = 0
    for ma in range(_N_MA):
        for loc in range(_N_LOC):
            for load in range(_N_LOAD):
                if ma in DROP_MAS and load and preconditions_hold(loc, load, 0, ma):
                    reward[i], right = rewards.for_drop(ma, load, loc)
                    counts[i] = (right, right and ma == JPUT, not right)
                i += 1
    return reward, counts


@functools.cache  # once per setting: a planner asks for the tables at every batch of rollouts
def ma_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(kind, target, successor)``: int64 (13,) bits ``GO_KIND``/``DROP_KIND``/``PICK_KIND``/``JPUT_KIND`` of
    each MA, (13,) the node each go-to MA ends at (0 for others), (13 * 13,) whether MA ``n`` may follow ``m``
    at ``m * 13 + n`` (``REFERENCE_SUCCESSORS``)."""
    kind = np.array(
        [
            GO_KIND * (node >= 0)
            + DROP_KIND * (m in DROP_MAS)
            + PICK_KIND * (m in (PICK, JPICK))
            + JPUT_KIND * (m == JPUT)
            for m, node in enumerate(TARGET_NODE)
        ],
        dtype=np.int64,
    )
    target = np.array([max(node, 0) for node in TARGET_NODE], dtype=np.int64)
    successor = np.zeros(_N_MA * _N_MA, dtype=np.int64)
    for prev, nexts in REFERENCE_SUCCESSORS.items():
        successor[[prev * _N_MA + n for n in nexts]] = 1
    return kind, target, successor


def params(joint_wait: float, solo_joint: bool, successor_rule: bool, large_per_robot: bool) -> np.ndarray:
    """The parameter vector of one domain instance (module constants read now, so a test may patch them)."""
    return np.array(
        [joint_wait, DURATION_NOISE, MIN_NOISE_FACTOR, solo_joint, successor_rule, large_per_robot], dtype=np.float64
    )


def tables(reference_pickup: bool, rewards: Rewards) -> tuple:
    """``(start flags, start means, drop rewards, drop counts, MA kinds, targets, successors, arrival codes)``."""
    arrival = np.asarray(ARRIVAL, dtype=np.int64)  # read at call time, so a test can pin the package stream
    return (*start_tables(reference_pickup), *drop_tables(rewards), *ma_tables(), arrival)


@njit
def at(a, field):
    """Index of robot ``a``'s entry ``field`` in the int state."""
    return _T + _R * a + field


@njit
def new_package(tab, rng):
    """A package code for a base that has just been emptied."""
    arrival = tab[7]
    return arrival[below(rng, arrival.shape[0])]


@njit
def waiting_here(si, a):
    """The package waiting at robot ``a``'s base (Base1's away from the bases)."""
    return si[BASE + 1] if si[at(a, LOC)] == BASE2 else si[BASE]


@njit
def situation(si, a, ma, here):
    """Index of robot ``a`` beginning ``ma`` with ``here`` at its base in the start tables (unsigned: numba adds
    no negative-index wraparound to a lookup with it)."""
    return np.uint64(((si[at(a, LOC)] * _N_LOAD + si[at(a, LOAD)]) * _N_PKG + here) * _N_MA + ma)


@njit(inline="always")
def reset(si, sf, p, tab, perception, num_agents, rng):
    """Both robots at Base1, empty; a new package at each base."""
    si[BASE] = new_package(tab, rng)
    si[BASE + 1] = new_package(tab, rng)
    for a in range(2):
        si[at(a, MA)] = GO_B1 if p[P_SUCCESSOR_RULE] > 0 else WAIT


@njit(inline="always")
def start(si, sf, p, tab, perception, agents, actions, t, end, rng):
    """Flagged robots begin ``actions``: drafting into joint MAs, preconditions, durations, pick-ups, then the
    synchronisation of joint MAs (see the module doc). Both see the state before either started."""
    flags_of, successor = tab[0], tab[6]
    go0, go1 = agents[0], agents[1]
    here0, here1 = waiting_here(si, 0), waiting_here(si, 1)
    act0, act1 = actions[0], actions[1]
    f0 = flags_of[situation(si, 0, act0, here0)] if go0 else 0
    f1 = flags_of[situation(si, 1, act1, here1)] if go1 else 0
    waits0, waits1 = si[at(0, WAITING)] == 1, si[at(1, WAITING)] == 1
    joint0, joint1 = (f0 & JOINT_OK) != 0, (f1 & JOINT_OK) != 0
    drafts0, drafts1 = go0 and waits1, go1 and waits0  # a partner waits in a joint MA
    if drafts0 or drafts1 or (joint0 and go1) or (joint1 and go0):
        same = si[at(0, LOC)] == si[at(1, LOC)] and si[at(0, LOAD)] == si[at(1, LOAD)]
        d0 = si[at(1, MA)] if drafts0 and same else act0
        d1 = si[at(0, MA)] if drafts1 and same else act1
        both = go0 and go1 and same
        act0 = d1 if both and joint1 and not joint0 else d0  # robot 0 leads when both start joint MAs
        act1 = d0 if both and joint0 else d1
        f0 = flags_of[situation(si, 0, act0, here0)] if go0 else 0
        f1 = flags_of[situation(si, 1, act1, here1)] if go1 else 0
    if p[P_SUCCESSOR_RULE] > 0:  # an MA that may not follow the previous one fails; a put-down failing so still pays
        if go0:
            allowed = successor[si[at(0, MA)] * _N_MA + act0] == 1
            si[at(0, PAYS)] = (f0 & OK_BIT) != 0 and not allowed and (act0 == PUT or act0 == JPUT)
            f0 = f0 if allowed else 0
        if go1:
            allowed = successor[si[at(1, MA)] * _N_MA + act1] == 1
            si[at(1, PAYS)] = (f1 & OK_BIT) != 0 and not allowed and (act1 == PUT or act1 == JPUT)
            f1 = f1 if allowed else 0
    m0 = tab[1][situation(si, 0, act0, here0)] if f0 & OK_BIT else FAIL_DURATION
    m1 = tab[1][situation(si, 1, act1, here1)] if f1 & OK_BIT else FAIL_DURATION
    finish0 = t + m0 * ((max(p[P_NOISE] * normal(rng), p[P_MIN_NOISE] - 1.0) + 1.0) if f0 & NOISY else 1.0)
    finish1 = t + m1 * ((max(p[P_NOISE] * normal(rng), p[P_MIN_NOISE] - 1.0) + 1.0) if f1 & NOISY else 1.0)
    ok0, ok1 = (f0 & OK_BIT) != 0, (f1 & OK_BIT) != 0
    pick0, pick1 = (f0 & SOLO_PICK_OK) != 0, (f1 & SOLO_PICK_OK) != 0
    if pick0 and pick1 and si[at(0, LOC)] == si[at(1, LOC)]:  # both pick up at one base at once: robot 0 takes it
        ok1, pick1, finish1 = False, False, t + FAIL_DURATION
    if go0:
        si[at(0, MA)], si[at(0, OK)] = act0, ok0
    if go1:
        si[at(1, MA)], si[at(1, OK)] = act1, ok1
    if pick0:
        si[at(0, LOAD)] = here0 + 1
        si[BASE + si[at(0, LOC)]] = new_package(tab, rng)
    if pick1:
        si[at(1, LOAD)] = here1 + 1
        si[BASE + si[at(1, LOC)]] = new_package(tab, rng)
    joined0 = joined1 = False
    joint0, joint1 = (f0 & JOINT_OK) != 0, (f1 & JOINT_OK) != 0
    if joint0 or joint1:
        same = (
            si[at(0, LOC)] == si[at(1, LOC)] and si[at(0, LOAD)] == si[at(1, LOAD)] and si[at(0, MA)] == si[at(1, MA)]
        )
        joins0, joins1 = joint0 and waits1 and same, joint1 and waits0 and same  # a partner waits: join it
        together = joint0 and joint1 and same  # both start it now: robot 0's duration
        if together:
            finish1 = finish0
        alone0 = joint0 and not joins0 and not together
        alone1 = joint1 and not joins1 and not together
        hold0, hold1 = alone0 and p[P_SOLO_JOINT] == 0, alone1 and p[P_SOLO_JOINT] == 0  # wait for the partner
        if hold0:
            finish0 = t + p[P_JOINT_WAIT]
        if hold1:
            finish1 = t + p[P_JOINT_WAIT]
        joined0, joined1 = joins1, joins0
        if joined0:
            finish0 = finish1
        elif joined1:
            finish1 = finish0
        si[at(0, WAITING)] = (waits0 and not joined0) or hold0
        si[at(1, WAITING)] = (waits1 and not joined1) or hold1
        if (joins0 or joins1 or together) and si[at(0, MA)] == JPICK:  # a joint pick-up lifts the package
            si[at(0, LOAD)] = si[at(1, LOAD)] = here0 + 1
            si[BASE + si[at(0, LOC)]] = new_package(tab, rng)
        if p[P_SOLO_JOINT] > 0:  # the reference's rule: a joint pick-up alone
            if alone0 and si[at(0, MA)] == JPICK:
                si[at(0, LOAD)] = here0 + 1
                si[BASE + si[at(0, LOC)]] = new_package(tab, rng)
            if alone1 and si[at(1, MA)] == JPICK:
                si[at(1, LOAD)] = here1 + 1
                si[BASE + si[at(1, LOC)]] = new_package(tab, rng)
    if go0 or joined0:
        end[0] = finish0
    if go1 or joined1:
        end[1] = finish1


@njit(inline="always")
def complete(si, sf, p, tab, perception, agents, actions, t, obs, rng):
    """Flagged robots finish their MAs: move, drop (reward and counters), pick-ups seen, observations."""
    drop_reward, drop_counts, kind_of, target = tab[2], tab[3], tab[4], tab[5]
    k0 = kind_of[si[at(0, MA)]] if si[at(0, OK)] == 1 and si[at(0, WAITING)] == 0 else 0
    k1 = kind_of[si[at(1, MA)]] if si[at(1, OK)] == 1 and si[at(1, WAITING)] == 0 else 0
    travelling0, travelling1 = (k0 & GO_KIND) != 0 and not agents[0], (k1 & GO_KIND) != 0 and not agents[1]
    reward = 0.0
    kind = (k0 if agents[0] else 0, k1 if agents[1] else 0)
    jput = (kind[0] & JPUT_KIND) != 0 and (kind[1] & JPUT_KIND) != 0  # a joint put-down by both robots
    for a in range(2):
        if not agents[a]:
            continue
        si[at(a, WAITING)] = 0  # a wait that runs out is a failed joint MA
        k, ma = kind[a], si[at(a, MA)]
        if k & GO_KIND:
            si[at(a, LOC)] = target[ma]
        dropped = (k & DROP_KIND) != 0
        if p[P_SUCCESSOR_RULE] > 0:  # a put-down that failed by the successor rule alone pays
            dropped = dropped or si[at(a, PAYS)] == 1
            si[at(a, PAYS)] = 0
        if dropped:
            i = np.uint64((ma * _N_LOC + si[at(a, LOC)]) * _N_LOAD + si[at(a, LOAD)])
            credit = drop_reward[i]
            if p[P_LARGE_PER_ROBOT] == 0 and (k & JPUT_KIND) and not jput:
                credit *= 2.0  # a solo joint put-down gets the whole reward
            reward += credit
            if not (a == 1 and jput):  # a joint put-down by both robots counts once
                for j in range(3):
                    si[DELIVERED + j] += drop_counts[i, j]
            si[at(a, LOAD)] = 0
    for a in range(2):
        if agents[a]:
            loc = si[at(a, LOC)]
            if loc > BASE2:
                obs[a] = 0  # none
            else:
                package = si[at(a, LOAD)] - 1 if kind[a] & PICK_KIND else waiting_here(si, a)
                partner = loc == si[at(1 - a, LOC)] and not (travelling1 if a == 0 else travelling0)
                obs[a] = 1 + 6 * partner + package
    return reward


@chunk_function
def chunk(args, out, scratch, index, lo, hi):
    """The engine's event loop for two robots with these rules, on rollouts ``lo .. hi - 1``."""
    return event_loop_two_agents(reset, start, complete, args, out, scratch, index, lo, hi)


ENGINE = EngineDomain(chunk, StateLayout(team=TEAM, robot=ROBOT), COUNTERS)
