"""G-DICE at the paper's package-delivery budget against the cold-start planner: time and value reached.

Three runs on package delivery, every robot running one shared controller (as in the reference study):

1. the paper's G-DICE (N_n = 13, N_k = 100, N_s = 100, N_b = 10, alpha = 0.1, 80 rollouts per sample:
   800,000 rollouts);
2. the cold-start planner (:mod:`decpomdp.search`) held to the same 800,000 rollouts;
3. the cold-start planner at its default settings (``PlannerConfig()``, what ``conf/planner/cold.yaml`` composes).

Each best controller is re-evaluated on ``--reeval`` rollouts the search never saw. Times are process
CPU time and wall time of this process; on a shared machine the wall time also counts other jobs, so
the ratio of CPU times is the comparison to read. For reference in the same process, the script also
times one G-DICE iteration's evaluation on a tabular problem (the shipped Dec-Tiger, horizon 50, same
batch of 100 x 80 rollouts).

    python benchmarks/bench_gdice.py [--seed 0] [--reeval 4000] [--skip-default]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import torch

from decpomdp import evaluate, random_controllers
from decpomdp.domains import PackageDelivery, shared
from decpomdp.dpomdp import TabularDecPOSMDP
from decpomdp.search import PlannerConfig, RolloutScorer, gdice_config, plan
from hbni_infra.streams import torch_generator, torch_stream

PAPER_ROLLOUTS = 100 * 100 * 80


def timed(fn):
    cpu, wall = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - cpu, time.perf_counter() - wall


def tiger_iteration_cpu(seed: int) -> float:
    """CPU seconds of one G-DICE iteration's evaluation on Dec-Tiger (horizon 50, 100 samples x 80 rollouts)."""
    tiger = TabularDecPOSMDP.from_problem("dectiger", gamma=0.99, horizon=50)
    gen = torch_generator(seed)
    ctrl = random_controllers(
        100, num_agents=2, num_nodes=13, num_actions=tiger.num_actions, num_obs=tiger.num_obs, generator=gen
    )
    return timed(lambda: RolloutScorer(tiger)(ctrl, 80, gen))[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--reeval", type=int, default=4000)
    parser.add_argument("--skip-default", action="store_true", help="skip the planner at its default budget")
    args = parser.parse_args()
    torch.set_num_threads(1)  # batches of ~8000 rollouts: intra-op threads only add overhead on a shared machine
    env = PackageDelivery()
    reeval = lambda ctrl: evaluate(env, shared(ctrl, 2), args.reeval, torch_stream(args.seed, "reeval"))  # noqa: E731

    rows = []
    paper = gdice_config()
    res, cpu, wall = timed(lambda: plan(RolloutScorer(env, shared=True), paper, seed=args.seed, progress=True))
    rows.append(("paper G-DICE", PAPER_ROLLOUTS, cpu, wall, *reeval(res.best)))
    default = PlannerConfig()  # conf/planner/cold.yaml: the planner's defaults
    runs = [("cold-start planner, paper budget", dataclasses.replace(default, budget=PAPER_ROLLOUTS))]
    if not args.skip_default:
        runs.append(("cold-start planner, default budget", default))
    for name, cfg in runs:
        out, cpu, wall = timed(
            lambda cfg=cfg: plan(RolloutScorer(env, shared=True), cfg, seed=args.seed, progress=True)
        )
        rows.append((name, out.rollouts, cpu, wall, *reeval(out.best)))
    ref = rows[0][2]
    print(
        f"\npackage delivery, shared controller, seed {args.seed}; values re-evaluated on {args.reeval} fresh rollouts"
    )
    print("| run | rollouts | CPU s | wall s | CPU / paper G-DICE | value +- s.e. |\n|---|---|---|---|---|---|")
    for name, rollouts, cpu, wall, mean, se in rows:
        print(
            f"| {name} | {rollouts:,} | {cpu:.1f} | {wall:.1f} | {cpu / ref:.2f} | {float(mean):.3f} +- {float(se):.3f} |"
        )
    tab = tiger_iteration_cpu(args.seed)
    print(
        f"one G-DICE iteration (CPU s): package delivery {ref / paper.ce_iterations:.3f} vs Dec-Tiger horizon 50 "
        f"(8000 rollouts, 50 events) {tab:.3f}; ratio {ref / paper.ce_iterations / tab:.2f}"
    )


if __name__ == "__main__":
    main()
