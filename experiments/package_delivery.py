"""G-DICE on package delivery (ICRA 2016): value against iteration, a sweep over alpha, and baselines.

G-DICE searches one finite-state controller that both robots run (as the reference study did;
``study.shared_controller``), scoring each sample by ``study.rollouts`` Monte Carlo rollouts; the
best controller is re-evaluated on ``study.reeval_rollouts`` independent rollouts. Two G-DICE runs
are reported: the paper's cold start (``planner``, uniform initial distributions; also the alpha
sweep) and "G-DICE seeded with the hand-written policy" (``planner`` overridden by
``study.seeded``: initial distributions ``(1 - init_weight) * uniform + init_weight * greedy``).
Baselines: Monte Carlo search over as many uniformly random controllers as the cold G-DICE samples,
the mean of random controllers, and the hand-written greedy controller. Writes ``metrics.json``,
``value_vs_iteration.png`` (cold), ``value_vs_iteration_seeded.png``, ``alpha_sweep.png``,
``baselines.png`` and the best joint controllers ``best_controller.safetensors`` (seeded) and
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
from experiments.common import save_figure
from experiments.steps.planning import run_baselines, run_gdice, run_seeded, score
from experiments.steps.planning_figures import bar_figure, history_figure

PAPER = {"gdice_best_sampled": 14.44, "mmcs": 4.53, "monte_carlo_search": 2.07}


def run(cfg: DictConfig, run_dir: Path) -> dict:
    study, seed = cfg.study, int(cfg.seed)
    torch.set_num_threads(int(study.threads))  # small tensors: one thread per job is fastest on shared cores
    env = instantiate(cfg.domain)
    config: GDICEConfig = instantiate(cfg.planner)
    reeval = int(study.reeval_rollouts)

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
    entries = {"G-DICE seeded": seeded_score, "G-DICE": gdice_score, "greedy (hand)": greedy, "Monte Carlo search": baselines["monte_carlo_search"],
               "random": baselines["random"]}
    save_figure(bar_figure(entries, "Package delivery: re-evaluated values",
                           {"paper G-DICE 14.44": PAPER["gdice_best_sampled"], "paper MCS 2.07": PAPER["monte_carlo_search"]}),
                run_dir / "baselines.png")
    mcs_value = baselines["monte_carlo_search"]["value"]
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
        "alpha_sweep": sweep,
        "baselines": {**baselines, "greedy": greedy},
        "paper": PAPER,
        "acceptance": {
            "gdice_at_least_14.4": gdice_score["value"] >= 14.4,
            "mcs_at_most_third_of_gdice": mcs_value <= gdice_score["value"] / 3,
            "seeded_gdice_at_least_14.4": seeded_score["value"] >= 14.4,
            "mcs_at_most_third_of_seeded_gdice": mcs_value <= seeded_score["value"] / 3,
        },
    }


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
