"""The package-delivery rules (:mod:`.rules`) on a batch of rollouts: :class:`PackageDelivery`.

:func:`decpomdp.simulate` runs the domain on the compiled engine (the rules in :mod:`.rules`); the
batched torch methods here are its test oracle (``backend="torch"``). The rules are compiled into lookup tables over (location, load, package at the base, MA), so a
batch step is a handful of gathers and elementwise ops on uint8 masks (see :mod:`decpomdp.batched`).
``tests/decpomdp/test_package_delivery.py`` checks this implementation against a plain-Python
simulator of the same rules, one rollout at a time. The torch methods run on the generator's device
(the tables are copied there once per device; the CPU uses them as they are).
"""

from __future__ import annotations


import torch
from torch import Tensor

from decpomdp.batched import any_true, as_u8, equal_u8, lookup, pair, select
from decpomdp.core import DecPOSMDP
from decpomdp.engine import EngineModel, no_perception
from hbni_infra.checks import as_float
from decpomdp.domains.package_delivery import rules
from decpomdp.domains.package_delivery.rules import (
    ACTION_NAMES,
    BASE1,
    COUNTERS,
    FAIL_DURATION,
    GO_B1,
    JPICK,
    JPUT,
    MIN_NOISE_FACTOR,
    OBS_NAMES,
    PUT,
    WAIT,
    Rewards,
)

_N_LOC, _N_LOAD, _N_PKG, _N_MA = 5, 6, 5, 13
_COUNT_BITS, _COUNT_MASK = 8, 255  # counters packed in one int32 per event (at most 2 per event each)


_NOISY, _OK, _JOINT_OK, _SOLO_PICK_OK = (
    1,
    2,
    4,
    8,
)  # bits (_NOISY first: ``flags & _NOISY`` is 0 or 1) of the start table's ``flags``


def _start_tables(reference_pickup: bool) -> dict[str, Tensor]:
    """:func:`.rules.start_tables` as uint8 flags and float64 means."""
    flags, mean = rules.start_tables(reference_pickup)
    return {"flags": torch.as_tensor(flags).to(torch.uint8), "mean": torch.as_tensor(mean)}


_START = {rule: _start_tables(rule) for rule in (False, True)}  # by reference_pickup
_GO, _DROP, _PICKS, _JPUT = rules.GO_KIND, rules.DROP_KIND, rules.PICK_KIND, rules.JPUT_KIND  # bits of ``_MA_KIND``
#: uint8 (13,) kind bits of each MA; int32 (13,) node each go-to MA ends at; uint8 (13 * 13,) allowed successors
_MA_KIND, _TARGET, _SUCCESSOR = (
    torch.as_tensor(x).to(dtype) for x, dtype in zip(rules.ma_tables(), (torch.uint8, torch.int32, torch.uint8))
)


