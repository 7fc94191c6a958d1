"""MA decisions per second: the batched simulator vs a per-rollout Python simulation.

Both run the same package-delivery domain (same rules and constants) under the same joint
controllers, in one process, one after the other. The reference is the straightforward way to
write such a simulator: one rollout at a time, a Python loop over completion events, Python
scalars and ``random.Random``. An "MA decision" is one macro-action started by one robot.

    python benchmarks/bench_simulator.py [--controllers 400] [--rollouts 80] [--reference-rollouts 1000]

The batched run simulates all controllers x rollouts in one batch (32 000 rollouts by default, so
the fixed cost of each tensor op is shared by many rollouts); the reference runs its rollouts one
after the other. Both rates count MA decisions per wall-clock second.

Prints both rates and their ratio (floor: 30x).
"""

from __future__ import annotations

import argparse
import random
import time

import torch

from decpomdp import JointController, simulate
from decpomdp.domains import package_delivery as pd

_MEAN = pd.MEAN_DURATION.tolist()
_TARGET = pd.TARGET_NODE
_JOINT = set(pd.JOINT_MAS)
_DROPS = set(pd.DROP_MAS)
_ARRIVAL = pd.ARRIVAL.tolist()


class ReferencePackageDelivery:
    """The rules of :class:`decpomdp.domains.PackageDelivery`, one rollout at a time in plain Python."""

    def __init__(self, env: pd.PackageDelivery) -> None:
        self.env = env

    @staticmethod
    def _package(rng: random.Random) -> int:
        return _ARRIVAL[rng.randrange(len(_ARRIVAL))]

    def _ok(self, s: dict, a: int, act: int) -> bool:
        load = s["load"][a]
        return pd.preconditions_hold(s["pos"][a], load, s["base"][min(s["pos"][a], pd.BASE2)], act)

    def _take(self, s: dict, agents: tuple[int, ...], rng: random.Random) -> None:
        base = s["pos"][agents[0]]
        for a in agents:
            s["load"][a] = 1 + s["base"][base]
        s["base"][base] = self._package(rng)

    def _start(self, s: dict, agents: list[int], acts: list[int], t: float, rng: random.Random) -> None:
        """Agents in ``agents`` start ``acts[a]`` at ``t``, all seeing the state before any of them started."""
        same_place = s["pos"][0] == s["pos"][1]
        acts = list(acts)
        if same_place and s["load"][0] == s["load"][1]:  # drafting into joint MAs
            for a in agents:
                if s["waiting"][1 - a]:
                    acts[a] = s["ma"][1 - a]
            if len(agents) == 2:
                lead = [a for a in (0, 1) if acts[a] in _JOINT and self._ok(s, a, acts[a])]
                if lead:
                    acts[1 - lead[0]] = acts[lead[0]]
        ok = {a: self._ok(s, a, acts[a]) for a in agents}
        if len(agents) == 2 and ok[0] and ok[1] and acts[0] == acts[1] == pd.PICK and same_place:
            ok[1] = False  # robot 0 takes the package
        together = (
            len(agents) == 2 and ok[0] and ok[1] and acts[0] == acts[1] and acts[0] in _JOINT
            and same_place and s["load"][0] == s["load"][1]
        )
        takers = []
        for a in agents:
            p, act = 1 - a, acts[a]
            noise = max(1.0 + pd.rules.DURATION_NOISE * rng.gauss(0.0, 1.0), pd.MIN_NOISE_FACTOR)
            s["ma"][a], s["okay"][a], s["waiting"][a] = act, ok[a], False
            if act == pd.WAIT:
                s["end"][a] = t + 1.0
            elif not ok[a]:
                s["end"][a] = t + pd.FAIL_DURATION
            else:
                s["end"][a] = t + _MEAN[act][s["pos"][a]] * noise
            if not ok[a] or act not in _JOINT:
                if ok[a] and act == pd.PICK:
                    takers.append((a,))
                continue
            if together:
                if a == 1:
                    s["end"][1] = s["end"][0]
                    if act == pd.JPICK:
                        takers.append((0, 1))
            elif s["waiting"][p] and s["ma"][p] == act and same_place and s["load"][p] == s["load"][a]:
                s["end"][p] = s["end"][a]
                s["waiting"][p] = False
                if act == pd.JPICK:
                    takers.append((a, p))
            elif self.env.solo_joint:  # the reference's rule: run it alone
                if act == pd.JPICK:
                    takers.append((a,))
            else:
                s["end"][a] = t + self.env.joint_wait
                s["waiting"][a] = True
        for group in takers:
            self._take(s, group, rng)

    def _complete(self, s: dict, agents: list[int]) -> tuple[float, list[int]]:
        env, reward, picked = self.env, 0.0, set()
        effective = [a for a in agents if s["okay"][a] and not s["waiting"][a]]
        travelling = [_TARGET[s["ma"][a]] >= 0 and s["okay"][a] and not s["waiting"][a] and a not in agents for a in range(2)]
        for a in agents:
            s["waiting"][a] = False
        for a in effective:
            act = s["ma"][a]
            if _TARGET[act] >= 0:
                s["pos"][a] = _TARGET[act]
            elif act in (pd.PICK, pd.JPICK):
                picked.add(a)
            elif act in _DROPS:
                robots = sum(s["ma"][b] == pd.JPUT for b in effective) if act == pd.JPUT else 1
                reward += env.rewards.for_drop(act, s["load"][a], s["pos"][a], robots)[0]
                s["load"][a] = 0
        obs = [0, 0]
        for a in agents:
            pos, p = s["pos"][a], 1 - a
            if pos > pd.BASE2:
                continue
            package = s["load"][a] - 1 if a in picked else s["base"][pos]
            partner = s["pos"][p] == pos and not travelling[p]
            obs[a] = 1 + 6 * partner + package
        return reward, obs

    def rollout(self, action: list[list[int]], next_node: list[list[list[int]]], rng: random.Random) -> tuple[float, int]:
        """Discounted return of one rollout of one joint controller and the number of MAs started."""
        env = self.env
        s = {
            "pos": [pd.BASE1, pd.BASE1],
            "load": [0, 0],
            "base": [self._package(rng), self._package(rng)],
            "ma": [pd.WAIT, pd.WAIT],
            "okay": [False, False],
            "waiting": [False, False],
            "end": [0.0, 0.0],
        }
        node = [0, 0]
        self._start(s, [0, 1], [action[0][0], action[1][0]], 0.0, rng)
        value, decisions = 0.0, 2
        while True:
            t = min(s["end"])
            if t > env.horizon:
                return value, decisions
            agents = [a for a in range(2) if s["end"][a] == t]
            reward, obs = self._complete(s, agents)
            value += env.gamma**t * reward
            for a in agents:
                node[a] = next_node[a][node[a]][obs[a]]
            self._start(s, agents, [action[a][node[a]] for a in range(2)], t, rng)
            decisions += len(agents)


