"""Planning on package delivery (ICRA 2016): the cold-start planner, G-DICE cold and seeded, baselines, the paper.

Side by side, every controller re-evaluated on ``study.reeval_rollouts`` independent rollouts:

* the cold-start planner (``cold_planner``, :mod:`decpomdp.search`), from no controller at all, one
  controller per robot or shared (``study.cold_shared_controller``);
* the paper's G-DICE from uniform distributions (``planner``; also the alpha sweep), scoring each
  sample by ``study.rollouts`` rollouts, one controller per robot or shared (``study.shared_controller``);
* G-DICE seeded with the hand-written policy (``planner`` overridden by ``study.seeded``: initial
  distributions ``(1 - init_weight) * uniform + init_weight * greedy``);
* the hand-written greedy controller, Monte Carlo search over as many uniformly random controllers as
  the cold G-DICE samples, and the mean of random controllers;
* the paper's 14.44 like for like (``reference``): the paper's G-DICE with one shared controller on this
  domain and on ``reference.domain``, the preset that follows the reference simulator's rules
  (``conf/domain/package_delivery_reference.yaml`` cites them), ``reference.runs`` seeds each.

Writes ``metrics.json``, ``report.md`` (the table), ``baselines.png``, ``planner_progress.png``,
``value_vs_iteration.png`` (cold G-DICE), ``value_vs_iteration_seeded.png``, ``alpha_sweep.png`` and
the controllers ``best_controller_planner.safetensors``, ``best_controller.safetensors`` (seeded) and
``best_controller_cold.safetensors`` (load with ``decpomdp.JointController.load``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig

from decpomdp import GDICEConfig
from decpomdp.domains.package_delivery import greedy_controller
from decpomdp.search import PlannerConfig
from experiments.common import save_figure
from experiments.report import write_report
from experiments.steps.planning import paper_comparison, run_baselines, run_cold, run_gdice, run_seeded, score
from experiments.steps.planning_figures import bar_figure, comparison_table, history_figure, planner_figure

PAPER = {"gdice_best_sampled": 14.44, "mmcs": 4.53, "monte_carlo_search": 2.07}


def run(cfg: DictConfig, run_dir: Path) -> dict:
    study, seed = cfg.study, int(cfg.seed)
    torch.set_num_threads(int(study.threads))  # small tensors: one thread per job is fastest on shared cores
    env = instantiate(cfg.domain)
    config: GDICEConfig = instantiate(cfg.planner)
    reeval = int(study.reeval_rollouts)

    cold_cfg: PlannerConfig = instantiate(cfg.cold_planner)
    planner, planner_best, planner_score = run_cold(env, cold_cfg, bool(study.cold_shared_controller), seed + 600,
                                                    bool(cfg.progress), reeval)
    planner_best.save(run_dir / "best_controller_planner.safetensors")
    save_figure(planner_figure(planner.history, "Cold-start planner on package delivery"), run_dir / "planner_progress.png")

    result, best, seconds = run_gdice(env, config, study, seed, bool(cfg.progress))
    best.save(run_dir / "best_controller_cold.safetensors")
    gdice_score = {"best_sampled": result.best_value, "seconds": seconds, **score(env, best, reeval, seed + 10)}
    save_figure(history_figure(result.history, "G-DICE on package delivery"), run_dir / "value_vs_iteration.png")
    seeded, seeded_best, seeded_score = run_seeded(env, config, study, greedy_controller(), seed + 500,
                                                   bool(cfg.progress))
    seeded_best.save(run_dir / "best_controller.safetensors")
    save_figure(history_figure(seeded.history, "G-DICE seeded with the hand-written policy, package delivery"),
                run_dir / "value_vs_iteration_seeded.png")

    sweep = {}
    for k, alpha in enumerate(study.alpha_sweep):
        sweep_cfg = dataclasses.replace(config, alpha=float(alpha), iterations=int(study.sweep_iterations))
        res, ctrl, secs = run_gdice(env, sweep_cfg, study, seed + 100 + k, bool(cfg.progress))
        sweep[str(alpha)] = {"alpha": float(alpha), "history_best": res.history["best"], "best_sampled": res.best_value,
                             "seconds": secs, **score(env, ctrl, reeval, seed + 200 + k)}
    save_figure(_sweep_figure(sweep), run_dir / "alpha_sweep.png")

    baselines = run_baselines(env, config, study, seed + 300)
    greedy = score(env, greedy_controller(), reeval, seed + 400)
    ref = cfg.reference
    paper = paper_comparison(env, instantiate(ref.domain), instantiate(ref.planner), int(ref.rollouts), int(ref.runs),
                             seed + 700, reeval, bool(cfg.progress))
    entries = {"cold-start planner": planner_score, "G-DICE": gdice_score, "G-DICE seeded": seeded_score,
               "greedy (hand)": greedy, "Monte Carlo search": baselines["monte_carlo_search"], "random": baselines["random"]}
    save_figure(bar_figure(entries, "Package delivery: re-evaluated values",
                           {"paper G-DICE 14.44": PAPER["gdice_best_sampled"], "paper MCS 2.07": PAPER["monte_carlo_search"]}),
                run_dir / "baselines.png")
    write_report(run_dir / "report.md", _report(entries, paper, reeval))
    mcs_value = baselines["monte_carlo_search"]["value"]
    return {
        "planner_cold_start": planner_score,
        "planner_cold_start_history": planner.history,
        "planner_cold_start_config": dataclasses.asdict(cold_cfg),
        "paper_comparison": {"paper_best_sampled": PAPER["gdice_best_sampled"], **paper},
        "domain": repr(env),
        "planner": dataclasses.asdict(config),
        "shared_controller": bool(study.shared_controller),
        "rollouts_per_evaluation": int(study.rollouts),
        "reeval_rollouts": reeval,
        "gdice": gdice_score,
        "gdice_history": result.history,
        "gdice_seeded": seeded_score,
        "gdice_seeded_history": seeded.history,
        "alpha_sweep": sweep,
        "baselines": {**baselines, "greedy": greedy},
        "paper": PAPER,
        "acceptance": {
            "planner_at_least_greedy": planner_score["value"] >= greedy["value"],
            "planner_at_least_14.4": planner_score["value"] >= 14.4,
            "gdice_at_least_14.4": gdice_score["value"] >= 14.4,
            "mcs_at_most_third_of_gdice": mcs_value <= gdice_score["value"] / 3,
            "seeded_gdice_at_least_14.4": seeded_score["value"] >= 14.4,
            "mcs_at_most_third_of_seeded_gdice": mcs_value <= seeded_score["value"] / 3,
        },
    }


def _report(entries: dict[str, dict], paper: dict[str, dict], reeval: int) -> str:
    this, preset = paper["this_domain"], paper["preset"]
    lines = ["# Package delivery: planners side by side", "",
             f"Every controller re-evaluated on {reeval} rollouts that its search never saw.", "",
             *comparison_table(entries), "",
             "## The paper's 14.44, like for like", "",
             "The paper's G-DICE (one controller shared by both robots), its best sampled value (a maximum over",
             "noisy scores, what the paper reports) and its best controller re-evaluated, mean ± s.e. over "
             f"{len(this['values'])} seeds:", "",
             "| domain | best sampled | re-evaluated |", "|---|---|---|",
             f"| this domain | {this['best_sampled_mean']:.2f} ± {this['best_sampled_stderr']:.2f} | "
             f"{this['value']:.2f} ± {this['stderr']:.2f} |",
             f"| reference-rules preset | {preset['best_sampled_mean']:.2f} ± {preset['best_sampled_stderr']:.2f} | "
             f"{preset['value']:.2f} ± {preset['stderr']:.2f} |",
             f"| paper (reference simulator) | {PAPER['gdice_best_sampled']:.2f} | – |", ""]
    return "\n".join(lines) + "\n"


def _sweep_figure(sweep: dict[str, dict[str, Any]]) -> plt.Figure:
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    for entry in sweep.values():
        ax.plot(range(1, len(entry["history_best"]) + 1), entry["history_best"],
                label=f"alpha = {entry['alpha']:g} (re-evaluated {entry['value']:.2f})")
    ax.set_xlabel("G-DICE iteration")
    ax.set_ylabel("best sampled value so far")
    ax.set_title("Package delivery: learning rate alpha")
    ax.legend(fontsize=8)
    return fig
