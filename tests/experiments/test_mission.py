"""The mission through the real entry point with tiny settings: artefacts, report, load_run, sweeps."""

import json
from pathlib import Path

import pytest
import torch
from experiment_runs import run_experiment

from experiments import load_run
from hbni_pyro import HBNIPosterior, MacroObservationModel
from mission_tiny import TINY_BANKS, TINY_MISSION, TINY_MISSION_FROM_SCRATCH, TINY_MISSION_GDICE

TINY = [*TINY_MISSION, TINY_BANKS]
NO_POWER = "mission.bank.powered.entries=[]"
"""For runs whose checks are not about the value test's power: no sequences rendered on demand (the shared run
checks them)."""


def _run(repo_root, *args, multirun=False, tiny=TINY):
    return run_experiment([*(["-m"] if multirun else []), "experiment=mission", *tiny, *args], repo_root)


@pytest.fixture(scope="module")
def mission_run(tiny_mission_run):
    return tiny_mission_run


def test_mission_writes_metrics_report_figures_and_artefacts(mission_run):
    metrics = json.loads((mission_run / "metrics.json").read_text())
    assert set(metrics["variants"]) == {"perfect", "hbni", "calibrated", "ssbf", "max_of_mean", "hbni_empirical"}
    for entry in metrics["variants"].values():
        assert {"value", "stderr", "delivered_per_rollout", "wrong_per_rollout", "mean_inference_frames"} <= set(entry)
        assert {"value", "stderr", "gap_in_stderr", "wrong_per_rollout"} <= set(entry["executed"])
    assert len(metrics["variants"]["ssbf"]["executed"]["bank_accuracy"]) == 6
    loop = metrics["closed_loop"]
    assert loop["planning"] == {
        "perfect": "exact",
        "hbni": "generative",
        "calibrated": "generative",
        "ssbf": "generative",
        "max_of_mean": "generative",
        "hbni_empirical": "empirical",
    }
    assert loop["bank"]["sequences_per_class"] == 2 and Path(loop["bank"]["path"]).is_file()
    held = loop["bank"]["held_out_sequences_per_class"]
    more = metrics["variants"]["hbni"]["executed"]["on_demand"]  # its value test short of power: 4 more per class
    assert more["sequences_per_class"] == 4 and 1 <= more["mean_frames_rendered"] <= 5
    for name, entry in metrics["variants"].items():  # a simulated table saw neither set: it runs on both
        if name != "perfect":
            extra = 4 if name.startswith("hbni") else 0  # both HBNI policies replay the variant's streams
            fresh = 2 + extra if loop["planning"][name] == "empirical" else 2 + held + extra
            assert entry["executed"]["sequences_per_class"] == fresh
            assert ("on_demand" in entry["executed"]) == (name == "hbni")  # mission.bank.powered.entries
    assert set(loop["acceptance"]) >= {
        "hbni_executed_over_perfect",
        "hbni_executed_beats_ssbf_outside_stderr",
        "hbni_executed_at_least_calibrated",
        "hbni_executed_at_least_98pct_perfect",
        "hbni_honest_on_held_out",
        "hbni_frames_at_most_1.5x_calibrated",
        "hbni_timeouts_at_most_0.1",
    }
    for name in ("hbni", "calibrated", "ssbf", "max_of_mean"):  # each process on the held-out streams it ran on
        checks = metrics["variants"][name]["held_out_process"]
        assert checks["threshold"] == 0.95 and 0 <= checks["timeout_rate"] <= 1
    assert metrics["variants"]["hbni"]["held_out_process"]["stop"] == metrics["hbni_stop"]["value"]
    assert metrics["hbni_stop"]["fitted"] and metrics["calibrated_peer"]["kind"] == "matrix"
    assert metrics["calibrated_peer"]["loss"] <= metrics["calibrated_peer"]["raw_loss"]
    report = (mission_run / "report.md").read_text()
    assert "## Closed loop: planned against executed" in report and "The **generative** planning model is" in report
    for png in ("values.png", "confusion.png", "frames.png", "learning_curves.png", "closed_loop.png"):
        assert (mission_run / png).stat().st_size > 10_000
        assert f"]({png})" in report
    assert metrics["hbni_temper"] == {"value": 1.0, "fitted": False, "needed": False}  # the sequence model's
    assert "uses no likelihood temper" in report
    assert "## Honesty of the planning models" in report and "Value test (one-sided, level 0.05" in report
    assert "so its process also ran on the bank's next 4 sequences per class" in report
    for name, entry in metrics["variants"].items():
        if name != "perfect":
            check = entry["executed"]["distribution_check"]
            assert len(check["classes"]) == 6 and check["passed"] == all(c["passed"] for c in check["classes"])
            test = entry["executed"]["value_test"]
            assert 0 <= test["power"] <= 1 and test["passed"] == (test["p_value"] >= 0.05)
    assert "hbni_distribution_check_passed" in loop["acceptance"]
    assert (mission_run / "reliability.png").stat().st_size > 10_000 and "](reliability.png)" in report
    assert metrics["conditions"]["overrides"] == {"gain": [0.45, 0.8], "noise": [3.0, 8.0], "blur": [1.0, 6.0]}
    assert metrics["planner"]["budget"] == 3000 and metrics["planner"]["ce_result"] == "duel"  # no hand-written seed
    assert metrics["warm_planner"]["budget"] == 1000
    started = {name: entry["started_from"] for name, entry in metrics["variants"].items()}
    assert started == {
        "perfect": "scratch",
        "hbni": "perfect",
        "calibrated": "perfect",
        "ssbf": "perfect",
        "max_of_mean": "perfect",
        "hbni_empirical": "perfect",
    }
    assert all(
        entry["rollouts"] > 0 and entry["planner_value"] == entry["planner_value"]
        for entry in metrics["variants"].values()
    )
    assert set(metrics["stage_seconds"]) == {
        "train",
        "classify",
        "fit",
        "characterize",
        "characterize_generative",
        "plan",
        "bank_wait",
        "closed_loop",
    }
    assert "preset with gain = [0.45, 0.8]" in report
    manifest = json.loads((mission_run / "artifacts.json").read_text())
    assert set(manifest) == {
        "classifier",
        "posterior",
        "calibration",
        "macro_hbni",
        "macro_calibrated",
        "macro_calibrated_generative",
        "controller_calibrated",
        "macro_ssbf",
        "macro_max_of_mean",
        "macro_hbni_generative",
        "macro_ssbf_generative",
        "macro_max_of_mean_generative",
        "controller_perfect",
        "controller_hbni",
        "controller_ssbf",
        "controller_max_of_mean",
        "controller_hbni_empirical",
    }
    generative = MacroObservationModel.load(mission_run / "macro_hbni_generative.safetensors")
    assert (
        generative.info["generative"] == "posterior predictive (sequence model)"
        and generative.info["num_streams"] == 50
    )


