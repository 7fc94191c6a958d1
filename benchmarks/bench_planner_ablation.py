"""What each part of the cold-start planner contributes: the planner with one part removed at a time.

Every variant runs from scratch on the same rollout budget and seed, and its best controller is
re-evaluated on ``--reeval`` rollouts the search never saw. Variants (the domain's experiment's
``planners.cold``, ``conf/planner/cold.yaml`` with the experiment's overrides, with one change):

* ``full``: the planner as configured;
* ``no agent copies``: ``ls_copy: false`` (no effect with a shared controller);
* ``reactive start``: ``ce_reactive: true`` with a 9-node cold start (``start_nodes: 9``);
* ``no local search``: cross-entropy phases only (``phases: [ce]``);
* ``no cross-entropy``: local search only, from node 0 running MA 0 (``phases: [ls]``);
* ``no chains``: local search with single edits only (``ls_chain: 0``);
* ``no team moves``: every move by one robot (``ls_team: false``; no effect with a shared controller);
* ``no racing``: local search scores every move on 128 rollouts (as many moves as the racing budget
  pays for), cross-entropy scores every sample on 80 (90 samples, the racing budget);
* ``no elite memory``: ``ce_memory: 0``;
* ``13 nodes``: the paper's node count instead of growing to 24;
* ``G-DICE``: the planner's G-DICE preset (:func:`decpomdp.search.gdice_config`: 13 nodes, 100 samples,
  10 elites, alpha 0.1, 80 rollouts per sample) run for as many iterations as the budget pays for.

Prints a markdown table (value +- s.e., rollouts, CPU seconds) and writes it as JSON to ``--out``.

    python benchmarks/bench_planner_ablation.py --domain package_delivery [--budget 20000000] [--seed 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import torch
from hydra.utils import instantiate

from decpomdp.domains import DisasterRelief, PackageDelivery, rollout_counters, shared
from decpomdp.search import PlannerConfig, RolloutScorer, gdice_config, plan
from experiments.schemas import compose_settings
from hbni_infra.files import atomic_write_text
from hbni_infra.streams import torch_stream


VARIANTS = {
    "full": {},
    "no agent copies": {"ls_copy": False},
    "reactive start": {"ce_reactive": True, "start_nodes": 9},
    "no local search": {"phases": ("ce",)},
    "no cross-entropy": {"phases": ("ls",)},
    "no chains": {"ls_chain": 0},
    "no team moves": {"ls_team": False},
    "no racing": {"ls_stages": ((128, 4),), "ls_candidates": 6450, "ce_screen_rollouts": 0, "ce_samples": 90},
    "no elite memory": {"ce_memory": 0},
    "13 nodes": {"num_nodes": 13},
}
DOMAINS = {"package_delivery": (PackageDelivery, True), "disaster_relief": (DisasterRelief, False)}


def experiment_planner(domain: str) -> PlannerConfig:
    """The ``planners.cold`` of ``experiment=<domain>`` (``conf/planner/cold.yaml`` and the experiment's overrides)."""
    return instantiate(compose_settings([f"experiment={domain}"]).planners.cold)


def run_variant(env, shared_controller: bool, name: str, config: PlannerConfig, seed: int, reeval: int) -> dict:
    cpu = time.process_time()
    if name == "G-DICE":
        config = gdice_config(ce_iterations=max(1, config.budget // (100 * 80)))
    out = plan(RolloutScorer(env, shared=shared_controller), config, seed=seed)
    best, rollouts = out.best, out.rollouts
    cpu = time.process_time() - cpu
    team = shared(best, env.num_agents) if shared_controller else best
    returns, _ = rollout_counters(env, team, reeval, torch_stream(seed, "reeval"))
    return {
        "variant": name,
        "value": float(returns.mean()),
        "stderr": float(returns.std() / reeval**0.5),
        "rollouts": rollouts,
        "cpu_seconds": cpu,
        "nodes": best.num_nodes,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domain", choices=sorted(DOMAINS), default="package_delivery")
    parser.add_argument("--budget", type=int, default=None, help="rollouts per run (default: the planner's)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--reeval", type=int, default=4000)
    parser.add_argument("--variants", nargs="*", default=[*VARIANTS, "G-DICE"])
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    make, shared_controller = DOMAINS[args.domain]
    env = make()
    base = experiment_planner(args.domain)
    if args.budget is not None:
        base = dataclasses.replace(base, budget=args.budget)
    rows = []
    for name in args.variants:
        config = dataclasses.replace(base, **VARIANTS.get(name, {}))
        rows.append(run_variant(env, shared_controller, name, config, args.seed, args.reeval))
        r = rows[-1]
        print(
            f"{args.domain} | {name} | {r['value']:.3f} +- {r['stderr']:.3f} | {r['rollouts']:,} | {r['cpu_seconds']:.0f} s",
            file=sys.stderr,
            flush=True,
        )  # progress; the table below is the result
    print(f"\n{args.domain}, budget {base.budget:,} rollouts, seed {args.seed}, values on {args.reeval} fresh rollouts")
    print("| variant | value +- s.e. | rollouts | CPU s |\n|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['variant']} | {r['value']:.3f} +- {r['stderr']:.3f} | {r['rollouts']:,} | {r['cpu_seconds']:.0f} |"
        )
    if args.out is not None:
        atomic_write_text(
            args.out,
            json.dumps({"domain": args.domain, "budget": base.budget, "seed": args.seed, "rows": rows}, indent=2)
            + "\n",
        )
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
