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
* the first MA is chosen in controller node 0 before any observation.

State (batch first): ``loc`` (B, 2) node of each robot (updated when a go-to MA completes);
``load`` (B, 2) carried package (0: none, else ``1 + package code``); ``base`` (B, 2) package code
waiting at Base1/Base2; ``ma``, ``ok``, ``waiting`` (B, 2) each robot's current MA, whether its
preconditions held, and whether it still waits for its partner. Package codes (``PACKAGES``):
0 small->Dest1, 1 small->Dest2, 2 small->Rendezvous, 3 large->Dest1, 4 large->Dest2.
Per-rollout counters: ``delivered`` (packages delivered right), ``delivered_large`` and ``wrong``
(wrong deliveries), all long (B,).

The rules are compiled into lookup tables over (location, load, package at the base, MA) so that
a batch step is a handful of gathers and elementwise ops.
"""

from __future__ import annotations

import math
import sys

import torch
from torch import Tensor

from decpomdp.core import DecPOSMDP

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
_DEST_ORDER = (DEST1, DEST2, RENDEZVOUS)  # destination order inside the observation index
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
_ARRIVAL = torch.tensor([0, 1, 2, 2, 3, 4], dtype=torch.int32)
DURATION_NOISE = 0.3
MIN_NOISE_FACTOR = 0.1
FAIL_DURATION = 1.0
JOINT_MAS = (JGO_D1, JGO_D2, JPICK, JPUT)
DROP_MAS = (PUT, JPUT, TRUCK)
#: per-rollout counters kept in the state, long (B,)
COUNTERS = ("delivered", "delivered_large", "wrong")
_N_LOC, _N_LOAD, _N_PKG, _N_MA = 5, 6, 5, 13
_COUNT_BITS, _COUNT_MASK = 8, 255  # counters packed in one int32 per event (at most 2 per event each)


def preconditions_hold(loc: int, load: int, here: int, ma: int) -> bool:
    """Whether a robot at ``loc`` with ``load``, seeing package ``here`` at its base, may start ``ma``.

    Only the robot's own state is checked; a joint MA also needs its partner (see the module doc).
    """
    if ma == WAIT:
        return True
    if math.isnan(float(MEAN_DURATION[ma, loc])):
        return False
    size = PACKAGES[load - 1][0] if load else 0
    if ma <= GO_D2:
        return size != LARGE
    if ma in (JGO_D1, JGO_D2, JPUT):
        return size == LARGE
    if ma in (PICK, JPICK):
        return size == 0 and PACKAGES[here][0] == (SMALL if ma == PICK else LARGE)
    return size == SMALL  # put down, place on truck


_NOISY, _OK, _JOINT_OK, _SOLO_PICK_OK = 1, 2, 4, 8  # bits (_NOISY first: ``flags & _NOISY`` is 0 or 1) of the start table's ``flags``


def _start_tables() -> dict[str, Tensor]:
    """Tables over ``((loc * 6 + load) * 5 + here) * 13 + ma``.

    ``flags`` (uint8) holds bits ``_OK`` (preconditions hold), ``_JOINT_OK`` (a joint MA whose
    preconditions hold), ``_SOLO_PICK_OK`` (a pick-up whose preconditions hold) and ``_NOISY`` (the
    duration is noisy: preconditions hold and the MA is not ``wait``); ``mean`` is the mean duration.
    """
    n = _N_LOC * _N_LOAD * _N_PKG * _N_MA
    flags, mean = torch.zeros(n, dtype=torch.uint8), torch.zeros(n, dtype=torch.float64)
    i = 0
    for loc in range(_N_LOC):
        for load in range(_N_LOAD):
            for here in range(_N_PKG):
                for ma in range(_N_MA):
                    ok = preconditions_hold(loc, load, here, ma)
                    flags[i] = ok * (_OK + _JOINT_OK * (ma in JOINT_MAS) + _SOLO_PICK_OK * (ma == PICK) + _NOISY * (ma != WAIT))
                    mean[i] = float(MEAN_DURATION[ma, loc]) if ok else FAIL_DURATION
                    i += 1
    return {"flags": flags, "mean": mean}


_START = _start_tables()


def _flags(mas) -> Tensor:
    flags = torch.zeros(_N_MA, dtype=torch.bool)
    flags[list(mas)] = True
    return flags


_GO, _DROP, _PICKS, _JPUT = 1, 2, 4, 8  # bits of ``_MA_KIND`` (_GO first: ``kind & _GO`` is 0 or 1)
#: uint8 (13,): whether each MA moves the robot, drops its load, picks a package up, is the joint put-down
_MA_KIND = (_flags(m for m, node in enumerate(TARGET_NODE) if node >= 0) * _GO + _flags(DROP_MAS) * _DROP
            + _flags([PICK, JPICK]) * _PICKS + _flags([JPUT]) * _JPUT).to(torch.uint8)
_TARGET = torch.tensor([max(node, 0) for node in TARGET_NODE], dtype=torch.int32)


# Masks inside the rules are uint8 0/1 tensors (bool tensors seen through ``view(torch.uint8)``):
# on CPU, ops that produce or consume bool tensors (``where``, ``==``, ``any``) cost several times
# more than integer arithmetic, so selections are arithmetic blends ``b + mask * (a - b)``, negation
# is ``mask ^ 1``, and equalities of small integers are ``1 - min((a - b) ** 2, 1)``.


def _any(mask: Tensor) -> bool:
    """``bool(mask.any())`` for a contiguous bool or uint8 tensor (a uint8 max, much faster than ``any`` on CPU)."""
    return mask.numel() > 0 and bool(mask.view(torch.uint8).max())


def _u8(mask: Tensor) -> Tensor:
    """uint8 0/1 view of a bool tensor (no copy when contiguous)."""
    return mask.contiguous().view(torch.uint8)


def _equal(a: Tensor, b: Tensor) -> Tensor:
    """uint8 0/1: ``a == b`` for integer tensors."""
    d = a - b
    return (1 - d.mul_(d).clamp_(max=1)).to(torch.uint8)


def _pair(x: Tensor) -> Tensor:
    """(B,) -> contiguous (B, 2) with ``x`` in both columns (ops broadcasting a (B, 1) operand are slow on CPU)."""
    if x.dtype == torch.uint8 and sys.byteorder == "little":  # each byte doubled: x * 257 as int16
        return x.to(torch.int16).mul_(257).view(torch.uint8).view(-1, 2)
    return torch.stack([x, x], dim=1)


def _select(mask: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """``where(mask, a, b)`` for a uint8 0/1 mask and finite float tensors, exact (a lerp with weight 0 or 1)."""
    return torch.lerp(b, a.to(b.dtype), mask.to(b.dtype))


def _same_place_and_load(state: dict[str, Tensor]) -> Tensor:
    """uint8 0/1 (B,): both robots at one node with the same load."""
    loc, load = state["loc"], state["load"]
    d_loc, d_load = loc[:, 0] - loc[:, 1], load[:, 0] - load[:, 1]
    return (1 - (d_loc * d_loc + d_load * d_load).clamp_(max=1)).to(torch.uint8)


def _lookup(table: Tensor, index: Tensor) -> Tensor:
    """``table[index]`` for a 1-D table (a flat ``index_select``, the fastest gather on CPU)."""
    return table.index_select(0, index.reshape(-1)).view(index.shape)


class PackageDelivery(DecPOSMDP):
    """The package-delivery Dec-POSMDP (2 robots, 13 MAs, 13 macro-observations).

    Args:
        gamma: discount per time unit.
        horizon: simulation length in time units.
        joint_wait: how long a robot that starts a joint MA waits for its partner (time units > 0).
        small_reward, large_reward, truck_reward: rewards for a package delivered right.
        large_reward_per_robot: credit ``large_reward`` to each robot of the joint put-down
            (the reference's accounting) instead of once per package.
        solo_joint: let one robot run a joint MA alone when its partner is not there (the
            reference's rule; off by default: large packages need both robots).
    """

    num_agents = 2
    num_actions = len(ACTION_NAMES)
    num_obs = len(OBS_NAMES)

    def __init__(
        self,
        gamma: float = 0.99,
        horizon: float = 50.0,
        joint_wait: float = 4.0,
        small_reward: float = 1.0,
        large_reward: float = 3.0,
        truck_reward: float = 1.0,
        large_reward_per_robot: bool = True,
        solo_joint: bool = False,
    ) -> None:
        if not 0.0 < float(gamma) <= 1.0:
            raise ValueError(f"gamma: expected a float in (0, 1], got {gamma!r}")
        for name, value in (("horizon", horizon), ("joint_wait", joint_wait)):
            if not (math.isfinite(float(value)) and float(value) > 0.0):
                raise ValueError(f"{name}: expected a finite float > 0, got {value!r}")
        for name, value in (("small_reward", small_reward), ("large_reward", large_reward), ("truck_reward", truck_reward)):
            if not math.isfinite(float(value)):
                raise ValueError(f"{name}: expected a finite float, got {value!r}")
        self.gamma, self.horizon, self.joint_wait = float(gamma), float(horizon), float(joint_wait)
        self.small_reward, self.large_reward, self.truck_reward = float(small_reward), float(large_reward), float(truck_reward)
        self.large_reward_per_robot, self.solo_joint = bool(large_reward_per_robot), bool(solo_joint)
        self.action_names, self.obs_names = list(ACTION_NAMES), list(OBS_NAMES)
        self._complete_tables = self._build_complete_tables()

    def __repr__(self) -> str:
        return (f"PackageDelivery(gamma={self.gamma}, horizon={self.horizon}, joint_wait={self.joint_wait}, "
                f"large_reward_per_robot={self.large_reward_per_robot}, solo_joint={self.solo_joint})")

    def drop_reward(self, ma: int, load: int, loc: int, robots: int = 2) -> tuple[float, bool]:
        """(reward credited to one robot, delivered right?) when ``ma`` in ``DROP_MAS`` completes at
        ``loc``; ``robots`` run a joint put-down together (1 only with ``solo_joint``)."""
        size, dest = PACKAGES[load - 1]
        right = dest == loc
        if not right:
            return 0.0, False
        if ma == JPUT:
            return (self.large_reward if self.large_reward_per_robot else self.large_reward / robots), True
        return (self.truck_reward if ma == TRUCK else self.small_reward), True

    def _build_complete_tables(self) -> dict[str, Tensor]:
        """Tables over ``(ma * 5 + loc) * 6 + load`` for a drop MA completing successfully.

        ``packed_counts[i]`` (int32) adds to the counters (delivered, delivered_large, wrong), counter
        ``k`` in bits ``_COUNT_BITS * k`` and up; a joint put-down completes for both robots at once and
        is counted on robot 0 only.
        """
        n = _N_MA * _N_LOC * _N_LOAD
        reward = torch.zeros(n, dtype=torch.float64)
        counts = torch.zeros(n, 3, dtype=torch.long)
        i = 0
        for ma in range(_N_MA):
            for loc in range(_N_LOC):
                for load in range(_N_LOAD):
                    if ma in DROP_MAS and load and preconditions_hold(loc, load, 0, ma):
                        reward[i], right = self.drop_reward(ma, load, loc)
                        counts[i] = torch.tensor([right, right and ma == JPUT, not right])
                    i += 1
        packed = (counts << torch.arange(0, _COUNT_BITS * len(COUNTERS), _COUNT_BITS)).sum(dim=1).to(torch.int32)
        return {"reward": reward, "packed_counts": packed}

    @staticmethod
    def sample_packages(count: int, generator: torch.Generator) -> Tensor:
        """int32 (count,) new package codes (see ``PACKAGES``)."""
        return _ARRIVAL[torch.randint(0, len(_ARRIVAL), (count,), generator=generator)]

    def reset(self, batch: int, generator: torch.Generator) -> dict[str, Tensor]:
        return {
            "loc": torch.full((batch, 2), BASE1, dtype=torch.int32),
            "load": torch.zeros(batch, 2, dtype=torch.int32),
            "base": self.sample_packages(2 * batch, generator).view(batch, 2),
            "ma": torch.full((batch, 2), WAIT, dtype=torch.int32),
            "ok": torch.zeros(batch, 2, dtype=torch.bool),
            "waiting": torch.zeros(batch, 2, dtype=torch.bool),
            **{key: torch.zeros(batch, dtype=torch.long) for key in COUNTERS},
        }

    def start(self, state, agents, actions, t, end_time, generator):
        loc, load, actions = state["loc"], state["load"], actions.to(torch.int32)
        agents_u8 = _u8(agents)
        here = self._here(state)
        situation = (loc * _N_LOAD + load) * (_N_PKG * _N_MA) + here * _N_MA  # the table index without the MA
        flags = _lookup(_START["flags"], situation + actions) * agents_u8
        drafted = self._draft(state, agents_u8, actions, (flags >> 2) & 1)
        if drafted is not None:
            actions = drafted
            flags = _lookup(_START["flags"], situation + actions) * agents_u8
        index = situation + actions
        noise = torch.randn(actions.shape, generator=generator).mul_(DURATION_NOISE).clamp_(min=MIN_NOISE_FACTOR - 1.0)
        noise.mul_(flags & _NOISY).add_(1.0)
        finish = torch.addcmul(_pair(t), _lookup(_START["mean"], index), noise)
        ok, joint, solo_pick = (flags >> 1) & 1, (flags >> 2) & 1, (flags >> 3) & 1
        both_pick = solo_pick[:, 0] & solo_pick[:, 1]
        if _any(both_pick):
            clash = both_pick & _equal(loc[:, 0], loc[:, 1])
            if _any(clash):  # both pick up at one base at once: robot 0 takes the package
                ok[:, 1] &= clash ^ 1
                solo_pick[:, 1] &= clash ^ 1
                finish[:, 1] = torch.where(clash.view(torch.bool), t + FAIL_DURATION, finish[:, 1])
        ma = state["ma"]
        state["ma"] = ma + agents_u8 * (actions - ma)
        state["ok"] = ((_u8(state["ok"]) & (agents_u8 ^ 1)) | ok).view(torch.bool)  # ok implies agents
        if _any(solo_pick):
            row, col = solo_pick.nonzero(as_tuple=True)
            self._take(state, row, col, here[row, col], generator)
        changed = agents_u8
        if _any(joint):
            finish, joined = self._start_joint(state, joint, here, t, finish, generator)
            changed = agents_u8 | joined
        # finish is finite wherever t is; end_time may be infinite (rows a simulation froze)
        return torch.where(changed.view(torch.bool), finish, end_time)

    @staticmethod
    def _draft(state: dict[str, Tensor], agents: Tensor, actions: Tensor, joint_ok: Tensor) -> Tensor | None:
        """int32 (B, 2) MAs after drafting partners into joint MAs, or None when nobody can be drafted.

        ``agents`` and ``joint_ok`` are uint8 0/1 (B, 2).
        """
        partner_waits = agents & _u8(state["waiting"]).roll(1, 1)
        # joint_ok implies agents: a joint MA starting while the partner also starts
        if not _any(partner_waits | (joint_ok & agents.roll(1, 1))):
            return None
        same = _same_place_and_load(state)
        act = actions + (partner_waits & _pair(same)) * (state["ma"].roll(1, 1) - actions)
        both = agents[:, 0] & agents[:, 1] & same
        lead0, lead1 = both & joint_ok[:, 0], both & joint_ok[:, 1] & (joint_ok[:, 0] ^ 1)
        act0, act1 = act[:, 0], act[:, 1]
        diff = act1 - act0
        return torch.stack([act0 + lead1 * diff, act1 - lead0 * diff], dim=1)

    def _take(self, state: dict[str, Tensor], row: Tensor, col: Tensor, package: Tensor, generator) -> None:
        """Robot ``col`` of rollout ``row`` loads ``package`` from its base, which gets a new package."""
        state["load"][row, col] = package + 1
        state["base"][row, state["loc"][row, col].long()] = self.sample_packages(int(row.numel()), generator)

    @staticmethod
    def _here(state: dict[str, Tensor]) -> Tensor:
        """int32 (B, 2): the package waiting at each robot's base (Base1's away from the bases)."""
        base, loc = state["base"], state["loc"]
        at_base2 = (loc * (2 - loc)).clamp_(min=0)  # 1 at Base2 (node 1), else 0 (nodes 0, 2, 3, 4)
        base1 = base[:, 0]
        return _pair(base1) + at_base2 * _pair(base[:, 1] - base1)

    def _start_joint(self, state, joint, here, t, finish, generator) -> tuple[Tensor, Tensor]:
        """Joint-MA synchronisation where some robot starts a joint MA (uint8 0/1 ``joint``).

        Returns the end times (B, 2) of the robots that start or are joined, and the uint8 0/1 mask
        (B, 2) of robots that were waiting and are joined by their partner now.
        """
        ma, waiting = state["ma"], _u8(state["waiting"])
        same = _same_place_and_load(state) & _equal(ma[:, 0], ma[:, 1])  # ... and the same MA
        # a (drafted) robot joins a partner waiting in the same joint MA at the same place with the same load
        joins = joint & waiting.roll(1, 1) & _pair(same)
        # both start the same joint MA at once (one drafted the other): they run it on robot 0's duration
        together = joint[:, 0] & joint[:, 1] & same
        finish[:, 1] = _select(together, finish[:, 0], finish[:, 1])
        alone = joint & (joins ^ 1) & _pair(together ^ 1)
        if self.solo_joint:
            waits = torch.zeros_like(alone)
        else:
            waits = alone
            finish = _select(waits, _pair(t + self.joint_wait), finish)
        joined = joins.roll(1, 1)
        finish = _select(joined, finish.roll(1, 1), finish)
        state["waiting"] = ((waiting & (joined ^ 1)) | waits).view(torch.bool)
        lift = (joins[:, 0] | joins[:, 1] | together) & _equal(ma[:, 0], JPICK)
        if _any(lift):
            row = lift.nonzero().squeeze(1)
            package = here[row, 0]
            state["load"][row] = (package + 1)[:, None].expand(-1, 2)
            state["base"][row, state["loc"][row, 0].long()] = self.sample_packages(int(row.numel()), generator)
        if self.solo_joint:
            solo = alone & _equal(ma, JPICK)
            if _any(solo):
                row, col = solo.nonzero(as_tuple=True)
                self._take(state, row, col, here[row, col], generator)
        return finish, joined

    def complete(self, state, agents, actions, t, generator):
        ma, waiting, agents = state["ma"], _u8(state["waiting"]), _u8(agents)
        active = _u8(state["ok"]) & (waiting ^ 1)  # running an MA whose preconditions held, not waiting for the partner
        kind = _lookup(_MA_KIND, ma) * active
        travelling = (kind & _GO) & (agents ^ 1)
        kind *= agents  # the effective completions
        state["waiting"] = (waiting & (agents ^ 1)).view(torch.bool)  # a wait that runs out is a failed joint MA
        loc = state["loc"]
        loc = state["loc"] = loc + (kind & _GO) * (_lookup(_TARGET, ma) - loc)
        load = state["load"]
        reward = torch.zeros(agents.shape[0], dtype=torch.float64)
        dropped = (kind >> 1) & 1
        if _any(dropped):
            index = (ma * _N_LOC + loc) * _N_LOAD + load
            table = self._complete_tables
            jput = (kind >> 3) & 1
            paired = jput[:, 0] & jput[:, 1]  # a joint put-down by both robots
            credit = _lookup(table["reward"], index) * dropped
            if not self.large_reward_per_robot:
                credit = credit * (1 + (jput & _pair(paired ^ 1)))  # a solo joint put-down gets it all
            reward = credit[:, 0] + credit[:, 1]
            counted = dropped.clone()
            counted[:, 1] &= paired ^ 1  # a joint put-down by both robots counts once
            counts = _lookup(table["packed_counts"], index) * counted
            counts = counts[:, 0] + counts[:, 1]
            for k, key in enumerate(COUNTERS):
                state[key] = state[key] + ((counts >> (_COUNT_BITS * k)) & _COUNT_MASK)
            load = state["load"] = load * (dropped ^ 1)
        picks = (kind >> 2) & 1
        here = self._here(state)
        package = here + picks * (load - 1 - here)
        partner = _pair(_equal(loc[:, 0], loc[:, 1])) & (travelling.roll(1, 1) ^ 1)
        at_base = (2 - loc).clamp_(0, 1)  # 1 at Base1/Base2 (nodes 0, 1), else 0
        obs = (1 + 6 * partner + package) * at_base
        return reward, obs.long()
