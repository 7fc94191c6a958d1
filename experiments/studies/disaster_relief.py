"""Planning on health-aware disaster relief: the cold-start planner, G-DICE cold and seeded, baselines.

Side by side: the cold-start planner (``planners.cold``, :mod:`decpomdp.search`), the paper's G-DICE from
uniform distributions (``planners.gdice``), "G-DICE seeded with the hand-written policy" (``planners.gdice``
overridden by ``study.seeded``, warm-started from the greedy controller), the greedy controller, Monte Carlo
search and random controllers; every planner searches one controller per robot or one shared by the team
(``study.shared_controller``). Every reported policy is
re-evaluated on ``study.reeval_rollouts`` independent rollouts, with per-rollout counts of objects
delivered right, wrong deliveries, inferences, inference frames and repairs. Writes ``metrics.json``,
``report.md`` (the table), ``comparison.png``, ``counters.png``, ``planner_progress.png``,
``value_vs_iteration.png`` (cold G-DICE), ``value_vs_iteration_seeded.png`` and the controllers
``best_controller_planner.safetensors``, ``best_controller.safetensors`` (seeded) and
``best_controller_cold.safetensors``.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from hydra.utils import instantiate

from decpomdp.domains.disaster_relief import greedy_controller
from experiments.reports.planning_figures import bar_figure, comparison_table
from experiments.reports.scores import beats
from experiments.runs.outputs import save_figure, write_report
from experiments.schemas.planning_studies import DisasterReliefExperiment
from experiments.steps.planner_comparison import compare_planners
from hbni_infra.threads import set_threads

COUNTS = ("delivered", "wrong", "inferences", "inference_frames", "repairs")


def run(settings: DisasterReliefExperiment, run_dir: Path) -> dict:
    set_threads(settings.study.threads)  # torch and the rollout engine
    env = instantiate(settings.domain)
    entries, metrics = compare_planners(settings, env, greedy_controller(env.num_agents), "disaster relief", run_dir)
    save_figure(bar_figure(entries, "Disaster relief: re-evaluated values"), run_dir / "comparison.png")
    write_report(
        run_dir / "report.md",
        "\n".join(
            [
                "# Disaster relief: planners side by side",
                "",
                f"Perception: {env.perception!r}. Every controller "
                f"re-evaluated on {metrics['reeval_rollouts']} rollouts that its search never saw.",
                "",
                *comparison_table(entries),
            ]
        )
        + "\n",
    )
    save_figure(_counters_figure({k: v for k, v in entries.items() if k != "random"}), run_dir / "counters.png")
    planner, gdice, seeded = metrics["planner_cold_start"], metrics["gdice"], metrics["gdice_seeded"]
    greedy, mcs = metrics["baselines"]["greedy"], metrics["baselines"]["monte_carlo_search"]
    return {
        **metrics,
        "acceptance": {
            "planner_beats_greedy": beats(planner, greedy),
            "planner_at_least_greedy": planner["value"] >= greedy["value"],
            "gdice_beats_greedy": beats(gdice, greedy),
            "gdice_beats_monte_carlo_search": beats(gdice, mcs),
            "seeded_gdice_beats_greedy": beats(seeded, greedy),
            "seeded_gdice_beats_monte_carlo_search": beats(seeded, mcs),
        },
    }


def _counters_figure(entries: dict[str, dict]) -> plt.Figure:
    fig, axes = plt.subplots(1, len(COUNTS), figsize=(13, 3.2))
    names = list(entries)
    for ax, key in zip(axes, COUNTS):
        ax.bar(
            np.arange(len(names)),
            [entries[n][f"{key}_per_rollout"] for n in names],
            yerr=[entries[n][f"{key}_stderr"] for n in names],
            capsize=3,
            color=["tab:blue", "tab:cyan", "tab:orange", "tab:green"],
        )
        ax.set_xticks(np.arange(len(names)), names, rotation=30, ha="right", fontsize=8)
        ax.set_title(key.replace("_", " ") + " / rollout", fontsize=9)
    fig.tight_layout()
    return fig
