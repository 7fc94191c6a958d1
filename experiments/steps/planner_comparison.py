"""The side-by-side planner comparison that the package-delivery and disaster-relief experiments share.

On one domain: the cold-start planner (``planners.cold``), the paper's G-DICE from uniform
distributions (``planners.gdice``), G-DICE seeded with a hand-written policy (``study.seeded``), that
policy itself, Monte Carlo search and random controllers; every controller re-evaluated on
``study.reeval_rollouts`` independent rollouts. Saves the three searched controllers and their
progress figures into the run folder.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, NamedTuple

from hydra.utils import instantiate

from decpomdp import JointController
from decpomdp.core import DecPOSMDP
from decpomdp.search import PlannerConfig
from experiments.reports.planning_figures import history_figure, planner_figure
from experiments.runs.outputs import save_figure
from experiments.schemas.planning_studies import PlanningExperiment
from experiments.steps.planning import run_baselines, run_planner, run_seeded, score
from hbni_infra.streams import stream_seed


class Comparison(NamedTuple):
    """``entries``: name -> score entry, in report order; ``metrics``: the ``metrics.json`` fields."""

    entries: dict[str, dict[str, Any]]
    metrics: dict[str, Any]


def compare_planners(
    settings: PlanningExperiment, env: DecPOSMDP, greedy_policy: JointController, title: str, run_dir: Path
) -> Comparison:
    """Run every planner and baseline of the comparison on ``env`` (seeds offset from ``settings.seed``).

    Writes ``best_controller_planner.safetensors`` (cold-start planner), ``best_controller_cold``
    (G-DICE), ``best_controller`` (seeded G-DICE), ``planner_progress.png``,
    ``value_vs_iteration.png`` and ``value_vs_iteration_seeded.png``; ``title`` names the domain in
    the figures.
    """
    study, seed, progress = settings.study, settings.seed, settings.progress
    config: PlannerConfig = instantiate(settings.planners.gdice)
    cold: PlannerConfig = instantiate(settings.planners.cold)
    reeval, shared_controller = study.reeval_rollouts, study.shared_controller

    planner, planner_best, planner_score = run_planner(
        env, cold, shared_controller, stream_seed(seed, "cold"), progress, reeval
    )
    planner_best.save(run_dir / "best_controller_planner.safetensors")
    save_figure(planner_figure(planner.history, f"Cold-start planner on {title}"), run_dir / "planner_progress.png")

    result, best, gdice_score = run_planner(
        env, config, shared_controller, stream_seed(seed, "gdice"), progress, reeval
    )
    best.save(run_dir / "best_controller_cold.safetensors")
    save_figure(history_figure(result.history, f"G-DICE on {title}"), run_dir / "value_vs_iteration.png")

    seeded, seeded_best, seeded_score = run_seeded(
        env, config, study, greedy_policy, stream_seed(seed, "seeded"), progress
    )
    seeded_best.save(run_dir / "best_controller.safetensors")
    save_figure(
        history_figure(seeded.history, f"G-DICE seeded with the hand-written policy, {title}"),
        run_dir / "value_vs_iteration_seeded.png",
    )

    baselines = run_baselines(env, config, study, stream_seed(seed, "baselines"))
    greedy = score(env, greedy_policy, reeval, stream_seed(seed, "reeval", "greedy"))
    entries = {
        "cold-start planner": planner_score,
        "G-DICE": gdice_score,
        "G-DICE seeded": seeded_score,
        "greedy (hand-written)": greedy,
        "Monte Carlo search": baselines["monte_carlo_search"],
        "random": baselines["random"],
    }
    metrics = {
        "planner_cold_start": planner_score,
        "planner_cold_start_history": planner.history,
        "planner_cold_start_config": dataclasses.asdict(cold),
        "domain": repr(env),
        "planner": dataclasses.asdict(config),
        "shared_controller": shared_controller,
        "rollouts_per_evaluation": config.ce_rollouts,
        "reeval_rollouts": reeval,
        "gdice": gdice_score,
        "gdice_history": result.history,
        "gdice_seeded": seeded_score,
        "gdice_seeded_history": seeded.history,
        "baselines": {**baselines, "greedy": greedy},
    }
    return Comparison(entries, metrics)
