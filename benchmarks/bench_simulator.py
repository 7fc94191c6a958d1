"""Rollouts per CPU-second: the compiled engine against the batched torch simulator (its test oracle).

Both simulate the same domain under the same joint controllers in one process, one after the other,
in the planners' two call patterns: 8000 controllers x 8 rollouts (local search's racing stage) and
400 x 80 (a cross-entropy iteration). The controllers are the domain's greedy controller and mutants
of it with a few random entries changed, as a search evaluates them. Rows:

* disaster relief with perfect perception;
* disaster relief with an HBNI macro-observation table (an HBNI process characterised on 1000 streams
  per class simulated from fixed noise levels);
* package delivery.

    python benchmarks/bench_simulator.py [--rounds 3] [--patterns 8000x8 400x80]

Prints, per row and pattern: rollouts per CPU-second of each at one thread and their ratio (floor
10x, aim 30x), the engine's rollouts per wall-second on two threads over one (floor 1.7x), and both
mean returns (the same controllers, so they agree within Monte Carlo error).
"""

from __future__ import annotations

import argparse
import time

import torch

import hbni_pyro
from decpomdp import JointController, simulate
from decpomdp.domains import DisasterRelief, PackageDelivery
from decpomdp.domains import disaster_relief as dr
from decpomdp.domains import package_delivery as pd
from hbni_pyro import HyperPrior
from hbni_infra.threads import threads
from hbni_infra.streams import numpy_generator, torch_generator


def mutants(controller: JointController, count: int, mutations: int, seed: int, num_actions: int) -> JointController:
    """``controller`` and ``count - 1`` copies with ``mutations`` random entries changed each."""
    action = controller.action.expand(count, -1, -1).clone()
    next_node = controller.next_node.expand(count, -1, -1, -1).clone()
    rng = numpy_generator(seed)
    _, agents, nodes, obs = next_node.shape
    for k in range(1, count):
        for _ in range(mutations):
            a, n = int(rng.integers(agents)), int(rng.integers(nodes))
            if rng.random() < 0.5:
                action[k, a, n] = int(rng.integers(num_actions))
            else:
                next_node[k, a, n, int(rng.integers(obs))] = int(rng.integers(nodes))
    return JointController(action, next_node)


def hbni_table(seed: int) -> hbni_pyro.MacroObservationModel:
    """An HBNI process's table on disaster relief's six classes (noise levels like the mission's)."""
    theta = torch.tensor([[[3.0, 6.0, 2.0, 8.0, 4.0, 5.0]]], dtype=torch.float64).expand(1, 50, -1)
    ones = torch.ones(1, 50, dtype=torch.float64)
    posterior = hbni_pyro.posterior.posterior_from_samples(
        {"theta": theta.clone(), "kappa": 2 * ones, "gamma": 10 * ones}, torch.full((6,), 1 / 6), HyperPrior()
    )
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.HBNIFilter(posterior), threshold=0.95, max_frames=30)
    return hbni_pyro.characterize(process, theta[0, 0], 1000, seed)


def rate(
    env, controller: JointController, rollouts: int, backend: str, count: int, repeats: int
) -> tuple[float, float, float]:
    """(rollouts per CPU-second, rollouts per wall-second, mean return) of ``backend``, each rate the best of
    ``repeats`` identical calls (the least disturbed by other work on a shared machine)."""
    best_cpu = best_wall = float("inf")
    for _ in range(repeats):
        g = torch_generator(1)
        cpu, wall = time.process_time(), time.perf_counter()
        returns = simulate(env, controller, rollouts, g, backend=backend)
        best_cpu, best_wall = min(best_cpu, time.process_time() - cpu), min(best_wall, time.perf_counter() - wall)
    return count / best_cpu, count / best_wall, float(returns.mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds; the median is reported")
    parser.add_argument("--repeats", type=int, default=5, help="calls per measurement; the fastest counts")
    parser.add_argument("--patterns", nargs="+", default=["8000x8", "400x80"], help="controllers x rollouts")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rows = {
        "disaster relief, perfect perception": (DisasterRelief(), dr.greedy_controller()),
        "disaster relief, HBNI table": (DisasterRelief(perception=hbni_table(args.seed)), dr.greedy_controller()),
        "package delivery": (PackageDelivery(), pd.greedy_controller()),
    }
    print(
        f"{'row':38s} {'pattern':>8s} {'engine/CPU-s':>13s} {'torch/CPU-s':>12s} {'ratio':>7s} "
        f"{'2 thr/1 thr':>11s} {'engine mean':>11s} {'torch mean':>10s}"
    )
    worst, worst_scaling = float("inf"), float("inf")
    for name, (env, greedy) in rows.items():
        for pattern in args.patterns:
            k, r = (int(x) for x in pattern.split("x"))
            family = mutants(greedy, k, 3, args.seed, env.num_actions)
            with threads(1):
                simulate(env, family[:2], 2, torch.Generator(), backend="engine")  # compiled code loaded
            ratios, scaling, rates, means = [], [], [], None
            for _ in range(args.rounds):
                with threads(1):
                    engine_cpu, engine_wall, engine_mean = rate(env, family, r, "engine", k * r, args.repeats)
                    torch_cpu, _, torch_mean = rate(env, family, r, "torch", k * r, args.repeats)
                with threads(2):
                    _, two_wall, _ = rate(env, family, r, "engine", k * r, args.repeats)
                ratios.append(engine_cpu / torch_cpu)
                scaling.append(two_wall / engine_wall)
                means = (engine_mean, torch_mean)
                rates.append((engine_cpu, torch_cpu))
            ratio, scale = sorted(ratios)[len(ratios) // 2], sorted(scaling)[len(scaling) // 2]
            engine_rate, torch_rate = (sorted(r)[len(r) // 2] for r in zip(*rates))
            worst, worst_scaling = min(worst, ratio), min(worst_scaling, scale)
            print(
                f"{name:38s} {pattern:>8s} {engine_rate:13.0f} {torch_rate:12.0f} {ratio:6.1f}x {scale:10.2f}x "
                f"{means[0]:11.3f} {means[1]:10.3f}"
            )
    print(
        f"smallest ratio at one thread: {worst:.1f}x (floor 10x, aim 30x); "
        f"smallest two-thread scaling: {worst_scaling:.2f}x (floor 1.7x)"
    )


if __name__ == "__main__":
    main()
