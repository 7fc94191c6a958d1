"""G-DICE at the paper's package-delivery settings: wall time and value reached.

N_n = 13, N_k = 100, N_s = 100, N_b = 10, alpha = 0.1, 80 rollouts per evaluation (all 100 x 80
rollouts of an iteration in one batched simulation). The floor is 2 minutes on 2 cores. The best
controller is re-evaluated on 1000 independent rollouts. For reference in the same process, the
script also times one iteration's evaluation on a tabular problem (Dec-Tiger, horizon 50, same batch).

    python benchmarks/bench_gdice.py [--seed 0] [--iterations 100]
"""

from __future__ import annotations

import argparse
import time

import torch

from decpomdp import GDICEConfig, MonteCarloEvaluator, gdice, random_controllers
from decpomdp.domains import PackageDelivery
from decpomdp.dpomdp import TabularDecPOSMDP


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--iterations", type=int, default=100)
    args = parser.parse_args()
    torch.set_num_threads(1)  # tensors of ~8000 rollouts: intra-op threads only add overhead on a shared machine
    env = PackageDelivery()
    cfg = GDICEConfig(num_nodes=13, iterations=args.iterations, samples=100, elites=10, alpha=0.1)
    start = time.perf_counter()
    result = gdice(MonteCarloEvaluator(env, 80), env.num_agents, env.num_actions, env.num_obs, cfg, seed=args.seed,
                   reevaluator=MonteCarloEvaluator(env, 1000), progress=True)
    elapsed = time.perf_counter() - start
    print(f"package delivery G-DICE (N_n=13, N_k={args.iterations}, N_s=100, N_b=10, 80 rollouts): {elapsed:.1f} s "
          f"(floor 120 s: {'met' if elapsed <= 120 else 'NOT met'}; {120 / elapsed:.2f}x under the floor)")
    print(f"best sampled value {result.best_value:.3f}; re-evaluated on 1000 rollouts: "
          f"{result.value:.3f} +- {result.stderr:.3f}")
    per_iter = elapsed / args.iterations
    tiger = TabularDecPOSMDP.from_problem("dectiger", gamma=0.99, horizon=50)
    ev = MonteCarloEvaluator(tiger, 80)
    gen = torch.Generator().manual_seed(args.seed)
    ctrl = random_controllers(100, 2, 13, tiger.num_actions, tiger.num_obs, gen)
    t0 = time.perf_counter()
    ev(ctrl, gen)
    tab = time.perf_counter() - t0
    print(f"one G-DICE iteration: package delivery {per_iter:.3f} s vs Dec-Tiger horizon 50 "
          f"(8000 rollouts, 50 events) {tab:.3f} s; ratio {per_iter / tab:.2f}")


if __name__ == "__main__":
    main()
