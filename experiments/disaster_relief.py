"""Planning on health-aware disaster relief: the cold-start planner, G-DICE cold and seeded, baselines.

Side by side: the cold-start planner (``cold_planner``, :mod:`decpomdp.search`, one controller per
robot or shared: ``study.cold_shared_controller``), the paper's G-DICE from uniform distributions
(``planner``), "G-DICE seeded with the hand-written policy" (``planner`` overridden by
``study.seeded``, warm-started from the greedy controller), the greedy controller, Monte Carlo search
and random controllers (G-DICE's team: ``study.shared_controller``). Every reported policy is
re-evaluated on ``study.reeval_rollouts`` independent rollouts, with per-rollout counts of objects
delivered right, wrong deliveries, inferences, inference frames and repairs. Writes ``metrics.json``,
``report.md`` (the table), ``comparison.png``, ``counters.png``, ``planner_progress.png``,
``value_vs_iteration.png`` (cold G-DICE), ``value_vs_iteration_seeded.png`` and the controllers
``best_controller_planner.safetensors``, ``best_controller.safetensors`` (seeded) and
``best_controller_cold.safetensors``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig

from decpomdp import GDICEConfig
from decpomdp.domains.disaster_relief import greedy_controller
from decpomdp.search import PlannerConfig
from experiments.common import beats, save_figure
from experiments.report import write_report
from experiments.steps.planning import run_baselines, run_cold, run_gdice, run_seeded, score
from experiments.steps.planning_figures import bar_figure, comparison_table, history_figure, planner_figure

COUNTS = ("delivered", "wrong", "inferences", "inference_frames", "repairs")


def run(cfg: DictConfig, run_dir: Path) -> dict:
    study, seed = cfg.study, int(cfg.seed)
    torch.set_num_threads(int(study.threads))
    env = instantiate(cfg.domain)
    config: GDICEConfig = instantiate(cfg.planner)
    reeval = int(study.reeval_rollouts)

    cold_cfg: PlannerConfig = instantiate(cfg.cold_planner)
    planner, planner_best, planner_score = run_cold(env, cold_cfg, bool(study.cold_shared_controller), seed + 600,
                                                    bool(cfg.progress), reeval)
    planner_best.save(run_dir / "best_controller_planner.safetensors")
    save_figure(planner_figure(planner.history, "Cold-start planner on disaster relief"), run_dir / "planner_progress.png")

    result, best, seconds = run_gdice(env, config, study, seed, bool(cfg.progress))
    best.save(run_dir / "best_controller_cold.safetensors")
    gdice_score = {"best_sampled": result.best_value, "seconds": seconds, **score(env, best, reeval, seed + 10)}
    save_figure(history_figure(result.history, "G-DICE on disaster relief"), run_dir / "value_vs_iteration.png")
    greedy_policy = greedy_controller(env.num_agents)
    seeded, seeded_best, seeded_score = run_seeded(env, config, study, greedy_policy, seed + 500, bool(cfg.progress))
    seeded_best.save(run_dir / "best_controller.safetensors")
    save_figure(history_figure(seeded.history, "G-DICE seeded with the hand-written policy, disaster relief"),
                run_dir / "value_vs_iteration_seeded.png")
    baselines = run_baselines(env, config, study, seed + 300)
    greedy = score(env, greedy_policy, reeval, seed + 400)
    entries = {"cold-start planner": planner_score, "G-DICE": gdice_score, "G-DICE seeded": seeded_score, "greedy": greedy,
               "Monte Carlo search": baselines["monte_carlo_search"], "random": baselines["random"]}
    save_figure(bar_figure(entries, "Disaster relief: re-evaluated values"), run_dir / "comparison.png")
    write_report(run_dir / "report.md", "\n".join([
        "# Disaster relief: planners side by side", "", f"Perception: {env.perception!r}. Every controller "
        f"re-evaluated on {reeval} rollouts that its search never saw.", "", *comparison_table(entries)]) + "\n")
    save_figure(_counters_figure({k: v for k, v in entries.items() if k != "random"}), run_dir / "counters.png")

    return {
        "planner_cold_start": planner_score,
        "planner_cold_start_history": planner.history,
        "planner_cold_start_config": dataclasses.asdict(cold_cfg),
        "domain": repr(env),
        "planner": dataclasses.asdict(config),
        "shared_controller": bool(study.shared_controller),
        "rollouts_per_evaluation": int(study.rollouts),
        "reeval_rollouts": reeval,
        "gdice": gdice_score,
        "gdice_history": result.history,
        "gdice_seeded": seeded_score,
        "gdice_seeded_history": seeded.history,
        "baselines": {**baselines, "greedy": greedy},
        "acceptance": {"planner_beats_greedy": beats(planner_score, greedy),
                       "planner_at_least_greedy": planner_score["value"] >= greedy["value"],
                       "gdice_beats_greedy": beats(gdice_score, greedy),
                       "gdice_beats_monte_carlo_search": beats(gdice_score, baselines["monte_carlo_search"]),
                       "seeded_gdice_beats_greedy": beats(seeded_score, greedy),
                       "seeded_gdice_beats_monte_carlo_search": beats(seeded_score, baselines["monte_carlo_search"])},
    }


def _counters_figure(entries: dict[str, dict]) -> plt.Figure:
    fig, axes = plt.subplots(1, len(COUNTS), figsize=(13, 3.2))
    names = list(entries)
    for ax, key in zip(axes, COUNTS):
        ax.bar(np.arange(len(names)), [entries[n][f"{key}_per_rollout"] for n in names],
               yerr=[entries[n][f"{key}_stderr"] for n in names], capsize=3, color=["tab:blue", "tab:cyan", "tab:orange", "tab:green"])
        ax.set_xticks(np.arange(len(names)), names, rotation=30, ha="right", fontsize=8)
        ax.set_title(key.replace("_", " ") + " / rollout", fontsize=9)
    fig.tight_layout()
    return fig
