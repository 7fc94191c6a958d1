"""G-DICE on health-aware disaster relief against the greedy policy, Monte Carlo search and random controllers.

The team shares one controller (``study.shared_controller``). Two G-DICE runs are reported: the
cold start (``planner``) and "G-DICE seeded with the hand-written policy" (``planner`` overridden by
``study.seeded``, warm-started from robot 0's greedy controller). Every reported policy is
re-evaluated on ``study.reeval_rollouts`` independent rollouts, with per-rollout counts of
objects delivered right, wrong deliveries, inferences, inference frames and repairs. Writes
``metrics.json``, ``value_vs_iteration.png`` (cold), ``value_vs_iteration_seeded.png``,
``comparison.png``, ``counters.png``, ``best_controller.safetensors`` (seeded) and
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
from experiments.common import beats, save_figure
from experiments.steps.planning import run_baselines, run_gdice, run_seeded, score
from experiments.steps.planning_figures import bar_figure, history_figure

COUNTS = ("delivered", "wrong", "inferences", "inference_frames", "repairs")


def run(cfg: DictConfig, run_dir: Path) -> dict:
    study, seed = cfg.study, int(cfg.seed)
    torch.set_num_threads(int(study.threads))
    env = instantiate(cfg.domain)
    config: GDICEConfig = instantiate(cfg.planner)
    reeval = int(study.reeval_rollouts)

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
    entries = {"G-DICE seeded": seeded_score, "G-DICE": gdice_score, "greedy": greedy, "Monte Carlo search": baselines["monte_carlo_search"],
               "random": baselines["random"]}
    save_figure(bar_figure(entries, "Disaster relief: re-evaluated values"), run_dir / "comparison.png")
    save_figure(_counters_figure({k: v for k, v in entries.items() if k != "random"}), run_dir / "counters.png")

    return {
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
        "acceptance": {"gdice_beats_greedy": beats(gdice_score, greedy),
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
