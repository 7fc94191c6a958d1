"""Planning on package delivery (ICRA 2016): the cold-start planner, G-DICE cold and seeded, baselines, the paper.

Side by side, every controller re-evaluated on ``study.reeval_rollouts`` independent rollouts:

* the cold-start planner (``planners.cold``, :mod:`decpomdp.search`), from no controller at all;
* the paper's G-DICE from uniform distributions (``planners.gdice``, the planner's G-DICE preset; also the
  alpha sweep), scoring each sample by ``ce_rollouts`` rollouts;
* G-DICE seeded with the hand-written policy (``planners.gdice`` overridden by ``study.seeded``: initial
  distributions ``(1 - ce_init_weight) * uniform + ce_init_weight * greedy``);
* the hand-written greedy controller, Monte Carlo search over as many uniformly random controllers as
  the cold G-DICE samples, and the mean of random controllers;
* every planner searches one controller per robot or one shared by the team (``study.shared_controller``);
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
from hydra.utils import instantiate

from decpomdp.search import PlannerConfig
from decpomdp.domains.package_delivery import greedy_controller
from experiments.reports.planning_figures import bar_figure, comparison_table
from experiments.runs.outputs import save_figure, write_report
from experiments.schemas.planning_studies import PackageDeliveryExperiment
from experiments.steps.planner_comparison import compare_planners
from experiments.steps.planning import paper_comparison, run_planner
from hbni_infra.threads import set_threads
from hbni_infra.streams import stream_seed

PAPER = {"gdice_best_sampled": 14.44, "mmcs": 4.53, "monte_carlo_search": 2.07}


def run(settings: PackageDeliveryExperiment, run_dir: Path) -> dict:
    study, seed, progress = settings.study, settings.seed, settings.progress
    set_threads(study.threads)  # torch and the rollout engine
    env = instantiate(settings.domain)
    config: PlannerConfig = instantiate(settings.planners.gdice)
    reeval = study.reeval_rollouts
    entries, metrics = compare_planners(settings, env, greedy_controller(), "package delivery", run_dir)

    sweep = {}
    for k, alpha in enumerate(study.alpha_sweep):
        swept = dataclasses.replace(config, ce_alpha=alpha, ce_iterations=study.sweep_iterations)
        res, _, entry = run_planner(
            env, swept, study.shared_controller, stream_seed(seed, "sweep", k), progress, reeval
        )
        sweep[str(alpha)] = {"alpha": alpha, "history_best": res.history["best_sampled"], **entry}
    save_figure(_sweep_figure(sweep), run_dir / "alpha_sweep.png")

    ref = settings.reference
    paper = paper_comparison(
        env,
        instantiate(ref.domain),
        instantiate(ref.planner),
        ref.runs,
        stream_seed(seed, "preset"),
        reeval,
        progress,
    )
    save_figure(
        bar_figure(
            entries,
            "Package delivery: re-evaluated values",
            {"paper G-DICE 14.44": PAPER["gdice_best_sampled"], "paper MCS 2.07": PAPER["monte_carlo_search"]},
        ),
        run_dir / "baselines.png",
    )
    write_report(run_dir / "report.md", _report(entries, paper, reeval))
    planner_value, greedy = metrics["planner_cold_start"]["value"], metrics["baselines"]["greedy"]["value"]
    gdice_value, seeded_value = metrics["gdice"]["value"], metrics["gdice_seeded"]["value"]
    mcs_value = metrics["baselines"]["monte_carlo_search"]["value"]
    return {
        **metrics,
        "paper_comparison": {"paper_best_sampled": PAPER["gdice_best_sampled"], **paper},
        "alpha_sweep": sweep,
        "paper": PAPER,
        "acceptance": {
            "planner_at_least_greedy": planner_value >= greedy,
            "planner_at_least_14.4": planner_value >= 14.4,
            "gdice_at_least_14.4": gdice_value >= 14.4,
            "mcs_at_most_third_of_gdice": mcs_value <= gdice_value / 3,
            "seeded_gdice_at_least_14.4": seeded_value >= 14.4,
            "mcs_at_most_third_of_seeded_gdice": mcs_value <= seeded_value / 3,
        },
    }


def _report(entries: dict[str, dict], paper: dict[str, dict], reeval: int) -> str:
    this, preset = paper["this_domain"], paper["preset"]
    lines = [
        "# Package delivery: planners side by side",
        "",
        f"Every controller re-evaluated on {reeval} rollouts that its search never saw.",
        "",
        *comparison_table(entries),
        "",
        "## The paper's 14.44, like for like",
        "",
        "The paper's G-DICE (one controller shared by both robots), its best sampled value (a maximum over",
        "noisy scores, what the paper reports) and its best controller re-evaluated, mean ± s.e. over "
        f"{len(this['values'])} seeds:",
        "",
        "| domain | best sampled | re-evaluated |",
        "|---|---|---|",
        f"| this domain | {this['best_sampled_mean']:.2f} ± {this['best_sampled_stderr']:.2f} | "
        f"{this['value']:.2f} ± {this['stderr']:.2f} |",
        f"| reference-rules preset | {preset['best_sampled_mean']:.2f} ± {preset['best_sampled_stderr']:.2f} | "
        f"{preset['value']:.2f} ± {preset['stderr']:.2f} |",
        f"| paper (reference simulator) | {PAPER['gdice_best_sampled']:.2f} | – |",
        "",
    ]
    return "\n".join(lines) + "\n"


def _sweep_figure(sweep: dict[str, dict[str, Any]]) -> plt.Figure:
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    for entry in sweep.values():
        ax.plot(
            range(1, len(entry["history_best"]) + 1),
            entry["history_best"],
            label=f"alpha = {entry['alpha']:g} (re-evaluated {entry['value']:.2f})",
        )
    ax.set_xlabel("G-DICE iteration")
    ax.set_ylabel("best sampled value so far")
    ax.set_title("Package delivery: learning rate alpha")
    ax.legend(fontsize=8)
    return fig