def test_same_seed_same_numbers_and_the_bank_comes_from_the_cache(mission_run, tmp_path, repo_root):
    _run(repo_root, f"hydra.run.dir={tmp_path}")
    first = json.loads((mission_run / "metrics.json").read_text())
    again = json.loads((tmp_path / "metrics.json").read_text())
    assert (
        again["closed_loop"]["bank"]["cached"]
        and again["closed_loop"]["bank"]["path"] == first["closed_loop"]["bank"]["path"]
    )
    for name, entry in first["variants"].items():
        assert again["variants"][name]["value"] == entry["value"]
        assert again["variants"][name]["executed"]["value"] == entry["executed"]["value"]


def _check_generative_planning(run_dir: Path, model: str, variants: list[str]) -> None:
    """Every noise model simulates the streams of its own posterior predictive for each variant's generative
    table; HBNI's empirical table is planned on too, and perfect perception exactly."""
    source = f"posterior predictive ({model} model)"
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["closed_loop"]["planning"] == {
        "perfect": "exact",
        **{v: "generative" for v in variants},
        "hbni_empirical": "empirical",
    }
    ssbf = MacroObservationModel.load(run_dir / "macro_ssbf_generative.safetensors")
    assert ssbf.info["generative"] == source and "StaticStateBayesFilter" in ssbf.info["filter"]
    assert HBNIPosterior.load(run_dir / "posterior.safetensors").model == model
    assert (
        f"model={model!r}" in MacroObservationModel.load(run_dir / "macro_hbni_generative.safetensors").info["filter"]
    )
    temper = metrics["hbni_temper"]
    if model == "paper":  # a frame-level model: the temper is fitted on the calibration sequences
        assert temper["fitted"] and temper["value"] in temper["grid"]
        assert temper["log_score"][temper["grid"].index(temper["value"])] == max(temper["log_score"])
        assert f"temper is {temper['value']:g}" in (run_dir / "report.md").read_text()
    else:
        assert temper == {"value": 1.0, "fitted": False, "needed": False}


def test_generative_planning_on_the_sequence_model(mission_run):
    """The defaults: the sequence model's posterior predictive for every variant, with no temper."""
    _check_generative_planning(mission_run, "sequence", ["hbni", "calibrated", "ssbf", "max_of_mean"])


