"""What the cold-start planner reaches in about a CPU-minute on the compiled rollout engine.

Runs the planner with its default settings (``conf/planner/cold.yaml``) on package delivery (one
controller shared by both robots, as in the G-DICE paper's study) and on disaster relief with perfect
perception, at a rollout budget chosen to take about 60 CPU seconds on one thread, for several seeds.
Each best controller is re-evaluated on ``--reeval`` rollouts the search never saw.

    python benchmarks/bench_planner_budget.py [--seeds 0 1 2] [--pd-budget 18e6] [--dr-budget 20e6] [--domains pd dr]

Prints, per domain and seed: rollouts spent, CPU seconds, the re-evaluated value, and whether it
reached the floor (package delivery 14.4, disaster relief 6.0) within 60 CPU seconds.
"""

from __future__ import annotations

import argparse
import time


from decpomdp import evaluate
from decpomdp.domains import DisasterRelief, PackageDelivery, shared
from decpomdp.search import PlannerConfig, RolloutScorer, plan
from hbni_infra.threads import threads
from hbni_infra.streams import torch_stream

FLOORS = {"package delivery": 14.4, "disaster relief, perfect perception": 6.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--pd-budget", type=float, default=18e6)
    parser.add_argument("--dr-budget", type=float, default=20e6)
    parser.add_argument("--reeval", type=int, default=4000)
    parser.add_argument("--domains", nargs="+", choices=["pd", "dr"], default=["pd", "dr"])
    args = parser.parse_args()
    domains = {
        "package delivery": ("pd", PackageDelivery, True, args.pd_budget),
        "disaster relief, perfect perception": ("dr", DisasterRelief, False, args.dr_budget),
    }
    domains = {
        name: (make(), share, int(budget))
        for name, (key, make, share, budget) in domains.items()
        if key in args.domains
    }
    print("| domain | seed | rollouts | CPU s | value ± s.e. | floor within 60 CPU s |\n|---|---|---|---|---|---|")
    with threads(1):
        for name, (env, share, budget) in domains.items():
            for seed in args.seeds:
                cpu = time.process_time()
                result = plan(RolloutScorer(env, shared=share), PlannerConfig(budget=budget), seed=seed)
                cpu = time.process_time() - cpu
                best = shared(result.best, env.num_agents) if share else result.best
                mean, se = evaluate(env, best, args.reeval, torch_stream(seed, "reeval"))
                ok = float(mean) >= FLOORS[name] and cpu <= 60
                print(
                    f"| {name} | {seed} | {result.rollouts / 1e6:.1f} M | {cpu:.0f} | {float(mean):.3f} ± "
                    f"{float(se):.3f} | {'yes' if ok else 'no'} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
