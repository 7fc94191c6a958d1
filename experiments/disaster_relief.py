"""G-DICE on health-aware disaster relief against the greedy policy, Monte Carlo search and random controllers.

The team shares one controller (``study.shared_controller``). Every reported policy is
re-evaluated on ``study.reeval_rollouts`` independent rollouts, with per-rollout counts of
objects delivered right, wrong deliveries, inferences, inference frames and repairs. Writes
``metrics.json``, ``value_vs_iteration.png``, ``comparison.png``, ``counters.png`` and
``best_controller.safetensors``.
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
from decpomdp.policies import disaster_relief_greedy
from experiments.common import save_figure
from experiments.package_delivery import bar_figure, history_figure, run_baselines, run_gdice, score

COUNTS = ("delivered", "wrong", "inferences", "inference_frames", "repairs")


def run(cfg: DictConfig, run_dir: Path) -> dict:
    study, seed = cfg.study, int(cfg.seed)
    torch.set_num_threads(int(study.threads))
    env = instantiate(cfg.domain)
    config: GDICEConfig = instantiate(cfg.planner)
    reeval = int(study.reeval_rollouts)

    result, best, seconds = run_gdice(env, config, study, seed, bool(cfg.progress))
    best.save(run_dir / "best_controller.safetensors")
    gdice_score = {"best_sampled": result.best_value, "seconds": seconds, **score(env, best, reeval, seed + 10)}
    save_figure(history_figure(result.history, "G-DICE on disaster relief"), run_dir / "value_vs_iteration.png")
    baselines = run_baselines(env, config, study, seed + 300)
    greedy = score(env, disaster_relief_greedy(env.num_agents), reeval, seed + 400)
    entries = {"G-DICE": gdice_score, "greedy": greedy, "Monte Carlo search": baselines["monte_carlo_search"],
               "random": baselines["random"]}
    save_figure(bar_figure(entries, "Disaster relief: re-evaluated values"), run_dir / "comparison.png")
    save_figure(_counters_figure({k: v for k, v in entries.items() if k != "random"}), run_dir / "counters.png")

    def beats(other: dict) -> bool:
        return gdice_score["value"] - gdice_score["stderr"] > other["value"] + other["stderr"]

    return {
        "domain": repr(env),
        "planner": dataclasses.asdict(config),
        "shared_controller": bool(study.shared_controller),
        "rollouts_per_evaluation": int(study.rollouts),
        "reeval_rollouts": reeval,
        "gdice": gdice_score,
        "gdice_history": result.history,
        "baselines": {**baselines, "greedy": greedy},
        "acceptance": {"gdice_beats_greedy": beats(greedy),
                       "gdice_beats_monte_carlo_search": beats(baselines["monte_carlo_search"])},
    }


def _counters_figure(entries: dict[str, dict]) -> plt.Figure:
    fig, axes = plt.subplots(1, len(COUNTS), figsize=(13, 3.2))
    names = list(entries)
    for ax, key in zip(axes, COUNTS):
        ax.bar(np.arange(len(names)), [entries[n][f"{key}_per_rollout"] for n in names],
               yerr=[entries[n][f"{key}_stderr"] for n in names], capsize=3, color=["tab:blue", "tab:orange", "tab:green"])
        ax.set_xticks(np.arange(len(names)), names, rotation=30, ha="right", fontsize=8)
        ax.set_title(key.replace("_", " ") + " / rollout", fontsize=9)
    fig.tight_layout()
    return fig