def test_generative_planning_on_the_paper_model_planned_by_gdice(tmp_path, repo_root):
    """hbni.model=paper: the paper model's posterior predictive, with the temper fitted; perfect perception
    planned by the paper's G-DICE, the variants from its plan; no preset conditions."""
    _run(
        repo_root,
        f"hydra.run.dir={tmp_path}",
        "perception=[hbni,ssbf]",
        "hbni.model=paper",
        "mission.conditions=null",
        NO_POWER,
        tiny=[*TINY_MISSION_GDICE, TINY_BANKS],  # G-DICE reads no local-search settings: the tiny ones are its own
    )
    _check_generative_planning(tmp_path, "paper", ["hbni", "ssbf"])
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["planner"]["ce_result"] == "best_sampled" and metrics["warm_planner"]["phases"] == ["ls"]
    assert metrics["variants"]["perfect"]["started_from"] == "scratch"
    assert metrics["variants"]["hbni"]["started_from"] == metrics["variants"]["ssbf"]["started_from"] == "perfect"
    assert metrics["conditions"]["overrides"] == {}


def test_load_run_returns_ready_objects(mission_run):
    from classifiers.data import render_images

    run = load_run(mission_run)
    images = render_images("ambulance", 2, "mission", seed=5)
    probs = run.classifier.proba(images)
    assert probs.shape == (2, 6)
    torch.testing.assert_close(probs.sum(-1).double(), torch.ones(2, dtype=torch.float64), atol=1e-5, rtol=0)
    assert run.posterior.model == "sequence" and "loc[0, 0]" in run.posterior.summary()  # the default model
    assert isinstance(HBNIPosterior.load(mission_run / "posterior.safetensors"), HBNIPosterior)
    label, frames = run.macro_hbni.sample(torch.zeros(10, dtype=torch.long), torch.Generator().manual_seed(0))
    assert label.shape == frames.shape == (10,) and (frames >= 1).all() and (frames <= 5).all()
    assert isinstance(MacroObservationModel.load(mission_run / "macro_ssbf.safetensors"), MacroObservationModel)
    assert run.controller_hbni.action.shape[:2] == (1, 2)


@pytest.mark.parametrize("launcher", ["joblib_local", "submitit_local_jobs"])
def test_two_job_sweep_over_perception(tmp_path, repo_root, launcher):
    _run(
        repo_root,
        f"hydra/launcher={launcher}",
        f"hydra.sweep.dir={tmp_path}",
        "perception=hbni,ssbf",
        NO_POWER,
        multirun=True,
    )
    for job, variant in (("0", "hbni"), ("1", "ssbf")):
        metrics = json.loads((tmp_path / job / "metrics.json").read_text())
        assert set(metrics["variants"]) == {"perfect", variant} | ({"hbni_empirical"} if variant == "hbni" else set())
    report = (tmp_path / "report.md").read_text()
    header = next(line for line in report.splitlines() if line.startswith("| job"))
    assert header.startswith("| job | status | perception | variants.perfect | variants.hbni |")
    assert "| variants.ssbf |" in header and "| variants.hbni.wrong_rate |" in header
    rows = [line for line in report.splitlines() if line.startswith("| [")]
    assert rows[0].startswith("| [0](0/) | completed | hbni | ") and rows[1].startswith(
        "| [1](1/) | completed | ssbf | "
    )


def test_fixed_temper_preset_conditions_and_planning_from_scratch(tmp_path, repo_root):
    """mission.temper fixes the paper model's temper; without warm starts every variant is planned from scratch."""
    _run(
        repo_root,
        f"hydra.run.dir={tmp_path}",
        "perception=hbni",
        "hbni.model=paper",
        "mission.temper=0.5",
        "mission.conditions=null",
        NO_POWER,
        tiny=[*TINY_MISSION_FROM_SCRATCH, TINY_BANKS],
    )
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["warm_planner"] is None
    assert {entry["started_from"] for entry in metrics["variants"].values()} == {"scratch"}
    assert metrics["hbni_temper"] == {"value": 0.5, "fitted": False}
    assert metrics["conditions"]["overrides"] == {}
    assert "temper=0.5" in MacroObservationModel.load(tmp_path / "macro_hbni.safetensors").info["filter"]


def test_stream_runs_a_missions_saved_models(mission_run, tmp_path, repo_root):
    """experiment=stream with stream.run: the run's classifier, posterior, class order and fitted temper."""
    import cv2

    from classifiers.data import render_sequence

    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (320, 240))
    for frame in render_sequence("medical_crate", 8, "mission", seed=9):
        writer.write(frame)
    writer.release()
    out = tmp_path / "stream"
    run_experiment(
        [
            "experiment=stream",
            f"stream.source={video}",
            f"stream.run={mission_run}",
            "stream.max_frames=5",
            "stream.annotate=[strip]",
            "progress=false",
            f"hydra.run.dir={out}",
        ],
        repo_root,
    )
    metrics = json.loads((out / "metrics.json").read_text())
    mission = json.loads((mission_run / "metrics.json").read_text())
    assert metrics["classes"] == mission["classes"] and metrics["frames"] == 8
    assert f"temper={mission['hbni_temper']['value']:g}" in metrics["process"]
    records = (out / "macro_observations.jsonl").read_text().splitlines()
    assert len(records) == metrics["macro_observations"] >= 2  # 8 frames, at most 5 per macro-observation
