"""Smoke test: the perception_replay study runs end to end through the Hydra entry point."""

from __future__ import annotations

import json

from experiment_runs import run_experiment

from classifiers import FrameClassifier
from experiments.runs.artifacts import load_run


def test_perception_replay_smoke(tmp_path, repo_root):
    run_experiment(
        [
            "experiment=perception_replay",
            f"hydra.run.dir={tmp_path}",
            "progress=false",
            "study.train_per_class=6",
            "study.augment=1",
            "study.calib_sequences=2",
            "study.test_sequences=2",
            "study.frames=3",
            "classifier.cv=2",
            "hbni.fit.num_chains=2",
            "hbni.fit.num_samples=40",
            "hbni.fit.warmup_steps=40",
        ],
        repo_root,
    )
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["classes"] == ["irobot", "quadrotor", "racecar"]
    for name in metrics["classes"]:
        for method in ("ssbf", "hbni"):
            entry = metrics["per_class"][name][method]
            assert 0.0 <= entry["end_accuracy"] <= 1.0
            assert len(entry["accuracy_by_frame"]) == 3
    assert metrics["hardest_class"] in metrics["classes"]
    assert metrics["sizes"]["calibration_frames"] == 3 * 2 * 3
    for png in ("replay_sequence.png", "accuracy_vs_frames.png"):
        assert (tmp_path / png).stat().st_size > 10_000
    run = load_run(tmp_path)
    assert isinstance(run.classifier, FrameClassifier)
    assert run.hbni_posterior.num_classes == 3
