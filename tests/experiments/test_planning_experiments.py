"""Smoke tests: the planning experiments run end to end through the real Hydra entry point."""

import json
from pathlib import Path

import pytest
from experiment_runs import run_experiment

from decpomdp import JointController

ROOT = Path(__file__).resolve().parents[2]
GDICE = ["ce_iterations=2", "ce_samples=6", "ce_elites=2", "ce_rollouts=3"]
TINY = [
    *(f"planners.gdice.{s}" for s in GDICE),
    "planners.gdice.num_nodes=4",
    "study.reeval_rollouts=5",
    "study.random_controllers=4",
    "study.select_rollouts=4",
    "progress=false",
    "planners.cold.budget=3000",
    "planners.cold.patience=1",
    "planners.cold.num_nodes=6",
    "planners.cold.ce_iterations=2",
    "planners.cold.ce_samples=10",
    "planners.cold.ce_elites=2",
    "planners.cold.ce_memory=1",
    "planners.cold.ce_rollouts=4",
    "planners.cold.ce_screen_rollouts=2",
    "planners.cold.ls_candidates=40",
    "planners.cold.ls_stages=[[2,0.5],[4,2]]",
    "planners.cold.duel_rollouts=20",
    "planners.cold.visit_rollouts=10",
]
REFERENCE = [*(f"reference.planner.{s}" for s in GDICE), "reference.runs=2"]


def run(name: str, tmp_path: Path, *overrides: str) -> dict:
    run_experiment([f"experiment={name}", f"hydra.run.dir={tmp_path}", *TINY, *overrides], ROOT)
    return json.loads((tmp_path / "metrics.json").read_text())


PACKAGE_DELIVERY = [
    "study.sweep_iterations=2",
    "study.alpha_sweep=[0.1,0.3]",
    "study.seeded.ce_iterations=2",
    *REFERENCE,
]


def test_package_delivery(tmp_path):
    """The study end to end; a second run with the same seed gives the same numbers."""
    run_dir = tmp_path / "a"
    metrics = run("package_delivery", run_dir, "seed=3", *PACKAGE_DELIVERY)
    again = run("package_delivery", tmp_path / "b", "seed=3", *PACKAGE_DELIVERY)
    assert without_timings(again) == without_timings(metrics)
    for png in (
        "value_vs_iteration.png",
        "value_vs_iteration_seeded.png",
        "alpha_sweep.png",
        "baselines.png",
        "planner_progress.png",
    ):
        assert (run_dir / png).stat().st_size > 0
    check_planner(metrics, run_dir, agents=1)
    paper = metrics["paper_comparison"]
    assert paper["paper_best_sampled"] == 14.44 and "successor_rule=True" in paper["preset"]["domain"]
    assert "successor_rule=False" in paper["this_domain"]["domain"]
    for entry in (paper["preset"], paper["this_domain"]):
        assert len(entry["best_sampled"]) == len(entry["values"]) == 2
        assert entry["value"] == pytest.approx(sum(entry["values"]) / 2)
    report = (run_dir / "report.md").read_text()
    assert "cold-start planner" in report and "reference-rules preset" in report and "14.44" in report
    assert len(metrics["gdice_history"]["best_sampled"]) == 2
    check_seeded(metrics, run_dir, num_nodes=14)
    assert set(metrics["alpha_sweep"]) == {"0.1", "0.3"}
    assert metrics["baselines"]["monte_carlo_search"]["budget"] == 12
    assert metrics["baselines"]["greedy"]["value"] > 0
    assert JointController.load(run_dir / "best_controller.safetensors").num_agents == 2
    assert set(metrics["acceptance"]) == {
        "planner_at_least_greedy",
        "planner_at_least_14.4",
        "gdice_at_least_14.4",
        "mcs_at_most_third_of_gdice",
        "seeded_gdice_at_least_14.4",
        "mcs_at_most_third_of_seeded_gdice",
    }


def test_disaster_relief(tmp_path):
    """The study end to end with three robots; a second run with the same seed gives the same numbers."""
    run_dir = tmp_path / "a"
    metrics = run("disaster_relief", run_dir, "seed=3", "domain.num_agents=3")
    again = run("disaster_relief", tmp_path / "b", "seed=3", "domain.num_agents=3")
    assert without_timings(again) == without_timings(metrics)
    for png in ("value_vs_iteration.png", "value_vs_iteration_seeded.png", "comparison.png", "counters.png"):
        assert (run_dir / png).stat().st_size > 0
    check_seeded(metrics, run_dir, num_nodes=8)
    check_planner(metrics, run_dir, agents=3)
    greedy = metrics["baselines"]["greedy"]
    assert greedy["delivered_per_rollout"] > 0 and greedy["inference_frames_per_rollout"] > 0
    assert JointController.load(run_dir / "best_controller.safetensors").num_agents == 3
    assert set(metrics["acceptance"]) == {
        "planner_beats_greedy",
        "planner_at_least_greedy",
        "gdice_beats_greedy",
        "gdice_beats_monte_carlo_search",
        "seeded_gdice_beats_greedy",
        "seeded_gdice_beats_monte_carlo_search",
    }


def check_seeded(metrics: dict, run_dir: Path, num_nodes: int) -> None:
    """The seeded run: its settings, candidates and saved controller (the cold one is saved too)."""
    seeded = metrics["gdice_seeded"]
    assert (
        seeded["planner"]["num_nodes"] == num_nodes and seeded["planner"]["ce_init_weight"] == seeded["init_weight"] > 0
    )
    assert (
        set(seeded["selection_values"]) == {"best_sampled", "mode"} and seeded["selected"] in seeded["selection_values"]
    )
    assert len(metrics["gdice_seeded_history"]["best_sampled"]) == 2 and metrics["planner"]["ce_init_weight"] == 0
    assert JointController.load(run_dir / "best_controller.safetensors").num_nodes == num_nodes
    assert JointController.load(run_dir / "best_controller_cold.safetensors").num_nodes == 4


def check_planner(metrics: dict, run_dir: Path, agents: int) -> None:
    """The cold-start planner's run: its budget, history, score and saved controller (the team's)."""
    entry = metrics["planner_cold_start"]
    assert entry["rollouts"] > 0 and entry["cpu_seconds"] >= 0 and entry["stderr"] >= 0
    assert metrics["planner_cold_start_config"]["budget"] == 3000
    assert metrics["planner_cold_start_history"]["rollouts"][-1] == entry["rollouts"]
    saved = JointController.load(run_dir / "best_controller_planner.safetensors")
    assert saved.num_agents == (2 if agents == 1 else agents) and saved.num_nodes == entry["nodes"] <= 6


def without_timings(obj):
    if isinstance(obj, dict):
        return {k: without_timings(v) for k, v in obj.items() if k not in ("seconds", "cpu_seconds")}
    return [without_timings(v) for v in obj] if isinstance(obj, list) else obj