def _same_place_and_load(state: dict[str, Tensor]) -> Tensor:
    """uint8 0/1 (B,): both robots at one node with the same load."""
    loc, load = state["loc"], state["load"]
    d_loc, d_load = loc[:, 0] - loc[:, 1], load[:, 0] - load[:, 1]
    return (1 - (d_loc * d_loc + d_load * d_load).clamp_(max=1)).to(torch.uint8)


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
        successor_rule: the reference's allowed successors, and its failed put-downs that still pay
            (see :mod:`.rules`; off by default).
        reference_pickup: the reference's loading rules: a pick-up takes a package of any size, moves
            accept any load (see :mod:`.rules`; off by default).
    """

    num_agents = 2
    num_actions = len(ACTION_NAMES)
    num_obs = len(OBS_NAMES)
    counters = COUNTERS

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
        successor_rule: bool = False,
        reference_pickup: bool = False,
    ) -> None:
        self.gamma = as_float("gamma", gamma, 0.0, 1.0, low_open=True)
        self.horizon = as_float("horizon", horizon, 0.0, low_open=True)
        self.joint_wait = as_float("joint_wait", joint_wait, 0.0, low_open=True)
        self.rewards = Rewards(
            as_float("small_reward", small_reward),
            as_float("large_reward", large_reward),
            as_float("truck_reward", truck_reward),
            bool(large_reward_per_robot),
        )
        self.solo_joint, self.successor_rule = bool(solo_joint), bool(successor_rule)
        self.reference_pickup = bool(reference_pickup)
        self._start = _START[self.reference_pickup]
        self.action_names, self.obs_names = list(ACTION_NAMES), list(OBS_NAMES)
        self._complete_tables = self._build_complete_tables()
        self._cpu_tables = {**self._start, "ma_kind": _MA_KIND, "target": _TARGET, **self._complete_tables}
        self._placed: dict[torch.device, dict[str, Tensor]] = {}

    def _tables(self, device: torch.device) -> dict[str, Tensor]:
        """Start, MA and completion tables on ``device`` (the tables themselves on the CPU, copies made once
        elsewhere): ``flags``, ``mean``, ``ma_kind``, ``target``, ``reward``, ``packed_counts``."""
        if device.type == "cpu":
            return self._cpu_tables
        if device not in self._placed:
            self._placed[device] = {k: v.to(device) for k, v in self._cpu_tables.items()}
        return self._placed[device]

    def __repr__(self) -> str:
        return (
            f"PackageDelivery(gamma={self.gamma}, horizon={self.horizon}, joint_wait={self.joint_wait}, "
            f"large_reward_per_robot={self.rewards.large_per_robot}, solo_joint={self.solo_joint}, "
            f"truck_reward={self.rewards.truck}, successor_rule={self.successor_rule}, "
            f"reference_pickup={self.reference_pickup})"
        )

    def _build_complete_tables(self) -> dict[str, Tensor]:
        """:func:`.rules.drop_tables` with the counter increments packed into one int32 per entry (counter ``k``
        in bits ``_COUNT_BITS * k`` and up); a joint put-down completes for both robots at once and is
        counted on robot 0 only."""
        reward, counts = (torch.as_tensor(x) for x in rules.drop_tables(self.rewards))
        packed = (counts << torch.arange(0, _COUNT_BITS * len(COUNTERS), _COUNT_BITS)).sum(dim=1).to(torch.int32)
        return {"reward": reward, "packed_counts": packed}

    def engine_model(self) -> EngineModel:
        """The domain for the compiled engine (:mod:`.rules`)."""
        p = rules.params(self.joint_wait, self.solo_joint, self.successor_rule, self.rewards.large_per_robot)
        return EngineModel(rules.ENGINE, p, rules.tables(self.reference_pickup, self.rewards), no_perception())

    @staticmethod
    def sample_packages(count: int, generator: torch.Generator) -> Tensor:
        """int32 (count,) new package codes (see ``PACKAGES``)."""
        arrival = rules.ARRIVAL  # read at call time, so a test can pin the package stream
        index = torch.randint(0, len(arrival), (count,), generator=generator, device=generator.device)
        return arrival.to(generator.device)[index]

    def reset(self, batch: int, generator: torch.Generator) -> dict[str, Tensor]:
        dev = generator.device
        state = {
            "loc": torch.full((batch, 2), BASE1, dtype=torch.int32, device=dev),
            "load": torch.zeros(batch, 2, dtype=torch.int32, device=dev),
            "base": self.sample_packages(2 * batch, generator).view(batch, 2),
            "ma": torch.full((batch, 2), GO_B1 if self.successor_rule else WAIT, dtype=torch.int32, device=dev),
            "ok": torch.zeros(batch, 2, dtype=torch.bool, device=dev),
            "waiting": torch.zeros(batch, 2, dtype=torch.bool, device=dev),
            **{key: torch.zeros(batch, dtype=torch.long, device=dev) for key in COUNTERS},
        }
        if self.successor_rule:  # a put-down that failed by the successor rule alone, paying when it ends
            state["pays"] = torch.zeros(batch, 2, dtype=torch.bool, device=dev)
        return state

    def start(self, state, agents, actions, t, end_time, generator):
        loc, load, actions = state["loc"], state["load"], actions.to(torch.int32)
        agents_u8 = as_u8(agents)
        here = self._here(state)
        situation = (loc * _N_LOAD + load) * (_N_PKG * _N_MA) + here * _N_MA  # the table index without the MA
        tables = self._tables(loc.device)
        flags = lookup(tables["flags"], situation + actions) * agents_u8
        drafted = self._draft(state, agents_u8, actions, (flags >> 2) & 1)
        if drafted is not None:
            actions = drafted
            flags = lookup(tables["flags"], situation + actions) * agents_u8
        mean = lookup(tables["mean"], situation + actions)
        if self.successor_rule:
            flags, mean = self._successors(state, agents_u8, actions, flags, mean)
        noise = (
            torch.randn(actions.shape, generator=generator, device=generator.device)
            .mul_(rules.DURATION_NOISE)
            .clamp_(min=MIN_NOISE_FACTOR - 1.0)
        )
        noise.mul_(flags & _NOISY).add_(1.0)
        finish = torch.addcmul(pair(t), mean, noise)
        ok, joint, solo_pick = (flags >> 1) & 1, (flags >> 2) & 1, (flags >> 3) & 1
        both_pick = solo_pick[:, 0] & solo_pick[:, 1]
        if any_true(both_pick):
            clash = both_pick & equal_u8(loc[:, 0], loc[:, 1])
            if any_true(clash):  # both pick up at one base at once: robot 0 takes the package
                ok[:, 1] &= clash ^ 1
                solo_pick[:, 1] &= clash ^ 1
                finish[:, 1] = torch.where(clash.view(torch.bool), t + FAIL_DURATION, finish[:, 1])
        ma = state["ma"]
        state["ma"] = ma + agents_u8 * (actions - ma)
        state["ok"] = ((as_u8(state["ok"]) & (agents_u8 ^ 1)) | ok).view(torch.bool)  # ok implies agents
        if any_true(solo_pick):
            row, col = solo_pick.nonzero(as_tuple=True)
            self._take(state, row, col, here[row, col], generator)
        changed = agents_u8
        if any_true(joint):
            finish, joined = self._start_joint(state, joint, here, t, finish, generator)
            changed = agents_u8 | joined
        # finish is finite wherever t is; end_time may be infinite (rows a simulation froze)
        return torch.where(changed.view(torch.bool), finish, end_time)

    @staticmethod
    def _successors(
        state: dict[str, Tensor], agents: Tensor, actions: Tensor, flags: Tensor, mean: Tensor
    ) -> tuple[Tensor, Tensor]:
        """``successor_rule``: starting MAs that may not follow the previous MA fail (flags 0, mean
        ``FAIL_DURATION``); a put-down failing by this rule alone is marked to pay when it ends.

        ``agents`` (the starting robots) and ``flags`` are uint8 (B, 2); ``flags`` imply ``agents``.
        """
        allowed = lookup(_SUCCESSOR.to(actions.device), state["ma"] * _N_MA + actions) | (agents ^ 1)
        drop = ((actions - PUT) * (actions - JPUT) == 0).to(torch.uint8)
        pays = (flags >> 1) & 1 & (allowed ^ 1) & drop
        state["pays"] = ((as_u8(state["pays"]) & (agents ^ 1)) | pays).view(torch.bool)
        return flags * allowed, select(allowed, mean, torch.full_like(mean, FAIL_DURATION))

    @staticmethod
    def _draft(state: dict[str, Tensor], agents: Tensor, actions: Tensor, joint_ok: Tensor) -> Tensor | None:
        """int32 (B, 2) MAs after drafting partners into joint MAs, or None when nobody can be drafted.

        ``agents`` and ``joint_ok`` are uint8 0/1 (B, 2).
        """
        partner_waits = agents & as_u8(state["waiting"]).roll(1, 1)
        # joint_ok implies agents: a joint MA starting while the partner also starts
        if not any_true(partner_waits | (joint_ok & agents.roll(1, 1))):
            return None
        same = _same_place_and_load(state)
        act = actions + (partner_waits & pair(same)) * (state["ma"].roll(1, 1) - actions)
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
        return pair(base1) + at_base2 * pair(base[:, 1] - base1)

    def _start_joint(self, state, joint, here, t, finish, generator) -> tuple[Tensor, Tensor]:
        """Joint-MA synchronisation where some robot starts a joint MA (uint8 0/1 ``joint``).

        Returns the end times (B, 2) of the robots that start or are joined, and the uint8 0/1 mask
        (B, 2) of robots that were waiting and are joined by their partner now.
        """
        ma, waiting = state["ma"], as_u8(state["waiting"])
        same = _same_place_and_load(state) & equal_u8(ma[:, 0], ma[:, 1])  # ... and the same MA
        # a (drafted) robot joins a partner waiting in the same joint MA at the same place with the same load
        joins = joint & waiting.roll(1, 1) & pair(same)
        # both start the same joint MA at once (one drafted the other): they run it on robot 0's duration
        together = joint[:, 0] & joint[:, 1] & same
        finish[:, 1] = select(together, finish[:, 0], finish[:, 1])
        alone = joint & (joins ^ 1) & pair(together ^ 1)
        if self.solo_joint:
            waits = torch.zeros_like(alone)
        else:
            waits = alone
            finish = select(waits, pair(t + self.joint_wait), finish)
        joined = joins.roll(1, 1)
        finish = select(joined, finish.roll(1, 1), finish)
        state["waiting"] = ((waiting & (joined ^ 1)) | waits).view(torch.bool)
        lift = (joins[:, 0] | joins[:, 1] | together) & equal_u8(ma[:, 0], JPICK)
        if any_true(lift):
            row = lift.nonzero().squeeze(1)
            package = here[row, 0]
            state["load"][row] = (package + 1)[:, None].expand(-1, 2)
            state["base"][row, state["loc"][row, 0].long()] = self.sample_packages(int(row.numel()), generator)
        if self.solo_joint:
            solo = alone & equal_u8(ma, JPICK)
            if any_true(solo):
                row, col = solo.nonzero(as_tuple=True)
                self._take(state, row, col, here[row, col], generator)
        return finish, joined

    def complete(self, state, agents, actions, t, generator):
        ma, waiting, agents = state["ma"], as_u8(state["waiting"]), as_u8(agents)
        active = as_u8(state["ok"]) & (
            waiting ^ 1
        )  # running an MA whose preconditions held, not waiting for the partner
        table = self._tables(ma.device)
        kind = lookup(table["ma_kind"], ma) * active
        travelling = (kind & _GO) & (agents ^ 1)
        kind *= agents  # the effective completions
        state["waiting"] = (waiting & (agents ^ 1)).view(torch.bool)  # a wait that runs out is a failed joint MA
        loc = state["loc"]
        loc = state["loc"] = loc + (kind & _GO) * (lookup(table["target"], ma) - loc)
        load = state["load"]
        reward = torch.zeros(agents.shape[0], dtype=torch.float64, device=ma.device)
        dropped = (kind >> 1) & 1
        if self.successor_rule:  # failed put-downs that still pay
            dropped = dropped | (as_u8(state["pays"]) & agents)
            state["pays"] = (as_u8(state["pays"]) & (agents ^ 1)).view(torch.bool)
        if any_true(dropped):
            index = (ma * _N_LOC + loc) * _N_LOAD + load
            jput = (kind >> 3) & 1
            paired = jput[:, 0] & jput[:, 1]  # a joint put-down by both robots
            credit = lookup(table["reward"], index) * dropped
            if not self.rewards.large_per_robot:
                credit = credit * (1 + (jput & pair(paired ^ 1)))  # a solo joint put-down gets it all
            reward = credit[:, 0] + credit[:, 1]
            counted = dropped.clone()
            counted[:, 1] &= paired ^ 1  # a joint put-down by both robots counts once
            counts = lookup(table["packed_counts"], index) * counted
            counts = counts[:, 0] + counts[:, 1]
            for k, key in enumerate(COUNTERS):
                state[key] = state[key] + ((counts >> (_COUNT_BITS * k)) & _COUNT_MASK)
            load = state["load"] = load * (dropped ^ 1)
        picks = (kind >> 2) & 1
        here = self._here(state)
        package = here + picks * (load - 1 - here)
        partner = pair(equal_u8(loc[:, 0], loc[:, 1])) & (travelling.roll(1, 1) ^ 1)
        at_base = (2 - loc).clamp_(0, 1)  # 1 at Base1/Base2 (nodes 0, 1), else 0
        obs = (1 + 6 * partner + package) * at_base
        return reward, obs.long()
