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

This module states the rules; :mod:`decpomdp.domains.package_delivery.batched` compiles them into
lookup tables and runs them on a batch of rollouts (:class:`PackageDelivery`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

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
OBS_NAMES = ["none"] + [
    f"{size}_{dest}_{who}" for who in ("alone", "partner") for size in _SIZES for dest in _DESTS
]

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
    GO_B1: (GO_B2, GO_R, PICK, JPICK), GO_B2: (GO_B1, GO_R, PICK, JPICK), GO_R: (GO_B1, GO_B2, TRUCK),
    GO_D1: (GO_B1, GO_B2, PUT), GO_D2: (GO_B1, GO_B2, PUT), JGO_D1: (JPUT,), JGO_D2: (JPUT,),
    PICK: (GO_R, GO_D1, GO_D2), JPICK: (JGO_D1, JGO_D2), PUT: (GO_B1, GO_B2), JPUT: (GO_B1, GO_B2),
    TRUCK: (GO_B1, GO_B2), WAIT: (WAIT,),
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
