"""The noise-model study through the real entry point (tiny settings), its output cache, a user's
image folder, its config checks, and the one key that switches the mission's noise model."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest
import torch
from experiment_runs import run_experiment

from classifiers.data import render_images, render_sequence
from experiments.runs.artifacts import load_run
from experiments.schemas import build_settings, compose_config, compose_settings
from experiments.steps.noise import fit_labelled
from hbni_pyro import HBNIPosterior

TINY = [
    "progress=false",
    "study.mission.train_per_class=5",
    "study.mission.augment=0",
    "study.mission.calib_sequences=2",
    "study.mission.test_sequences=2",
    "study.mission.frames=4",
    "study.toy.num_trials=40",
    "study.toy.num_training_sets=2",
    "study.toy.max_len=6",
    "study.toy.filter_draws=50",
    "hbni.fit.num_chains=2",
    "hbni.fit.num_samples=30",
    "hbni.fit.warmup_steps=30",
    "study.curve_thresholds=[0.5,0.95]",
    "classifier.cv=2",
    "study.photos.train_per_class=5",
    "study.photos.augment=0",
    "study.photos.calib_sequences=2",
    "study.photos.test_sequences=2",
    "study.photos.frames=4",
]


def _run(repo_root, run_dir, *args):
    return run_experiment(["experiment=noise_models", f"hydra.run.dir={run_dir}", *TINY, *args], repo_root)


@pytest.fixture(scope="module")
def study(tmp_path_factory, repo_root):
    root = tmp_path_factory.mktemp("noise_models")
    _run(repo_root, root / "first", f"study.cache_dir={root / 'cache'}")
    _run(repo_root, root / "second", f"study.cache_dir={root / 'cache'}")
    return root


def test_study_writes_tables_figures_and_every_posterior(study):
    metrics = json.loads((study / "first" / "metrics.json").read_text())
    assert set(metrics["conditions"]) == {"default", "in_flight", "photos"}
    filters = {
        "paper",
        "paper_tempered",
        "confusion",
        "confusion_tempered",
        "sequence",
        "sequence_stopped",
        "calibrated",
        "calibrated_temperature",
        "ssbf",
        "max_of_mean",
    }
    for cond in metrics["conditions"].values():
        assert set(cond["filters"]) == filters
        for row in cond["filters"].values():
            assert set(row["thresholds"]) == {"0.9", "0.95", "0.99"} and set(row["curve"]) == {"0.5", "0.95"}
            assert row["log_score"] <= 0 and 0 <= row["final_accuracy"] <= 1 and 0 <= row["ece"] <= 1
    assert set(metrics["toy"]["crossing_n"]) == {"paper", "confusion", "sequence", "ssbf", "max_of_mean"}
    for cond in ("default", "in_flight", "photos"):
        assert metrics["acceptance"][cond]["best_model"] in ("paper", "confusion", "sequence")
    report = (study / "first" / "report.md").read_text()
    for png in ("toy_error.png", "accuracy_vs_frames.png", "reliability.png"):
        assert (study / "first" / png).stat().st_size > 10_000 and f"]({png})" in report
    assert "## In-flight preset" in report and "## Default mission conditions" in report
    assert "## Real photographs, degraded moving camera" in report
    run = load_run(study / "first")
    for cond in ("default", "in_flight"):
        for model in ("paper", "confusion", "sequence"):
            post = getattr(run, f"posterior_{cond}_{model}")
            assert isinstance(post, HBNIPosterior) and post.model == model and post.num_classes == 6


def test_second_run_reuses_the_cached_outputs_and_gets_the_same_numbers(study):
    first = json.loads((study / "first" / "metrics.json").read_text())
    second = json.loads((study / "second" / "metrics.json").read_text())
    assert first["conditions"] == second["conditions"] and first["toy"] == second["toy"]
    assert len(list((study / "cache").glob("*.safetensors"))) == 3
    assert not (study / "second" / "classifier.safetensors").exists(), "the classifier is not retrained when cached"


def test_the_photo_condition_reports_sizes_honesty_and_the_default_models_target(study):
    metrics = json.loads((study / "first" / "metrics.json").read_text())
    cond = metrics["conditions"]["photos"]
    assert cond["sizes"] == {"calibration_sequences_per_class": 2, "held_out_sequences": 12, "frames": 4}
    honesty = metrics["honesty"]["photos"]
    assert set(honesty) == set(cond["filters"])
    assert all(
        set(v) == {"0.9", "0.95", "0.99"} and all(isinstance(b, bool) for b in v.values()) for v in honesty.values()
    )
    target = metrics["acceptance"]["photos"]["sequence_target"]
    assert set(target) == {"emitted_right", "timeouts_at_most_0.1", "frames_at_most_ssbf", "met"}
    assert list(load_run(study / "first").posterior_photos_sequence.class_names) == [
        "astronaut",
        "coffee",
        "chelsea",
        "rocket",
        "hubble_deep_field",
        "immunohistochemistry",
    ]


def _write_folder(root: Path, classes: list[str]) -> None:
    for name in classes:
        for i, img in enumerate(render_images(name, 5, "training", seed=0)):
            (root / "train" / name).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(root / "train" / name / f"{i:03d}.png"), img)
        for s in range(4):
            seq = root / "sequences" / name / f"seq{s}"
            seq.mkdir(parents=True)
            for i, frame in enumerate(render_sequence(name, 5, "mission", seed=3, index=s)):
                cv2.imwrite(str(seq / f"frame_{i}.png"), frame)


def test_a_user_image_folder_beside_the_photographs_without_the_mission_conditions(tmp_path, repo_root):
    classes = ["irobot", "quadrotor", "racecar"]
    _write_folder(tmp_path / "images", classes)
    _run(
        repo_root,
        tmp_path / "run",
        f"study.images={tmp_path / 'images'}",
        "~study.conditions.default",
        "~study.conditions.in_flight",
        "study.cache_dir=null",
        "study.models=[paper,sequence]",
    )
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert set(metrics["conditions"]) == {"images", "photos"}
    filters = {
        "paper",
        "paper_tempered",
        "sequence",
        "sequence_stopped",
        "calibrated",
        "calibrated_temperature",
        "ssbf",
        "max_of_mean",
    }
    images, photos = metrics["conditions"]["images"], metrics["conditions"]["photos"]
    assert images["sizes"] == {"calibration_sequences_per_class": 2, "held_out_sequences": 6, "frames": 4}
    assert set(images["filters"]) == set(photos["filters"]) == filters
    assert set(photos["stops"]["sequence_stopped"]) == {"0.9", "0.95", "0.99"}
    stopped = photos["filters"]["sequence_stopped"]["thresholds"]["0.95"]
    assert stopped["stop"] == photos["stops"]["sequence_stopped"]["0.95"]
    assert set(metrics["acceptance"]["photos"]["default_vs_calibrated"]) >= {"honest", "frames_over_peer", "met"}


@pytest.mark.parametrize(
    "override, match",
    [
        ("study.models=[paper,gaussian]", "study.models: expected distinct models"),
        ("study.images_calibration=1.5", "study.images_calibration"),
        ("study.thresholds=[0.9,1.2]", "study.thresholds"),
        ("study.toy.training_size=16", "study.toy.training_size"),
        ("study.photos.frames=0", "study.photos.frames"),
        ("study.photos.augment=-1", "study.photos.augment"),
        ("hbni.model=mixture", "hbni.model: expected one of"),
    ],
)
def test_bad_settings_fail_before_any_work(override, match):
    with pytest.raises(ValueError, match=match):
        build_settings(compose_config(["experiment=noise_models", override]))


@pytest.mark.parametrize("experiment", ["mission", "perception_replay"])
@pytest.mark.parametrize("model", ["confusion", "sequence"])
def test_one_key_switches_the_noise_model_of_the_mission_and_the_replay(experiment, model):
    settings = compose_settings(
        [
            f"experiment={experiment}",
            f"hbni.model={model}",
            "hbni.fit.num_chains=2",
            "hbni.fit.num_samples=20",
            "hbni.fit.warmup_steps=20",
        ]
    )
    g = torch.Generator().manual_seed(0)
    outputs = torch.softmax(
        torch.randn(3, 2, 4, 3, generator=g, dtype=torch.float64) + 2 * torch.eye(3)[:, None, None], -1
    )
    post = fit_labelled(outputs, settings.hbni, seed=0, progress=False)
    assert post.model == model and post.num_classes == 3