def controller_family(count: int, mutations: int, seed: int) -> JointController:
    """The greedy package-delivery controller and ``count - 1`` copies with random entries changed.

    Mutants behave like the controllers G-DICE evaluates mid-search: mostly sensible, sometimes
    failing or idle.
    """
    greedy = pd.greedy_controller()
    action = greedy.action.expand(count, -1, -1).clone()
    next_node = greedy.next_node.expand(count, -1, -1, -1).clone()
    rng = random.Random(seed)
    _, agents, nodes, obs = next_node.shape
    for k in range(1, count):
        for _ in range(mutations):
            a, n = rng.randrange(agents), rng.randrange(nodes)
            if rng.random() < 0.5:
                action[k, a, n] = rng.randrange(pd.PackageDelivery.num_actions)
            else:
                next_node[k, a, n, rng.randrange(obs)] = rng.randrange(nodes)
    return JointController(action, next_node)


def batched_rate(env, controller: JointController, rollouts: int, seed: int) -> tuple[float, float]:
    """(decisions per second, mean return) of the batched simulator."""
    counter = _CountingEnv(env)
    tic = time.perf_counter()
    returns = simulate(counter, controller, rollouts, torch.Generator().manual_seed(seed))
    elapsed = time.perf_counter() - tic
    return counter.decisions / elapsed, float(returns.mean())


class _CountingEnv(pd.PackageDelivery):
    """Counts MA starts (decisions) while delegating to the wrapped domain's rules."""

    def __init__(self, env: pd.PackageDelivery) -> None:
        self.__dict__.update(env.__dict__)
        self.decisions = 0

    def start(self, state, agents, actions, t, end_time, generator):
        self.decisions += int(agents.sum())
        return super().start(state, agents, actions, t, end_time, generator)


def reference_rate(env, controller: JointController, rollouts: int, seed: int) -> tuple[float, float]:
    """(decisions per second, mean return) of the per-rollout Python reference."""
    ref, rng = ReferencePackageDelivery(env), random.Random(seed)
    action, next_node = controller.action.tolist(), controller.next_node.tolist()
    k_count = controller.num_controllers
    decisions, total = 0, 0.0
    tic = time.perf_counter()
    for i in range(rollouts):
        value, count = ref.rollout(action[i % k_count], next_node[i % k_count], rng)
        decisions += count
        total += value
    elapsed = time.perf_counter() - tic
    return decisions / elapsed, total / rollouts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controllers", type=int, default=400)
    parser.add_argument("--rollouts", type=int, default=80, help="rollouts per controller (batched)")
    parser.add_argument("--reference-rollouts", type=int, default=1000)
    parser.add_argument("--mutations", type=int, default=3, help="random entries changed per controller")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (the machine's load drifts)")
    parser.add_argument("--threads", type=int, default=2,
                        help="torch threads for the batched simulator (2 = both cores; use 1 on a heavily shared machine)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    env = pd.PackageDelivery()
    controller = controller_family(args.controllers, args.mutations, args.seed)
    simulate(env, controller[:2], 2, torch.Generator().manual_seed(args.seed))  # warm-up
    ratios = []
    for r in range(args.rounds):
        batched, batched_mean = batched_rate(env, controller, args.rollouts, args.seed + r)
        reference, reference_mean = reference_rate(env, controller, args.reference_rollouts, args.seed + r)
        ratios.append(batched / reference)
        print(f"round {r}: batched {batched:10.0f} MA decisions/s (mean return {batched_mean:.3f}), "
              f"per-rollout Python {reference:8.0f} MA decisions/s (mean return {reference_mean:.3f}), "
              f"ratio {ratios[-1]:.1f}x")
    print(f"batched simulator: {args.controllers} controllers x {args.rollouts} rollouts, {args.threads} torch thread(s)")
    print(f"median ratio      : {sorted(ratios)[len(ratios) // 2]:.1f}x (floor 30x)")


if __name__ == "__main__":
    main()
